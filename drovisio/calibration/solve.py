"""The calibration solve: intrinsics, per-view errors, outlier views, fixed coefficients,
covariance, projection-uncertainty map and cross-validation.

Rules (stated once here, reported in the result):

* **RMS** (``rms_px``): √(mean over all kept corners of |projected − detected|²), pixels —
  OpenCV's ``calibrateCamera`` return value. Per view the same over that view's corners.
* **Outlier views**: after a solve, the view with the largest per-view RMS is rejected when it
  exceeds both 2.5 × the median per-view RMS and the median + 0.15 px; the solve is repeated
  until no view qualifies (never below 4 views). Such a view disagrees with the others (blur,
  a bent or moving board, a wrong detection).
* **The solver** (:mod:`drovisio.calibration.lm`): Levenberg–Marquardt over the intrinsics
  and every board pose, each step accepted only when it lowers the RMS (which therefore
  never grows), serial (the same views give the same numbers, bit for bit, with one thread
  or many). Every model starts from the solve of the same corners by a simpler one: OpenCV's
  closed-form pinhole start (``initCameraMatrix2D``) → pinhole → plumb_bob (k1 k2 p1 p2,
  then k3) → rational / thin prism / tilted from plumb_bob's coefficients; the fisheye from
  plumb_bob's K, else the pinhole's K, else its own closed form (f = diagonal / π, centred),
  k1 k2 first, then all four.
* **Converged and determined, or refused** (:func:`_diagnose`): a solve is not written when
  its lens mapping folds back (stops growing with the angle from the axis) inside the field
  the board covered, when its RMS exceeds both 10 × the corners' own noise
  (:func:`corner_noise_px`, measured without a lens model) and that noise + 2 px, or when
  the 1-σ of fx, fy, cx or cy exceeds 10 % of the focal length. It is then solved again from
  the next start, then with its highest-order coefficients held at 0 (fisheye k3 k4,
  rational k4–k6, plumb_bob k3; said in ``fixed``), and otherwise refused in one line that
  names the model, the cause and the fix.
* **Fixed coefficients**: k3 (the r⁶ term) of plumb_bob is fixed to 0 when the data do not
  show that it differs from 0, i.e. when |k3| < 2·σ(k3) in the free solve (a two-sided 95 %
  test; it is a likelihood-ratio test for one parameter). The fixed model is what is written;
  the free solve's k3 ± σ and its uncertainty are kept in the result (``free_model``), so the
  choice can be checked. The same rule holds the other models' highest-order coefficients
  (fisheye k3 k4, rational k4–k6...) at 0 when any of them is within 2σ of 0.
* **Outlier corners**: before the outlier views, a corner farther from its projection than
  5 × the median corner residual (and 0.5 px) is dropped, at most 5 % of a view's corners, and
  listed with its residual (``rejected_corners``).
* **Lens model** (``model``): plumb_bob (5 coefficients), rational (8), thin_prism (12),
  tilted (14) or fisheye (Kannala–Brandt, 4). ``auto`` chooses among plumb_bob, fisheye and
  rational (the thin prism and the tilted sensor are asked for by name), see
  :func:`choose_model`: a model that does not converge on all views, or that they do not
  determine, is refused; each model is solved without every sixth view (6 folds) and scored
  per held-out view posed through it; a view a model cannot pose is its failure on that view
  only, and a fold a model cannot solve is no evidence either way. From fewer coefficients to
  more, a model replaces the one chosen when it poses more views and is not worse (10 %) on
  those both posed, or is 10 % better there beyond twice the per-view standard error
  (``model_choice`` says the figures and why). It is chosen before the outlier rules, which
  need the right model.
* **Covariance / uncertainty map**: see :mod:`drovisio.calibration.uncertainty`.
* **Cross-validation**: the kept views are split into two disjoint halves (alternating views),
  each is solved with the same model, and the two models are compared over the image:
  |π_B(ray_A(q)) − q| on the uncertainty grid, pixels (p50, p95, max), with the camera frame
  fixed (comparable with the uncertainty map) and after the rotation that best aligns the two
  frames (a principal-point difference is mostly such a rotation). It needs 8 views.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio.calibration.lm import Refined, initial_poses, make_camera, refine
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
           "solve", "fit_model", "choose_model", "corner_noise_px", "MODELS", "MODEL_CHOICES",
           "AUTO_MODELS", "RMS_DEFINITION", "unknown_model", "clear_cache"]

RMS_DEFINITION = ("root mean square over all kept corners of the distance between the detected "
                  "corner and the projection of its board point, pixels (OpenCV calibrateCamera)")


class CalibrationError(RuntimeError):
    """The views cannot be calibrated (too few, degenerate, or no model converged on them);
    the message says why and what to do, in one line."""


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
    rms_history: list[float] = field(default_factory=list)
    """RMS after each accepted step of the last stage (never growing)."""
    start: str = ""
    """Where the solve started (e.g. "plumb_bob K" for the fisheye)."""
    retry_note: str | None = None
    """Set when the full model was refused and fewer coefficients were solved instead."""

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


def _fail_line(model: str, cause: str, fix: str) -> str:
    return f"the {model} solve {cause}; {fix}"


_STAGES_CACHE: OrderedDict[bytes, tuple[Refined, Refined]] = OrderedDict()
_STAGES_LOCK = threading.Lock()


def _pinhole_stages(O, I, size, fix_k3: bool) -> tuple[Refined, Refined]:
    """The pinhole solve (no distortion) and the plumb_bob solve started from it, k1 k2 p1 p2
    first, then k3 unless fixed: every other model starts from these. Kept for the last 64
    sets of views (``auto`` solves three models on the same views and folds)."""
    h = hashlib.sha1(repr((tuple(size), bool(fix_k3))).encode())
    for o, i in zip(O, I):
        h.update(np.ascontiguousarray(o, np.float64).tobytes())
        h.update(np.ascontiguousarray(i, np.float64).tobytes())
    key = h.digest()
    with _STAGES_LOCK:
        if key in _STAGES_CACHE:
            _STAGES_CACHE.move_to_end(key)
            return _STAGES_CACHE[key]
    out = _solve_pinhole_stages(O, I, size, fix_k3)
    with _STAGES_LOCK:
        _STAGES_CACHE[key] = out
        while len(_STAGES_CACHE) > 64:
            _STAGES_CACHE.popitem(last=False)
    return out


def clear_cache() -> None:
    """Forget the pinhole solves kept for reuse (tests that compare fresh solves)."""
    with _STAGES_LOCK:
        _STAGES_CACHE.clear()


def _solve_pinhole_stages(O, I, size, fix_k3: bool) -> tuple[Refined, Refined]:
    try:
        K0 = cv2.initCameraMatrix2D([o.astype(np.float32) for o in O],
                                    [i.astype(np.float32) for i in I], size)
    except cv2.error:
        K0 = None
    if K0 is None or not np.all(np.isfinite(K0)) or K0[0, 0] <= 0 or K0[1, 1] <= 0:
        raise CalibrationError(
            f"no pinhole camera fits the {len(O)} views (OpenCV's closed-form start failed): "
            "the boards are probably all parallel to the image; add views with the board "
            "tilted 20-40 degrees toward each side")
    th = np.r_[K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], np.zeros(5)]
    poses = initial_poses(make_camera(th, "plumb_bob", size), O, I)
    if poses is None:
        raise CalibrationError("a board cannot be posed through the closed-form pinhole start; "
                               "check --board and --square against the printed board")
    free = np.zeros(9, bool)
    free[:4] = True
    pin = refine(th, poses, "plumb_bob", size, O, I, free)
    free[4:8] = True
    pb = refine(pin.theta, pin.poses, "plumb_bob", size, O, I, free)
    if not fix_k3:
        free[8] = True
        pb = refine(pb.theta, pb.poses, "plumb_bob", size, O, I, free)
    return pin, pb


def _fisheye_starts(pin: Refined, pb: Refined, size) -> list[tuple[str, np.ndarray]]:
    """Starts of the fisheye solve: the plumb_bob and pinhole solves' K, and the
    equidistant model's own closed form for a lens whose image circle fills the diagonal
    (f = diagonal / π, centred: OpenCV's fisheye start)."""
    f0 = float(np.hypot(*size)) / np.pi
    return [("plumb_bob K", pb.theta[:4]), ("pinhole K", pin.theta[:4]),
            ("equidistant closed form",
             np.array([f0, f0, (size[0] - 1) / 2.0, (size[1] - 1) / 2.0]))]


def _candidates(O, I, size, model: str, stages: tuple[Refined, Refined],
                fixed_coefficients: int = 0) -> Iterator[tuple[Refined, str]]:
    """Solves of ``model``, one per start, lazily (the caller stops at the first that
    passes :func:`_diagnose`): every non-pinhole model starts from the pinhole / plumb_bob
    solve of the same corners ``stages`` (module doc). ``fixed_coefficients`` holds that
    many of the model's highest-order coefficients at 0 (a retry with fewer free
    coefficients).

    Yields:
        (refined solve, which start it came from).
    """
    pin, pb = stages
    if model == "plumb_bob":
        yield pb, "pinhole solve"
        return
    n = len(param_names(model))
    free = np.ones(n, bool)
    if fixed_coefficients:
        free[n - fixed_coefficients:] = False
    if model == "fisheye":
        for name, k in _fisheye_starts(pin, pb, size):
            th = np.r_[k, np.zeros(4)]
            poses = initial_poses(make_camera(th, "fisheye", size), O, I)
            if poses is None:
                continue
            stage = free.copy()
            stage[6:] = False           # k1 k2 first: fewer free coefficients, then all
            r = refine(th, poses, "fisheye", size, O, I, stage)
            if np.any(free[6:]):
                r = refine(r.theta, r.poses, "fisheye", size, O, I, free)
            yield r, name
        return
    th = np.zeros(n)
    th[:9] = pb.theta
    yield refine(th, pb.poses, model, size, O, I, free), "plumb_bob solve"


#: How many of a model's highest-order coefficients a retry holds at 0 ("fewer free
#: coefficients"): fisheye k3 k4, rational k4-k6, thin prism s1-s4, tilted tx ty.
_RETRY_FIXED = {"plumb_bob": 1, "rational_polynomial": 3, "thin_prism": 4, "tilted": 2,
                "fisheye": 2}
#: A solve whose 1-σ focal length or principal point is this fraction of the focal length
#: (of the image side) is not determined by its views: it is refused, never written.
MAX_RELATIVE_SIGMA = 0.1
#: A solve whose RMS exceeds both this many times the corner noise and the noise + 2 px has
#: not found the lens (the corners disagree with the model far beyond their own noise).
MAX_RMS_OVER_NOISE = 10.0


def corner_noise_px(views: list[ViewInput]) -> float | None:
    """The corners' own noise, measured without any lens model, pixels (1-σ per axis).

    Every corner with its 8 grid neighbours (a 3 × 3 patch of the board) is fitted by a
    quadratic map from board to image (6 coefficients per axis: perspective and distortion
    are smooth over two squares); the residual variance of a patch is SSR / 6 (9 points, 6
    coefficients, 2 axes), and the noise is the median over all patches corrected for the
    median of χ²₆/6 (0.891). Board bow, print errors and any lens are smooth at this scale
    and are not counted: this is a lower bound of what a perfect model could reach.

    Returns:
        None when no view has a complete 3 × 3 patch.
    """
    vals: list[float] = []
    for v in views:
        o = np.asarray(v.object_points, float).reshape(-1, 3)[:, :2]
        c = np.asarray(v.corners, float).reshape(-1, 2)
        if len(o) < 9:
            continue
        dist = np.hypot(o[:, None, 0] - o[None, :, 0], o[:, None, 1] - o[None, :, 1])
        pos = dist[dist > 1e-12]
        if pos.size == 0:
            continue
        sq = float(pos.min())
        for i in range(len(o)):
            nb = np.flatnonzero(dist[i] < 1.5 * sq)
            if nb.size != 9:
                continue
            u = (o[nb] - o[i]) / sq
            M = np.stack([np.ones(9), u[:, 0], u[:, 1], u[:, 0] ** 2, u[:, 0] * u[:, 1],
                          u[:, 1] ** 2], axis=1)
            res = c[nb] - M @ np.linalg.lstsq(M, c[nb], rcond=None)[0]
            vals.append(float((res ** 2).sum()) / 6.0)
    if not vals:
        return None
    return float(np.sqrt(np.median(vals) / 0.8914))


def _field_radius(cam: Camera, O, fits: list[ViewFit]) -> float:
    """The largest angle from the optical axis (radians) at which the views saw a corner."""
    worst = 0.0
    for o, f in zip(O, fits):
        R = cv2.Rodrigues(np.asarray(f.rvec, float))[0]
        X = np.asarray(o, float).reshape(-1, 3) @ R.T + np.asarray(f.tvec, float)
        worst = max(worst, float(np.max(np.arctan2(np.hypot(X[:, 0], X[:, 1]), X[:, 2]))))
    return worst


def _fold_angle(cam: Camera, theta_max: float) -> float | None:
    """The first angle from the axis (radians, up to ``theta_max``) where the lens model's
    radial mapping stops growing (a folded model: two rays on one pixel), None if it grows
    all the way."""
    th = np.linspace(0.0, min(theta_max, np.pi / 2 - 1e-3), 400)[1:]
    if cam.is_fisheye:
        k1, k2, k3, k4 = cam.dist
        t2 = th * th
        r = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    else:
        d = np.zeros(8)
        d[: min(8, cam.dist.size)] = cam.dist[:8]
        x = np.tan(th)
        x2 = x * x
        num = 1 + x2 * (d[0] + x2 * (d[1] + x2 * d[4]))
        den = 1 + x2 * (d[5] + x2 * (d[6] + x2 * d[7]))
        if np.any(den <= 0):
            return float(th[int(np.argmax(den <= 0))])
        r = x * num / den
    bad = np.flatnonzero(np.diff(r) <= 0)
    return None if bad.size == 0 else float(th[bad[0]])


def _diagnose(m: Model, O, noise: float | None) -> tuple[str, str] | None:
    """Why a solve cannot be written ((cause, fix)), or None: it did not converge (folded
    lens mapping inside the field the board covered, residuals far above the corner noise)
    or its views do not determine it (focal length or principal point uncertain by
    :data:`MAX_RELATIVE_SIGMA`)."""
    cam = m.camera
    key = lens_key(cam)
    other = ("or try --model plumb_bob" if key == "fisheye" else
             "or try --model fisheye for a wide lens")
    field_max = _field_radius(cam, O, m.fits)
    fold = _fold_angle(cam, field_max)
    coeffs = ", ".join(f"{n} = {v:.4g}" for n, v in zip(param_names(cam)[4:], cam.dist)
                       if abs(v) > 0)
    if fold is not None:
        return (f"did not converge: its lens mapping folds back {np.degrees(fold):.0f}° from "
                f"the axis, inside the {np.degrees(field_max):.0f}° the board covered "
                f"({coeffs})", "add views with the board near the image corners and edges, "
                + other)
    if noise is not None and m.rms_px > max(MAX_RMS_OVER_NOISE * noise, noise + 2.0):
        return (f"did not converge: RMS {m.rms_px:.2f} px, far above the corners' own noise "
                f"({noise:.2f} px, measured without a lens model)", "check --board and "
                "--square and that the board is flat, remove views of a moving board, "
                + other)
    sd = m.std
    rel = np.array([sd[0] / cam.fx, sd[1] / cam.fy, sd[2] / cam.fx, sd[3] / cam.fy])
    if not np.all(np.isfinite(rel)) or rel.max() > MAX_RELATIVE_SIGMA:
        worst = int(np.nanargmax(np.where(np.isfinite(rel), rel, np.inf)))
        name = ("fx", "fy", "cx", "cy")[worst]
        return (f"is not determined by these views: 1-sigma of {name} is "
                f"{rel[worst] * 100:.0f} % of the focal length" if np.isfinite(rel[worst])
                else f"is not determined by these views: {name} has no finite uncertainty",
                "add views with the board tilted toward each side and at other distances, "
                "or use a model with fewer coefficients")
    return None


def _model_from(ref: Refined, views: list[ViewInput], O, I, size, key: str,
                free: np.ndarray) -> Model:
    """The :class:`Model` (fits, covariance) of a refined solve."""
    cam = make_camera(ref.theta, key, size)
    cam = Camera(K=cam.K, dist=cam.dist, width=size[0], height=size[1], name="camera",
                 model=camera_model(key))
    jac, fits, ssr, n_obs = [], [], 0.0, 0
    for v, o, i, p in zip(views, O, I, ref.poses):
        A, B, px = view_jacobian(o, p[:3], p[3:], cam)
        jac.append((A, B))
        e2 = np.sum((px - i) ** 2, axis=1)
        ssr += float(e2.sum())
        n_obs += 2 * len(e2)
        fits.append(ViewFit(v.name, float(np.sqrt(e2.mean())), float(np.sqrt(e2.max())),
                            len(e2), p[:3].copy(), p[3:].copy()))
    dof = n_obs - int(free.sum()) - 6 * len(views)
    if dof <= 0:
        raise CalibrationError(f"{len(views)} views give too few corners for {free.sum()} + "
                               "6·views parameters; add views")
    sigma2 = ssr / dof
    S = schur_information(jac, free)
    cov = covariance_from_information(S, sigma2, free)
    # RMS over all corners (OpenCV's calibrateCamera definition, for every model)
    rms = float(np.sqrt(ssr / (n_obs / 2)))
    return Model(cam, rms, fits, free, S, sigma2, cov, rms_history=list(ref.rms_history))


def _fit(views: list[ViewInput], size: tuple[int, int], fix_k3: bool,
         model: str = "plumb_bob", noise: float | None = None,
         fixed_coefficients: int = 0) -> Model:
    """Solve ``model`` and check it (:func:`_diagnose`); a solve that fails the check is
    retried with its highest-order coefficients held at 0, and refused when that fails too.

    Raises:
        CalibrationError: one line: the model, the cause, the fix.
    """
    O = [np.asarray(v.object_points, np.float64).reshape(-1, 3) for v in views]
    I = [np.asarray(v.corners, np.float64).reshape(-1, 2) for v in views]
    if noise is None:
        noise = corner_noise_px(views)
    n = len(param_names(model))
    tries = [fixed_coefficients] if fixed_coefficients else [0, _RETRY_FIXED[model]]
    if model == "plumb_bob" and fix_k3:
        tries = [1]
    first: tuple[str, str] | None = None
    stages: dict[bool, tuple[Refined, Refined]] = {}
    for k in tries:
        k3_fixed = fix_k3 or (model == "plumb_bob" and k > 0)
        if k3_fixed not in stages:
            stages[k3_fixed] = _pinhole_stages(O, I, size, k3_fixed)
        free = np.ones(n, bool)
        if k:
            free[n - k:] = False
        for ref, start in _candidates(O, I, size, model, stages[k3_fixed], k):
            if not np.isfinite(ref.rms_px):
                why: tuple[str, str] | None = (f"diverged from the {start} (no finite "
                                               "reprojection)", "add varied views")
            else:
                m = _model_from(ref, views, O, I, size, model, free)
                why = _diagnose(m, O, noise)
                if why is None:
                    m.start = start
                    if k and first is not None and not (model == "plumb_bob" and fix_k3):
                        names = ", ".join(param_names(model)[n - k:])
                        m.retry_note = (f"{names} held at 0: with them free the solve "
                                        f"{first[0]}")
                    return m
            first = first or why
        if first is None:
            first = ("found no start: no start's lens model sees the corners",
                     "check --board and --square, or try --model plumb_bob")
    assert first is not None
    raise CalibrationError(_fail_line(model, *first))


def fit_model(views: list[ViewInput], image_size: tuple[int, int], fix_k3: bool = False,
              model: str = "plumb_bob", fixed_coefficients: int = 0) -> Model:
    """One solve (no outlier rejection, no model selection); ``fixed_coefficients`` holds
    that many of the model's highest-order coefficients at 0."""
    if len(views) < 3:
        raise CalibrationError(f"{len(views)} usable view(s); a calibration needs at least 3 "
                               "(10 or more, varied, for a good one)")
    return _fit(views, (int(image_size[0]), int(image_size[1])), fix_k3,
                MODELS.get(model, model), fixed_coefficients=fixed_coefficients)


def _chi2_quantile(dof: int, sigmas: float) -> float:
    """The χ² of ``dof`` degrees of freedom exceeded with the probability of a two-sided
    ``sigmas``-σ normal deviation (dof 1: sigmas²), by bisection on the regularised gamma."""
    from math import erf, exp, lgamma, log, sqrt

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


def _fit_with_rules(views: list[ViewInput], size, model: str, opt: SolveOptions
                    ) -> tuple[Model, dict[str, str], dict | None]:
    """One solve of ``model`` with the k3 rule (plumb_bob): (model, fixed, free_model)."""
    fixed: dict[str, str] = {}
    if model != "plumb_bob":
        m = fit_model(views, size, model=model)
        if m.retry_note:
            fixed[m.retry_note.split(" held at 0")[0]] = m.retry_note
            return m, fixed, None
        # the k3 rule for every model: its highest-order coefficients (fisheye k3 k4,
        # rational k4-k6...) are held at 0 when together they do not differ from 0 (a narrow
        # lens or few views cannot tell them from the lower orders): a Wald test of the
        # block, χ² = vᵀΣ⁻¹v, at the confidence of the 2σ rule (they are correlated with each
        # other — the rational model's numerator and denominator trade — so one at a time
        # would miss a block that matters)
        n, k = len(param_names(model)), _RETRY_FIXED[model]
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
        fixed["k3"] = m.retry_note
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


#: The models ``auto`` compares, fewest coefficients first (plumb_bob first: every tool
#: reads it).
AUTO_MODELS = ("plumb_bob", "fisheye", "rational_polynomial")


def choose_model(views: list[ViewInput], size, opt: SolveOptions) -> tuple[str, dict]:
    """The lens model by held-out views (the module doc's rule).

    1. Each model is solved on all views and checked (:func:`_diagnose`): a model that does
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
    refused: dict[str, str] = {}
    for name in AUTO_MODELS:
        try:
            _fit_with_rules(views, size, name, opt)
        except CalibrationError as e:
            refused[name] = str(e)
    eligible = [n for n in AUTO_MODELS if n not in refused]
    if not eligible:
        raise CalibrationError("no lens model converged on these views (" + "; ".join(
            refused.values()) + ")")
    per_view = {name: _held_out_errors(views, size, name, opt) for name in AUTO_MODELS}

    def scored(x: float | None) -> bool:
        return x is not None and np.isfinite(x)

    def rms(e: list[float | None]) -> float | None:
        v = [x for x in e if scored(x)]
        return float(np.sqrt(np.mean(np.square(v)))) if v else None

    def failed(e: list[float | None]) -> int:
        return sum(x is None for x in e)

    chosen, why = eligible[0], ""
    for cand in eligible[1:]:
        eb, ec = per_view[chosen], per_view[cand]
        # only views both models had a solved fold for: a fold that one model cannot
        # determine is no evidence for the other
        both = [i for i in range(len(views)) if (eb[i] is None or scored(eb[i]))
                and (ec[i] is None or scored(ec[i]))]
        common = [i for i in both if scored(eb[i]) and scored(ec[i])]
        fb, fc = sum(eb[i] is None for i in both), sum(ec[i] is None for i in both)
        if not common:
            if fc < fb:
                chosen, why = cand, f"{cand} posed {fb - fc} more held-out views"
            continue
        mb = np.array([eb[i] for i in common]) ** 2
        mc = np.array([ec[i] for i in common]) ** 2
        rb, rc = float(np.sqrt(mb.mean())), float(np.sqrt(mc.mean()))
        d = mb - mc
        se = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("inf")
        if fc < fb and rc <= 1.1 * rb:
            chosen, why = cand, (f"{cand} posed {fb - fc} more held-out views and is not worse "
                                 f"on the {len(common)} both posed ({rc:.3f} vs {rb:.3f} px)")
        elif fc <= fb and rc < 0.9 * rb and d.mean() > 2.0 * se:
            chosen, why = cand, (f"{cand} is clearly better on the {len(common)} views both "
                                 f"posed ({rc:.3f} vs {rb:.3f} px, beyond twice the per-view "
                                 "spread)")

    def fmt(name: str) -> str:
        if name in refused:
            return "refused"
        e = per_view[name]
        r, f = rms(e), failed(e)
        u = sum(x is not None and not scored(x) for x in e)
        if r is None:
            return "failed" if f else "not determined without the held-out views"
        return f"{r:.3f} px" + (f" ({f} of {len(views)} views not posed)" if f else "") + (
            f" ({u} views not scored: the views without them do not determine it)" if u else "")

    table = ", ".join(f"{k} {fmt(k)}" for k in AUTO_MODELS)
    if chosen == "plumb_bob":
        reason = (f"kept plumb_bob: held-out RMS {table}; another model must pose more views, "
                  "or lower it by 10 % beyond the per-view noise, to be chosen")
    else:
        reason = f"chose {chosen}: held-out RMS {table}; " + (
            why or f"the models before it were refused ({', '.join(refused)})")
    if refused:
        reason += "; refused: " + "; ".join(f"{k}: {v}" for k, v in refused.items())
    return chosen, {
        "chosen": chosen, "reason": reason,
        "held_out_rms_px": {k: None if k in refused or rms(v) is None else round(rms(v), 4)
                            for k, v in per_view.items()},
        "failed_views": {k: failed(v) for k, v in per_view.items()},
        "refused": refused,
        "corner_noise_px": None if noise is None else round(noise, 4)}


#: Folds of the held-out comparison: view i is held out in fold i mod 6 (leave-one-out up to
#: 6 views), so every model is solved on 5/6 of the views (a half is too few on a small set).
HELD_OUT_FOLDS = 6


def _held_out_errors(views: list[ViewInput], size, model: str, opt: SolveOptions
                     ) -> list[float | None]:
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
            m, _, _ = _fit_with_rules([views[i] for i in train_i], size, model, opt)
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

