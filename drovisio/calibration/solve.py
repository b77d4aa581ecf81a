"""The calibration solve: intrinsics, per-view errors, outlier views, fixed coefficients,
covariance, projection-uncertainty map and cross-validation.

Rules (stated once here, reported in the result):

* **RMS** (``rms_px``): √(mean over all kept corners of |projected − detected|²), pixels —
  OpenCV's ``calibrateCamera`` return value. Per view the same over that view's corners.
* **Outlier views**: after a solve, the view with the largest per-view RMS is rejected when it
  exceeds both 2.5 × the median per-view RMS and the median + 0.15 px; the solve is repeated
  until no view qualifies (never below 4 views). Such a view disagrees with the others (blur,
  a bent or moving board, a wrong detection).
* **Fixed coefficients** (plumb_bob): k3 (the r⁶ term) is fixed to 0 when the data do not show that it
  differs from 0, i.e. when |k3| < 2·σ(k3) in the free solve (a two-sided 95 % test; it is a
  likelihood-ratio test for one parameter). The fixed model is what is written; the free solve's
  k3 ± σ and its uncertainty are kept in the result (``free_model``), so the choice can be
  checked.
* **Outlier corners**: before the outlier views, a corner farther from its projection than
  5 × the median corner residual (and 0.5 px) is dropped, at most 5 % of a view's corners, and
  listed with its residual (``rejected_corners``).
* **Lens model** (``model``): plumb_bob (5 coefficients), rational (8), thin_prism (12),
  tilted (14) or fisheye (Kannala–Brandt, 4). ``auto`` chooses among plumb_bob, rational and
  fisheye (the thin prism and the tilted sensor are asked for by name): it solves each on one
  half of the views (alternating) and scores it by the RMS of the other half's corners, each
  of those views posed by PnP through the half's model, both ways round; plumb_bob is kept
  unless another model lowers that by 10 % and 0.02 px (``model_choice`` says the figures and
  why). It is chosen before the outlier rules, which need the right model.
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
    UncertaintyMap,
    camera_model,
    covariance_from_information,
    grid_jacobians,
    lens_key,
    model_difference_px,
    param_names,
    param_values,
    projection_uncertainty,
    schur_information,
    sigma_max,
    view_jacobian,
)
from drovisio.camera import Camera

__all__ = ["CalibrationError", "SolveOptions", "ViewInput", "ViewFit", "CalibrationResult",
           "solve", "fit_model", "choose_model", "MODELS", "MODEL_CHOICES",
           "RMS_DEFINITION", "unknown_model"]

RMS_DEFINITION = ("root mean square over all kept corners of the distance between the detected "
                  "corner and the projection of its board point, pixels (OpenCV calibrateCamera)")


class CalibrationError(RuntimeError):
    """The views cannot be calibrated (too few, degenerate); the message says why."""


@dataclass
class SolveOptions:
    """Knobs of :func:`solve` (defaults are the documented rules)."""

    model: str = "plumb_bob"
    """Lens model: one of :data:`MODEL_CHOICES` (``auto``: chosen by held-out views; module
    doc)."""
    fix_k3: str | bool = "auto"
    """"auto" (the 2σ rule), True (always fix) or False (never); plumb_bob only."""
    reject_corners: bool = True
    """Drop single corners that disagree with the model (module doc)."""
    corner_factor: float = 5.0
    corner_margin_px: float = 0.5
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
    board_flatness: bool = False
    """Also estimate how far the board bowed (:mod:`drovisio.calibration.flatness`)."""


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
        return param_values(self.camera)


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
    model_choice: dict | None = None
    """How the lens model was chosen (``auto``): per model its held-out RMS, and why."""
    rejected_corners: list[dict] = field(default_factory=list)
    board_flatness: dict | None = None
    """The board's bow (:func:`drovisio.calibration.flatness.board_flatness`), if asked."""

    @property
    def std(self) -> dict[str, float]:
        return {n: float(s) for n, s in zip(param_names(self.camera), self.model.std)}

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
                       "model": self.camera.model,
                       "camera_matrix": self.camera.K.tolist()},
            "model_choice": self.model_choice,
            "rejected_corners": list(self.rejected_corners),
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
            "board_flatness": self.board_flatness,
        }


# ==================================================================================== solves
MODELS = {"plumb_bob": "plumb_bob", "rational": "rational_polynomial",
          "rational_polynomial": "rational_polynomial", "thin_prism": "thin_prism",
          "tilted": "tilted", "fisheye": "fisheye"}
"""Names ``--model`` takes → the calibration's model names (:func:`lens_key`)."""
MODEL_CHOICES = ("auto", "plumb_bob", "rational", "thin_prism", "tilted", "fisheye")
"""What ``--model`` and the calibration page offer."""
# OpenCV's flags of each model but the fisheye (their coefficients: param_names)
_BROWN_FLAGS = {"plumb_bob": 0,
                "rational_polynomial": cv2.CALIB_RATIONAL_MODEL,
                "thin_prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
                "tilted": (cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL
                           | cv2.CALIB_TILTED_MODEL)}


