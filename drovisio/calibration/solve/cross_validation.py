"""Cross-validation: the kept views' two halves solved apart and their models compared over
the image (a diagnostic: it never stops a calibration)."""

from __future__ import annotations

import numpy as np

from drovisio.calibration.solve.fit import fit_model
from drovisio.calibration.solve.results import CalibrationError, SolveOptions, ViewInput
from drovisio.calibration.uncertainty import (
    UncertaintyMap,
    grid_jacobians,
    model_difference_px,
    sigma_max,
)


def cross_validate(views: list[ViewInput], size, fix_k3: bool, um: UncertaintyMap,
                    opt: SolveOptions, model: str = "plumb_bob") -> dict:
    """The two halves' models compared (a diagnostic: it never stops a calibration)."""
    try:
        return _compare_halves(views, size, fix_k3, um, opt, model)
    except Exception as e:  # noqa: BLE001 - a diagnostic degrades, it never kills the solve
        return {"p50": None, "p95": None, "max": None,
                "skipped": f"not computed: {type(e).__name__}: {e}"}


def _compare_halves(views: list[ViewInput], size, fix_k3: bool, um: UncertaintyMap,
                    opt: SolveOptions, model: str = "plumb_bob") -> dict:
    if not opt.cross_validate:
        return {"p50": None, "p95": None, "max": None, "skipped": "disabled"}
    if len(views) < opt.min_views_cross_validation:
        return {"p50": None, "p95": None, "max": None,
                "skipped": f"needs {opt.min_views_cross_validation} views, have {len(views)}"}
    a, b = views[0::2], views[1::2]
    try:
        ma = fit_model(a, size, fix_k3, model)
        mb = fit_model(b, size, fix_k3, model)
    except CalibrationError as e:
        return {"p50": None, "p95": None, "max": None, "skipped": str(e)}
    m = um.mask(opt.roi)
    d = model_difference_px(ma.camera, mb.camera, um.xs, um.ys)
    # the difference expected from the halves' own covariances: z = d / σ_{A−B}
    s_ab = sigma_max(np.nan_to_num(grid_jacobians(ma.camera, um.xs, um.ys), nan=0.0),
                     ma.covariance + mb.covariance)
    z = (d.ravel() / np.maximum(s_ab, 1e-12)).reshape(d.shape)[m]
    v = d[m]
    vr = model_difference_px(ma.camera, mb.camera, um.xs, um.ys, compensate_rotation=True)[m]
    finite = np.isfinite(v)
    if not finite.any():
        return {"p50": None, "p95": None, "max": None,
                "skipped": "not computed: a half's lens model sees no ray over the image"}
    z, vr = z[np.isfinite(z)], vr[np.isfinite(vr)]
    out_of_model = float(1.0 - finite.mean())
    v = v[finite]
    return {"p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)),
            "max": float(v.max()), "halves": [len(a), len(b)],
            "normalized_p95": float(np.percentile(z, 95)) if z.size else None,
            "rotation_compensated": {"p50": float(np.percentile(vr, 50)),
                                     "p95": float(np.percentile(vr, 95)),
                                     "max": float(vr.max())} if vr.size else None,
            "no_ray_fraction": round(out_of_model, 4),
            "definition": "difference of the projections of the two halves' models over the "
                          "image, pixels: camera frame fixed (comparable with uncertainty_px), "
                          "and after the best-aligning rotation of the camera frame (what a "
                          "pose estimator feels); normalized_p95: p95 of the difference divided "
                          "by the 1-sigma the two halves' covariances predict for it"}
