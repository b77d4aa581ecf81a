"""The whole calibration solve: the lens model, outlier corners and views, the k3 rule, the
uncertainty map, cross-validation and the board's bow."""

from __future__ import annotations

from typing import Any

import numpy as np

from drovisio.calibration.flatness import board_flatness
from drovisio.calibration.solve.choice import choose_model
from drovisio.calibration.solve.cross_validation import cross_validate
from drovisio.calibration.solve.fit import fit_model
from drovisio.calibration.solve.models import MODELS, unknown_model
from drovisio.calibration.solve.results import (
    CalibrationError,
    CalibrationResult,
    Model,
    SolveOptions,
    ViewInput,
)
from drovisio.calibration.solve.rules import fit_with_rules, reject_corners
from drovisio.calibration.uncertainty import lens_key, projection_uncertainty
from drovisio.camera import Camera


def solve(views: list[ViewInput], image_size: tuple[int, int],
          options: SolveOptions | None = None, camera_name: str = "camera") -> CalibrationResult:
    """Calibrate from views of a board (see the module docstring for the rules).

    Raises:
        CalibrationError: fewer than 3 views, or a degenerate set, or an unknown model.
    """
    opt = options or SolveOptions()
    size = (int(image_size[0]), int(image_size[1]))
    if opt.model != "auto" and opt.model not in MODELS:
        raise CalibrationError(unknown_model(opt.model))
    kept = list(views)
    choice = None
    if opt.model == "auto":     # first: the outlier rules need the right lens model
        model_name, choice = choose_model(kept, size, opt)
    else:
        model_name = MODELS[opt.model]
    model = fit_model(kept, size, fix_k3=opt.fix_k3 is True, model=model_name)
    # ---- single corners that disagree (a wrong or smeared corner in a good view), before
    # the views: one such corner must not cost its whole view
    rejected_corners: list[dict[str, Any]] = []
    if opt.reject_corners:
        kept, rejected_corners = reject_corners(kept, model, opt)
        if rejected_corners:
            model = fit_model(kept, size, fix_k3=opt.fix_k3 is True, model=model_name)
    # ---- outlier views, worst first
    kept, model, rejected = _reject_views(kept, model, size, model_name, opt)
    # ---- k3
    model, fixed, free_model = fit_with_rules(kept, size, model_name, opt)
    camera = Camera(K=model.camera.K, dist=model.camera.dist, width=size[0], height=size[1],
                    name=camera_name, model=model.camera.model)
    model.camera = camera
    um = projection_uncertainty(camera, model.covariance, opt.grid_step_px)
    cv_result = cross_validate(kept, size, "k3" in fixed, um, opt, model_name)
    flatness = None
    if opt.board_flatness:
        flatness = board_flatness(kept, camera, lens_key(camera), model.rms_px, model.fits,
                                  float(model.std[0]))
    return CalibrationResult(camera=camera, rms_px=model.rms_px, per_view=model.fits,
                             rejected=rejected, model=model, fixed=fixed, uncertainty=um,
                             cross_validation=cv_result, free_model=free_model, roi=opt.roi,
                             views=kept, model_choice=choice,
                             rejected_corners=rejected_corners, board_flatness=flatness)


def _reject_views(views: list[ViewInput], model: Model, size: tuple[int, int], model_name: str,
                  opt: SolveOptions) -> tuple[list[ViewInput], Model, list[dict[str, Any]]]:
    """Outlier views, worst first, each followed by a new solve (the module doc's rule).

    Returns:
        (the kept views, their model, the rejected views with their reasons).
    """
    kept = list(views)
    rejected: list[dict[str, Any]] = []
    while len(kept) > max(opt.min_views, 3):
        errs = np.array([f.rms_px for f in model.fits])
        med = float(np.median(errs))
        worst = int(np.argmax(errs))
        limit = max(opt.outlier_factor * med, med + opt.outlier_margin_px)
        if errs[worst] <= limit:
            break
        rejected.append({
            "file": kept[worst].name,
            "reason": (f"outlier: reprojection RMS {errs[worst]:.3f} px is "
                       f"{errs[worst] / max(med, 1e-12):.1f}x the median of the views "
                       f"({med:.3f} px); its corners disagree with the other views (blur, a "
                       "moving or bent board, or a wrong detection)"),
            "rms_px": float(errs[worst])})
        kept.pop(worst)
        model = fit_model(kept, size, fix_k3=opt.fix_k3 is True, model=model_name)
    return kept, model, rejected