def unknown_model(model: str) -> str:
    """The one message for a lens model the calibration does not know."""
    return f"unknown lens model {model!r}: use {', '.join(MODEL_CHOICES)}"


_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def _opencv_solve(O, I, size, model: str, fix_k3: bool):
    """OpenCV's calibration of ``model``: (K, distortion, rvecs, tvecs)."""
    if model == "fisheye":
        O64 = [o.astype(np.float64).reshape(1, -1, 3) for o in O]
        I64 = [i.astype(np.float64).reshape(1, -1, 2) for i in I]
        flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
        _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(O64, I64, size, np.eye(3), np.zeros(4),
                                                      flags=flags, criteria=_CRITERIA)
        return K, np.asarray(D, float).ravel()[:4], rvecs, tvecs
    flags, n = _BROWN_FLAGS[model], len(param_names(model)) - 4
    if model == "plumb_bob" and fix_k3:
        flags |= cv2.CALIB_FIX_K3
    _, K, D, rvecs, tvecs = cv2.calibrateCamera(O, I, size, None, None, flags=flags,
                                                criteria=_CRITERIA)
    return K, np.asarray(D, float).ravel()[:n], rvecs, tvecs


def _fit(views: list[ViewInput], size: tuple[int, int], fix_k3: bool,
         model: str = "plumb_bob") -> Model:
    O = [np.asarray(v.object_points, np.float32).reshape(-1, 1, 3) for v in views]
    I = [np.asarray(v.corners, np.float32).reshape(-1, 1, 2) for v in views]
    try:
        K, D, rvecs, tvecs = _opencv_solve(O, I, size, model, fix_k3)
    except cv2.error as e:
        msg = str(e).strip().splitlines()[-1] if str(e).strip() else "OpenCV error"
        raise CalibrationError(f"the {model} solve failed on {len(views)} views ({msg}); the "
                               "views are probably degenerate (all boards parallel, or too "
                               "few)") from None
    K = np.asarray(K, float)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D))) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CalibrationError("the solve diverged (non-finite or negative focal length); "
                               "add views with the board tilted and at other distances")
    cam = Camera(K=K, dist=D, width=size[0], height=size[1], name="camera",
                 model=camera_model(model))
    free = np.ones(len(param_names(model)), bool)
    if model == "plumb_bob":
        free[8] = not fix_k3
    jac, fits, ssr, n_obs = [], [], 0.0, 0
    for v, o, r, t in zip(views, O, rvecs, tvecs):
        A, B, p = view_jacobian(o, r, t, cam)
        jac.append((A, B))
        e2 = np.sum((p - np.asarray(v.corners, float).reshape(-1, 2)) ** 2, axis=1)
        ssr += float(e2.sum())
        n_obs += 2 * len(e2)
        fits.append(ViewFit(v.name, float(np.sqrt(e2.mean())), float(np.sqrt(e2.max())),
                            len(e2), np.asarray(r, float).ravel(), np.asarray(t, float).ravel()))
    dof = n_obs - int(free.sum()) - 6 * len(views)
    if dof <= 0:
        raise CalibrationError(f"{len(views)} views give too few corners for {free.sum()} + "
                               "6·views parameters; add views")
    sigma2 = ssr / dof
    S = schur_information(jac, free)
    cov = covariance_from_information(S, sigma2, free)
    # RMS over all corners (OpenCV's calibrateCamera value; computed here for every model)
    rms = float(np.sqrt(ssr / (n_obs / 2)))
    return Model(cam, rms, fits, free, S, sigma2, cov)


def fit_model(views: list[ViewInput], image_size: tuple[int, int], fix_k3: bool = False,
              model: str = "plumb_bob") -> Model:
    """One solve (no outlier rejection, no model selection)."""
    if len(views) < 3:
        raise CalibrationError(f"{len(views)} usable view(s); a calibration needs at least 3 "
                               "(10 or more, varied, for a good one)")
    return _fit(views, tuple(int(s) for s in image_size), fix_k3, MODELS.get(model, model))


