"""``--model auto``: the lens model chosen by how well each poses views it was not solved
on."""

from __future__ import annotations

from typing import Any

import numpy as np

from drovisio.calibration.lm import initial_poses, refine
from drovisio.calibration.solve.checks import corner_noise_px
from drovisio.calibration.solve.results import CalibrationError, SolveOptions, ViewInput
from drovisio.calibration.solve.rules import fit_with_rules
from drovisio.calibration.uncertainty import lens_key, param_values

#: The models ``auto`` compares, fewest coefficients first (plumb_bob first: every tool
#: reads it).
AUTO_MODELS = ("plumb_bob", "fisheye", "rational_polynomial")

#: One model's held-out error per view: RMS in pixels; None where the view could not be posed
#: through the model; NaN where its fold could not be solved (no evidence).
HeldOut = list[float | None]


def choose_model(views: list[ViewInput], size: tuple[int, int], opt: SolveOptions
                 ) -> tuple[str, dict[str, Any]]:
    """The lens model by held-out views (the module doc's rule).

    1. Each model is solved on all views and checked (:func:`diagnose`): a model that does
       not converge, or whose coefficients the views do not determine, is refused by name.
    2. Each model is solved without every sixth view (:data:`HELD_OUT_FOLDS` folds;
       leave-one-out up to 6 views) and every held-out view is posed through it; a view a
       model cannot pose is that model's failure on that view, not its failure as a whole,
       and a fold the model cannot solve is no evidence either way.
    3. Going from fewer coefficients to more (plumb_bob, fisheye, rational), a model replaces
       the one chosen so far when it fails on fewer views and is not worse on the views both
       posed (held-out RMS within 10 %), or fails on no more views and is clearly better
       beyond the noise: held-out RMS 10 % lower and the per-view improvement larger than
       twice its standard error.

    Returns:
        (camera model name, {"chosen", "reason", "held_out_rms_px": {model: px or None},
        "failed_views", "refused", "corner_noise_px"}).

    Raises:
        CalibrationError: no model converged on these views.
    """
    if len(views) < 6:
        return "plumb_bob", {
            "chosen": "plumb_bob", "held_out_rms_px": {},
            "reason": f"kept plumb_bob: {len(views)} views are too few to compare lens models "
                      "on held-out views (6 or more)"}
    noise = corner_noise_px(views)
    refused = _refused_models(views, size, opt)
    eligible = [n for n in AUTO_MODELS if n not in refused]
    if not eligible:
        raise CalibrationError("no lens model converged on these views (" + "; ".join(
            refused.values()) + ")")
    per_view = {name: _held_out_errors(views, size, name, opt) for name in AUTO_MODELS}
    chosen, why = eligible[0], ""
    for cand in eligible[1:]:
        why_cand = _replaces(per_view[chosen], per_view[cand], cand, len(views))
        if why_cand is not None:
            chosen, why = cand, why_cand
    return chosen, {
        "chosen": chosen, "reason": _reason(chosen, why, per_view, refused, len(views)),
        "held_out_rms_px": {k: None if k in refused else _rounded(_rms(v))
                            for k, v in per_view.items()},
        "failed_views": {k: _failed(v) for k, v in per_view.items()},
        "refused": refused,
        "corner_noise_px": None if noise is None else round(noise, 4)}


def _refused_models(views: list[ViewInput], size: tuple[int, int], opt: SolveOptions
                    ) -> dict[str, str]:
    """Each of :data:`AUTO_MODELS` that does not converge on all views, or that they do not
    determine, with the one line saying why."""
    refused: dict[str, str] = {}
    for name in AUTO_MODELS:
        try:
            fit_with_rules(views, size, name, opt)
        except CalibrationError as e:
            refused[name] = str(e)
    return refused


def _scored(x: float | None) -> bool:
    return x is not None and bool(np.isfinite(x))


def _rms(e: HeldOut) -> float | None:
    v = [x for x in e if x is not None and np.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(v)))) if v else None


def _rounded(x: float | None) -> float | None:
    return None if x is None else round(x, 4)


def _failed(e: HeldOut) -> int:
    return sum(x is None for x in e)


