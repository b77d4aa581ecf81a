"""The rules applied to a solve: highest-order coefficients held at 0 when the data do not
determine them (the k3 rule), and single corners that disagree with the model dropped."""

from __future__ import annotations

from math import erf, exp, lgamma, log, sqrt

import numpy as np

from drovisio.calibration.solve.fit import fit_model
from drovisio.calibration.solve.models import RETRY_FIXED
from drovisio.calibration.solve.results import CalibrationError, Model, SolveOptions, ViewInput
from drovisio.calibration.uncertainty import param_names, projection_uncertainty, view_jacobian


def _chi2_quantile(dof: int, sigmas: float) -> float:
    """The χ² of ``dof`` degrees of freedom exceeded with the probability of a two-sided
    ``sigmas``-σ normal deviation (dof 1: sigmas²), by bisection on the regularised gamma."""
    p = erf(sigmas / sqrt(2.0))          # the confidence, e.g. 0.9545 for 2σ

    def cdf(x: float) -> float:          # P(dof/2, x/2) by its series
        a, z = dof / 2.0, x / 2.0
        term = total = 1.0 / a
        for i in range(1, 500):
            term *= z / (a + i)
            total += term
            if term < total * 1e-15:
                break
        return total * exp(-z + a * log(z) - lgamma(a)) if z > 0 else 0.0

    lo, hi = 0.0, 200.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < p else (lo, mid)
    return 0.5 * (lo + hi)


def _retry_entry(note: str) -> tuple[str, str]:
    """A retry's note (``k4, k5, k6 held at 0: ...``) as a ``fixed`` entry: the names, and
    the rest (the report says them as ``NAMES REST``, the names once)."""
    names, _, rest = note.partition(" held at 0")
    return names, "held at 0" + rest


def fit_with_rules(views: list[ViewInput], size, model: str, opt: SolveOptions
                    ) -> tuple[Model, dict[str, str], dict | None]:
    """One solve of ``model`` with the k3 rule (plumb_bob): (model, fixed, free_model)."""
    fixed: dict[str, str] = {}
    if model != "plumb_bob":
        m = fit_model(views, size, model=model)
        if m.retry_note:
            fixed.update([_retry_entry(m.retry_note)])
            return m, fixed, None
        # the k3 rule for every model: its highest-order coefficients (fisheye k3 k4,
        # rational k4-k6...) are held at 0 when together they do not differ from 0 (a narrow
        # lens or few views cannot tell them from the lower orders): a Wald test of the
        # block, χ² = vᵀΣ⁻¹v, at the confidence of the 2σ rule (they are correlated with each
        # other — the rational model's numerator and denominator trade — so one at a time
        # would miss a block that matters)
        n, k = len(param_names(model)), RETRY_FIXED[model]
        vals, sds = m.values()[n - k:], m.std[n - k:]
        block = m.covariance[n - k:, n - k:]
        try:
            chi2 = float(vals @ np.linalg.solve(block, vals))
        except np.linalg.LinAlgError:
            chi2 = 0.0
        if np.isfinite(chi2) and chi2 >= _chi2_quantile(k, opt.k3_significance):
            return m, fixed, None
        names = ", ".join(param_names(model)[n - k:])
        try:
            m2 = fit_model(views, size, model=model, fixed_coefficients=k)
        except CalibrationError:
            return m, fixed, None
        fixed[names] = ("held at 0: the data do not determine them (free solve: " + ", ".join(
            f"{nm} = {v:.4g} ± {sd:.2g}" for nm, v, sd in zip(param_names(model)[n - k:],
                                                            vals, sds))
            + f"; together χ² = {chi2:.3g}, below the {opt.k3_significance:g}σ level "
            f"{_chi2_quantile(k, opt.k3_significance):.3g})")
        return m2, fixed, None
    if opt.fix_k3 is True:
        fixed["k3"] = "fixed to 0 on request"
        return fit_model(views, size, fix_k3=True), fixed, None
    m = fit_model(views, size, fix_k3=False)
    if m.retry_note:
        fixed.update([_retry_entry(m.retry_note)])
        return m, fixed, None
    if opt.fix_k3 != "auto":
        return m, fixed, None
    k3, s3 = float(m.camera.dist[4]), float(m.std[8])
    if abs(k3) >= opt.k3_significance * s3:
        return m, fixed, None
    free_um = projection_uncertainty(m.camera, m.covariance, opt.grid_step_px)
    free_model = {"k3": k3, "k3_std": s3, "rms_px": m.rms_px,
                  "uncertainty_px": free_um.stats(opt.roi)}
    fixed["k3"] = (f"fixed to 0: the data do not determine it (free solve: k3 = {k3:.4g}"
                   f" ± {s3:.2g}, |k3| < {opt.k3_significance:g}σ); the uncertainty map "
                   "is conditioned on k3 = 0")
    return fit_model(views, size, fix_k3=True), fixed, free_model


def reject_corners(views: list[ViewInput], model: Model, opt: SolveOptions
                    ) -> tuple[list[ViewInput], list[dict]]:
    """Corners farther from the model's projection than ``corner_factor`` × the median corner
    residual (and ``corner_margin_px``) are dropped — at most 5 % of a view's corners (more
    is a bad view, which the view rule handles)."""
    res = []
    for v, f in zip(views, model.fits):
        _, _, p = view_jacobian(v.object_points, f.rvec, f.tvec, model.camera)
        res.append(np.hypot(*(p - np.asarray(v.corners, float).reshape(-1, 2)).T))
    med = float(np.median(np.concatenate(res)))
    limit = max(opt.corner_factor * med, opt.corner_margin_px)
    out, dropped = [], []
    for v, e in zip(views, res):
        bad = np.flatnonzero(e > limit)
        if bad.size == 0 or bad.size > max(1, int(0.05 * e.size)):
            out.append(v)
            continue
        keep = np.ones(e.size, bool)
        keep[bad] = False
        out.append(ViewInput(v.name, np.asarray(v.corners)[keep],
                             np.asarray(v.object_points)[keep]))
        dropped += [{"file": v.name, "corner": int(i), "residual_px": round(float(e[i]), 3),
                     "reason": f"{e[i]:.2f} px from the model's projection, more than "
                               f"{opt.corner_factor:g}x the median corner residual "
                               f"({med:.3f} px): a wrong or smeared corner"} for i in bad]
    return out, dropped