def _fit_with_rules(views: list[ViewInput], size, model: str, opt: SolveOptions
                    ) -> tuple[Model, dict[str, str], dict | None]:
    """One solve of ``model`` with the k3 rule (plumb_bob): (model, fixed, free_model)."""
    fixed: dict[str, str] = {}
    if model != "plumb_bob":
        return fit_model(views, size, model=model), fixed, None
    if opt.fix_k3 is True:
        fixed["k3"] = "fixed to 0 on request"
        return fit_model(views, size, fix_k3=True), fixed, None
    m = fit_model(views, size, fix_k3=False)
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
    rejected: list[dict] = []
    choice = None
    if opt.model == "auto":     # first: the outlier rules need the right lens model
        model_name, choice = choose_model(kept, size, opt)
    else:
        model_name = MODELS[opt.model]
    model = fit_model(kept, size, fix_k3=opt.fix_k3 is True, model=model_name)
    # ---- single corners that disagree (a wrong or smeared corner in a good view), before
    # the views: one such corner must not cost its whole view
    rejected_corners: list[dict] = []
    if opt.reject_corners:
        kept, rejected_corners = _reject_corners(kept, model, opt)
        if rejected_corners:
            model = fit_model(kept, size, fix_k3=opt.fix_k3 is True, model=model_name)
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
        model = fit_model(kept, size, fix_k3=opt.fix_k3 is True, model=model_name)
    # ---- k3
    model, fixed, free_model = _fit_with_rules(kept, size, model_name, opt)
    camera = Camera(K=model.camera.K, dist=model.camera.dist, width=size[0], height=size[1],
                    name=camera_name, model=model.camera.model)
    model.camera = camera
    um = projection_uncertainty(camera, model.covariance, opt.grid_step_px)
    cv_result = _cross_validate(kept, size, "k3" in fixed, um, opt, model_name)
    flatness = None
    if opt.board_flatness:
        from drovisio.calibration.flatness import board_flatness

        flatness = board_flatness(kept, camera, lens_key(camera), model.rms_px, model.fits,
                                  float(model.std[0]))
    return CalibrationResult(camera=camera, rms_px=model.rms_px, per_view=model.fits,
                             rejected=rejected, model=model, fixed=fixed, uncertainty=um,
                             cross_validation=cv_result, free_model=free_model, roi=opt.roi,
                             views=kept, model_choice=choice,
                             rejected_corners=rejected_corners, board_flatness=flatness)


def _reject_corners(views: list[ViewInput], model: Model, opt: SolveOptions
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


def choose_model(views: list[ViewInput], size, opt: SolveOptions) -> tuple[str, dict]:
    """The lens model by held-out views: each model is solved on one half of the views
    (alternating) and scored by the RMS reprojection error of the other half's corners, each
    of those views posed by PnP through the half's model (both ways round). plumb_bob, the
    model every tool reads, is kept unless another lowers the held-out RMS by 10 % and
    0.02 px; of rational and fisheye, the lower wins.

    Returns:
        (camera model name, {"chosen", "reason", "held_out_rms_px": {model: px or None}}).
    """
    if len(views) < 6:
        return "plumb_bob", {
            "chosen": "plumb_bob", "held_out_rms_px": {},
            "reason": f"kept plumb_bob: {len(views)} views are too few to compare lens models "
                      "on held-out views (6 or more)"}
    halves = (views[0::2], views[1::2])
    scores: dict[str, float | None] = {}
    for name in ("plumb_bob", "rational_polynomial", "fisheye"):
        scores[name] = _held_out_rms(halves, size, name, opt)
    base = scores["plumb_bob"]
    others = {k: v for k, v in scores.items() if k != "plumb_bob" and v is not None}
    chosen = "plumb_bob"
    if others:
        best = min(others, key=lambda k: others[k])
        if base is None or (others[best] < 0.9 * base and base - others[best] > 0.02):
            chosen = best

    def fmt(v):
        return "failed" if v is None else f"{v:.3f} px"

    table = ", ".join(f"{k} {fmt(v)}" for k, v in scores.items())
    if chosen == "plumb_bob":
        reason = (f"kept plumb_bob: held-out RMS {table}; another model must lower it by 10 % "
                  "(and 0.02 px) to be chosen")
    else:
        reason = (f"chose {chosen}: held-out RMS {table}; plumb_bob "
                  + ("fails on these views" if base is None else
                     f"is {base / scores[chosen]:.1f}x worse"))
    return chosen, {"chosen": chosen, "reason": reason,
                    "held_out_rms_px": {k: None if v is None else round(v, 4)
                                        for k, v in scores.items()}}


def _held_out_rms(halves, size, model: str, opt: SolveOptions) -> float | None:
    """RMS over the held-out corners of both halves (None: a half fails to solve or pose)."""
    from drovisio.pose import solve_brick_pose

    sq, n = 0.0, 0
    for train, test in (halves, halves[::-1]):
        try:
            m, _, _ = _fit_with_rules(train, size, model, opt)
        except CalibrationError:
            return None
        for v in test:
            obj = np.asarray(v.object_points, float).reshape(-1, 3)
            img = np.asarray(v.corners, float).reshape(-1, 2)
            res = solve_brick_pose(obj, img, m.camera)
            if res is None or not np.isfinite(res.rmse_px):
                return None
            sq += float(res.rmse_px) ** 2 * len(img)
            n += len(img)
    return float(np.sqrt(sq / n)) if n else None


def _cross_validate(views: list[ViewInput], size, fix_k3: bool, um: UncertaintyMap,
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

