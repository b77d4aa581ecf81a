"""The calibration solve: intrinsics, per-view errors, outlier views, fixed coefficients,
covariance, projection-uncertainty map and cross-validation.

Rules (stated once here, reported in the result):

* **RMS** (``rms_px``): √(mean over all kept corners of |projected − detected|²), pixels —
  OpenCV's ``calibrateCamera`` return value. Per view the same over that view's corners.
* **Outlier views**: after a solve, the view with the largest per-view RMS is rejected when it
  exceeds both 2.5 × the median per-view RMS and the median + 0.15 px; the solve is repeated
  until no view qualifies (never below 4 views). Such a view disagrees with the others (blur,
  a bent or moving board, a wrong detection).
* **Fixed coefficients**: k3 (the r⁶ term) is fixed to 0 when the data do not show that it
  differs from 0, i.e. when |k3| < 2·σ(k3) in the free solve (a two-sided 95 % test; it is a
  likelihood-ratio test for one parameter). The fixed model is what is written; the free solve's
  k3 ± σ and its uncertainty are kept in the result (``free_model``), so the choice can be
  checked.
* **Covariance / uncertainty map**: see :mod:`drovisio.calibration.uncertainty`.
* **Cross-validation**: the kept views are split into two disjoint halves (alternating views),
  each is solved with the same model, and the two models are compared over the image:
  |π_B(ray_A(q)) − q| on the uncertainty grid, pixels (p50, p95, max), with the camera frame
  fixed (comparable with the uncertainty map) and after the rotation that best aligns the two
  frames (a principal-point difference is mostly such a rotation). It needs 8 views.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio.calibration.uncertainty import (
    PARAM_NAMES,
    UncertaintyMap,
    covariance_from_information,
    grid_jacobians,
    model_difference_px,
    projection_uncertainty,
    schur_information,
    sigma_max,
    view_jacobian,
)
from drovisio.camera import Camera

__all__ = ["CalibrationError", "SolveOptions", "ViewInput", "ViewFit", "CalibrationResult",
           "solve", "fit_model", "RMS_DEFINITION"]

RMS_DEFINITION = ("root mean square over all kept corners of the distance between the detected "
                  "corner and the projection of its board point, pixels (OpenCV calibrateCamera)")


class CalibrationError(RuntimeError):
    """The views cannot be calibrated (too few, degenerate); the message says why."""


@dataclass
class SolveOptions:
    """Knobs of :func:`solve` (defaults are the documented rules)."""

    fix_k3: str | bool = "auto"
    """"auto" (the 2σ rule), True (always fix) or False (never)."""
    k3_significance: float = 2.0
    outlier_factor: float = 2.5
    outlier_margin_px: float = 0.15
    min_views: int = 4
    """Never reject views below this count."""
    cross_validate: bool = True
    min_views_cross_validation: int = 8
    grid_step_px: float = 16.0
    roi: tuple[float, float, float, float] | None = None
    """Image region (x0, y0, x1, y1) where the statistics are taken (None: whole image)."""


@dataclass
class ViewInput:
    """What the solve needs from a view: its corners and their board points."""

    name: str
    corners: np.ndarray
    object_points: np.ndarray


@dataclass
class ViewFit:
    """A kept view after the solve."""

    name: str
    rms_px: float
    max_px: float
    n_corners: int
    rvec: np.ndarray
    tvec: np.ndarray

    def to_json(self) -> dict:
        return {"file": self.name, "rms_px": round(self.rms_px, 5),
                "max_px": round(self.max_px, 5), "corners": self.n_corners,
                "rvec": np.round(self.rvec, 6).tolist(), "tvec": np.round(self.tvec, 6).tolist()}


@dataclass
class Model:
    """One solve of a fixed set of views and a fixed parameter set."""

    camera: Camera
    rms_px: float
    fits: list[ViewFit]
    free: np.ndarray
    information: np.ndarray
    sigma2: float
    covariance: np.ndarray

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def values(self) -> np.ndarray:
        c = self.camera
        d = np.zeros(5)
        d[: min(5, c.dist.size)] = c.dist[:5]
        return np.array([c.fx, c.fy, c.cx, c.cy, *d])


@dataclass
class CalibrationResult:
    """Everything the solve found. ``to_json`` gives the report fields."""

    camera: Camera
    rms_px: float
    per_view: list[ViewFit]
    rejected: list[dict]
    model: Model
    fixed: dict[str, str]
    uncertainty: UncertaintyMap
    cross_validation: dict
    free_model: dict | None = None
    roi: tuple[float, float, float, float] | None = None
    views: list[ViewInput] = field(default_factory=list, repr=False)

    @property
    def std(self) -> dict[str, float]:
        return {n: float(s) for n, s in zip(PARAM_NAMES, self.model.std)}

    @property
    def covariance(self) -> np.ndarray:
        return self.model.covariance

    def uncertainty_stats(self) -> dict:
        return self.uncertainty.stats(self.roi)

    def to_json(self) -> dict:
        return {
            "camera": {"width": self.camera.width, "height": self.camera.height,
                       "fx": self.camera.fx, "fy": self.camera.fy, "cx": self.camera.cx,
                       "cy": self.camera.cy, "dist": self.camera.dist.tolist(),
                       "camera_matrix": self.camera.K.tolist()},
            "rms_px": self.rms_px,
            "rms_definition": RMS_DEFINITION,
            "corner_noise_px": float(np.sqrt(self.model.sigma2)),
            "per_view": [v.to_json() for v in self.per_view],
            "rejected": list(self.rejected),
            "std": self.std,
            "fixed": dict(self.fixed),
            "free_model": self.free_model,
            "uncertainty_px": {**self.uncertainty_stats(),
                               "definition": "1-sigma projection uncertainty in the worst "
                                             "image direction, over a grid covering the "
                                             + ("region of interest" if self.roi else "image"),
                               "grid_step_px": float(self.uncertainty.xs[1]
                                                     - self.uncertainty.xs[0])},
            "cross_validation_px": self.cross_validation,
        }


# ==================================================================================== solves
def _fit(views: list[ViewInput], size: tuple[int, int], fix_k3: bool) -> Model:
    O = [np.asarray(v.object_points, np.float32).reshape(-1, 1, 3) for v in views]
    I = [np.asarray(v.corners, np.float32).reshape(-1, 1, 2) for v in views]
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    try:
        rms, K, D, rvecs, tvecs = cv2.calibrateCamera(
            O, I, size, None, None, flags=flags,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    except cv2.error as e:
        msg = str(e).strip().splitlines()[-1] if str(e).strip() else "OpenCV error"
        raise CalibrationError(f"the solve failed on {len(views)} views ({msg}); the views are "
                               "probably degenerate (all boards parallel, or too few)") from None
    K = np.asarray(K, float)
    D = np.asarray(D, float).ravel()[:5]
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D))) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CalibrationError("the solve diverged (non-finite or negative focal length); "
                               "add views with the board tilted and at other distances")
    free = np.ones(9, bool)
    free[8] = not fix_k3
    jac, fits, ssr, n_obs = [], [], 0.0, 0
    for v, o, r, t in zip(views, O, rvecs, tvecs):
        A, B, p = view_jacobian(o, r, t, K, D)
        jac.append((A, B))
        e2 = np.sum((p - np.asarray(v.corners, float).reshape(-1, 2)) ** 2, axis=1)
        ssr += float(e2.sum())
        n_obs += 2 * len(e2)
        fits.append(ViewFit(v.name, float(np.sqrt(e2.mean())), float(np.sqrt(e2.max())),
                            len(e2), np.asarray(r, float).ravel(), np.asarray(t, float).ravel()))
    dof = n_obs - int(free.sum()) - 6 * len(views)
    if dof <= 0:
        raise CalibrationError(f"{len(views)} views give too few corners for 9 + 6·views "
                               "parameters; add views")
    sigma2 = ssr / dof
    S = schur_information(jac, free)
    cov = covariance_from_information(S, sigma2, free)
    cam = Camera(K=K, dist=D, width=size[0], height=size[1], name="camera")
    return Model(cam, float(rms), fits, free, S, sigma2, cov)


def fit_model(views: list[ViewInput], image_size: tuple[int, int], fix_k3: bool = False
              ) -> Model:
    """One solve (no outlier rejection, no model selection)."""
    if len(views) < 3:
        raise CalibrationError(f"{len(views)} usable view(s); a calibration needs at least 3 "
                               "(10 or more, varied, for a good one)")
    return _fit(views, tuple(int(s) for s in image_size), fix_k3)


def solve(views: list[ViewInput], image_size: tuple[int, int],
          options: SolveOptions | None = None, camera_name: str = "camera") -> CalibrationResult:
    """Calibrate from views of a board (see the module docstring for the rules).

    Raises:
        CalibrationError: fewer than 3 views, or a degenerate set.
    """
    opt = options or SolveOptions()
    size = (int(image_size[0]), int(image_size[1]))
    kept = list(views)
    rejected: list[dict] = []
    force_fix = opt.fix_k3 is True
    model = fit_model(kept, size, fix_k3=force_fix)
    # ---- outlier views, worst first
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
        model = fit_model(kept, size, fix_k3=force_fix)
    # ---- k3: keep it only if the data determine it
    fixed: dict[str, str] = {}
    free_model = None
    if force_fix:
        fixed["k3"] = "fixed to 0 on request"
    elif opt.fix_k3 == "auto":
        k3, s3 = float(model.camera.dist[4]), float(model.std[8])
        if abs(k3) < opt.k3_significance * s3:
            free_um = projection_uncertainty(model.camera, model.covariance, opt.grid_step_px)
            free_model = {"k3": k3, "k3_std": s3, "rms_px": model.rms_px,
                          "uncertainty_px": free_um.stats(opt.roi)}
            fixed["k3"] = (f"fixed to 0: the data do not determine it (free solve: k3 = {k3:.4g}"
                           f" ± {s3:.2g}, |k3| < {opt.k3_significance:g}σ); the uncertainty map "
                           "is conditioned on k3 = 0")
            model = fit_model(kept, size, fix_k3=True)
    camera = Camera(K=model.camera.K, dist=model.camera.dist, width=size[0], height=size[1],
                    name=camera_name)
    model.camera = camera
    um = projection_uncertainty(camera, model.covariance, opt.grid_step_px)
    cv_result = _cross_validate(kept, size, "k3" in fixed, um, opt)
    return CalibrationResult(camera=camera, rms_px=model.rms_px, per_view=model.fits,
                             rejected=rejected, model=model, fixed=fixed, uncertainty=um,
                             cross_validation=cv_result, free_model=free_model, roi=opt.roi,
                             views=kept)


def _cross_validate(views: list[ViewInput], size, fix_k3: bool, um: UncertaintyMap,
                    opt: SolveOptions) -> dict:
    """The two halves' models compared (a diagnostic: it never stops a calibration)."""
    try:
        return _compare_halves(views, size, fix_k3, um, opt)
    except Exception as e:  # noqa: BLE001 - a diagnostic degrades, it never kills the solve
        return {"p50": None, "p95": None, "max": None,
                "skipped": f"not computed: {type(e).__name__}: {e}"}


def _compare_halves(views: list[ViewInput], size, fix_k3: bool, um: UncertaintyMap,
                    opt: SolveOptions) -> dict:
    if not opt.cross_validate:
        return {"p50": None, "p95": None, "max": None, "skipped": "disabled"}
    if len(views) < opt.min_views_cross_validation:
        return {"p50": None, "p95": None, "max": None,
                "skipped": f"needs {opt.min_views_cross_validation} views, have {len(views)}"}
    a, b = views[0::2], views[1::2]
    try:
        ma = fit_model(a, size, fix_k3)
        mb = fit_model(b, size, fix_k3)
    except CalibrationError as e:
        return {"p50": None, "p95": None, "max": None, "skipped": str(e)}
    m = um.mask(opt.roi)
    d = model_difference_px(ma.camera, mb.camera, um.xs, um.ys)
    # the difference expected from the halves' own covariances: z = d / σ_{A−B}
    s_ab = sigma_max(grid_jacobians(ma.camera, um.xs, um.ys), ma.covariance + mb.covariance)
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