def _replaces(eb: HeldOut, ec: HeldOut, cand: str, n_views: int) -> str | None:
    """Why candidate ``cand`` (held-out errors ``ec``) replaces the model chosen so far
    (``eb``), or None when it does not (rule 3 of :func:`choose_model`)."""
    # only views both models had a solved fold for: a fold that one model cannot
    # determine is no evidence for the other
    both = [i for i in range(n_views) if (eb[i] is None or _scored(eb[i]))
            and (ec[i] is None or _scored(ec[i]))]
    common = [i for i in both if _scored(eb[i]) and _scored(ec[i])]
    fb, fc = sum(eb[i] is None for i in both), sum(ec[i] is None for i in both)
    if not common:
        return f"{cand} posed {fb - fc} more held-out views" if fc < fb else None
    mb = np.array([eb[i] for i in common]) ** 2
    mc = np.array([ec[i] for i in common]) ** 2
    rb, rc = float(np.sqrt(mb.mean())), float(np.sqrt(mc.mean()))
    d = mb - mc
    se = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("inf")
    if fc < fb and rc <= 1.1 * rb:
        return (f"{cand} posed {fb - fc} more held-out views and is not worse "
                f"on the {len(common)} both posed ({rc:.3f} vs {rb:.3f} px)")
    if fc <= fb and rc < 0.9 * rb and d.mean() > 2.0 * se:
        return (f"{cand} is clearly better on the {len(common)} views both "
                f"posed ({rc:.3f} vs {rb:.3f} px, beyond twice the per-view "
                "spread)")
    return None


def _held_out_cell(name: str, e: HeldOut, refused: dict[str, str], n_views: int) -> str:
    """One model's entry in the reason's table of held-out RMS."""
    if name in refused:
        return "refused"
    r, f = _rms(e), _failed(e)
    u = sum(x is not None and not _scored(x) for x in e)
    if r is None:
        return "failed" if f else "not determined without the held-out views"
    return f"{r:.3f} px" + (f" ({f} of {n_views} views not posed)" if f else "") + (
        f" ({u} views not scored: the views without them do not determine it)" if u else "")


def _reason(chosen: str, why: str, per_view: dict[str, HeldOut], refused: dict[str, str],
            n_views: int) -> str:
    """The one paragraph ``model_choice.reason`` says: the table, the choice and why."""
    table = ", ".join(f"{k} {_held_out_cell(k, per_view[k], refused, n_views)}"
                      for k in AUTO_MODELS)
    if chosen == "plumb_bob":
        reason = (f"kept plumb_bob: held-out RMS {table}; another model must pose more views, "
                  "or lower it by 10 % beyond the per-view noise, to be chosen")
    else:
        reason = f"chose {chosen}: held-out RMS {table}; " + (
            why or f"the models before it were refused ({', '.join(refused)})")
    if refused:
        reason += "; refused: " + "; ".join(f"{k}: {v}" for k, v in refused.items())
    return reason


#: Folds of the held-out comparison: view i is held out in fold i mod 6 (leave-one-out up to
#: 6 views), so every model is solved on 5/6 of the views (a half is too few on a small set).
HELD_OUT_FOLDS = 6


def _held_out_errors(views: list[ViewInput], size: tuple[int, int], model: str,
                     opt: SolveOptions) -> HeldOut:
    """Per view, its RMS (pixels) posed through ``model`` solved on the other folds' views;
    None where the view could not be posed through it (a
    failure of the model on that view), NaN where the fold could not be solved (no
    evidence: the views cannot determine the model)."""
    out: list[float | None] = [None] * len(views)
    idx = np.arange(len(views))
    k = min(len(views), HELD_OUT_FOLDS)
    for f in range(k):
        test_i = idx[f::k]
        train_i = np.setdiff1d(idx, test_i)
        try:
            m, _, _ = fit_with_rules([views[i] for i in train_i], size, model, opt)
        except CalibrationError:
            # views too few or too alike to determine the model are no evidence either way
            for i in test_i:
                out[i] = float("nan")
            continue
        key = lens_key(m.camera)
        theta = param_values(m.camera)
        fixed = np.zeros(theta.size, bool)
        for i in test_i:
            o = np.asarray(views[i].object_points, float).reshape(-1, 3)
            c = np.asarray(views[i].corners, float).reshape(-1, 2)
            p0 = initial_poses(m.camera, [o], [c])
            if p0 is None:
                continue
            r = refine(theta, p0, key, size, [o], [c], fixed)
            if np.isfinite(r.rms_px):
                out[i] = r.rms_px
    return out
