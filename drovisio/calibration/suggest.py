"""Next-pose suggestion: where to hold the board next to reduce the uncertainty most.

With a solved model, every candidate placement — the board centred toward each of the nine
image regions (pushed inward just enough to be fully visible), at three sizes (the board
spanning 30, 45 or 60 % of the image width, which sets the distance), facing the camera or
tilted 35° about a horizontal or vertical axis either way — is turned into a hypothetical view:
its corners are projected with the current model, its Jacobian is added to the current
information about the nine intrinsics (its own pose eliminated by the Schur complement, as in
:mod:`drovisio.calibration.uncertainty`), and the resulting projection-uncertainty map is
evaluated. The candidate with the smallest predicted p95 of σ over the region of interest wins
(near-ties go to the smaller tilt, then to the middle size). The model's parameter set is kept
(k3 stays fixed if the solve fixed it) and the map uses the solve's grid, so the predicted p95
is comparable with the reported ``uncertainty_px``.

Before a model exists (fewer than 3 views), the hint follows coverage: first the centre, facing
the camera; then the least covered region, corners first, with alternating tilts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from drovisio.calibration.board import BoardSpec
from drovisio.calibration.coverage import Coverage
from drovisio.calibration.geometry import (
    board_outline_px,
    board_pose_summary,
    far_edge_name,
    fit_board,
)
from drovisio.calibration.uncertainty import (
    grid_jacobians,
    image_grid,
    param_names,
    schur_information,
    sigma_max,
    view_jacobian,
)
from drovisio.camera import Camera

__all__ = ["Suggestion", "suggest_next_pose", "BOARD_WIDTH_FRACTIONS", "TILT_DEG"]

BOARD_WIDTH_FRACTIONS = (0.3, 0.45, 0.6)
TILT_DEG = 35.0
# region → anchor as a fraction of the image (the image corner itself for corner regions)
_ANCHORS = {"top-left": (0.0, 0.0), "top": (0.5, 0.0), "top-right": (1.0, 0.0),
            "left": (0.0, 0.5), "centre": (0.5, 0.5), "right": (1.0, 0.5),
            "bottom-left": (0.0, 1.0), "bottom": (0.5, 1.0), "bottom-right": (1.0, 1.0)}
# (tilt sign·degrees, tilt axis in the image, degrees)
_TILTS = ((0.0, 0.0), (TILT_DEG, 0.0), (-TILT_DEG, 0.0), (TILT_DEG, 90.0), (-TILT_DEG, 90.0))


@dataclass
class Suggestion:
    """Where to put the board next (data for the page and the report)."""

    region: str
    """Named image region the board should be in (see :mod:`coverage`)."""
    box_px: tuple[float, float, float, float]
    """(x0, y0, x1, y1) of the board (with its margin) in the image."""
    outline_px: np.ndarray
    """(M, 2) outline of the board in the image, to draw."""
    target_px: tuple[float, float]
    distance_m: float
    tilt_deg: float
    far_edge: str | None
    """Which edge of the board (as seen in the image) should be farther away; None if flat."""
    sentence: str
    camera_from_board: np.ndarray
    current_p95_px: float | None = None
    predicted_p95_px: float | None = None

    def to_json(self) -> dict:
        return {"region": self.region, "box_px": [round(v, 1) for v in self.box_px],
                "outline_px": np.round(self.outline_px, 1).tolist(),
                "target_px": [round(v, 1) for v in self.target_px],
                "distance_m": round(self.distance_m, 3), "tilt_deg": round(self.tilt_deg, 1),
                "far_edge": self.far_edge, "sentence": self.sentence,
                "current_p95_px": None if self.current_p95_px is None
                else round(self.current_p95_px, 4),
                "predicted_p95_px": None if self.predicted_p95_px is None
                else round(self.predicted_p95_px, 4)}


def _candidate(camera: Camera, board: BoardSpec, region: str, frac: float, tilt: float,
               axis: float):
    ax, ay = _ANCHORS[region]
    target = np.array([ax * (camera.width - 1), ay * (camera.height - 1)])
    dist = camera.fx * board.width_m / (frac * camera.width)
    fit = fit_board(camera, board, target, dist, tilt, axis, 0.0, margin_px=8.0)
    if fit is None:
        return None
    T, tp, d = fit
    return T, tp, d


def _sentence(region: str, dist: float, tilt: float, far_edge: str | None,
              current: float | None, predicted: float | None) -> str:
    where = "in the centre of the image" if region == "centre" else \
        f"at the {region} of the image"
    s = f"Hold the board {where}, about {dist:.2f} m from the camera, "
    if abs(tilt) < 1.0 or far_edge is None:
        s += "facing the camera"
    else:
        s += f"tilted {abs(tilt):.0f}° with its {far_edge} edge farther away"
    if current is not None and predicted is not None:
        s += f" (uncertainty p95 {current:.2f} → {predicted:.2f} px)"
    return s + "."


def _make(camera, board, region, T, tp, tilt, current=None, predicted=None) -> Suggestion:
    outline = board_outline_px(camera, board, T)
    d, _ = board_pose_summary(T, board)
    far = far_edge_name(camera, board, T) if abs(tilt) >= 1.0 else None
    box = (float(outline[:, 0].min()), float(outline[:, 1].min()),
           float(outline[:, 0].max()), float(outline[:, 1].max()))
    return Suggestion(region, box, outline, (float(tp[0]), float(tp[1])), d, float(abs(tilt)),
                      far, _sentence(region, d, tilt, far, current, predicted), T, current,
                      predicted)


def _roi_mask(xs, ys, roi):
    gx, gy = np.meshgrid(xs, ys)
    if roi is None:
        return np.ones(gx.size, bool)
    x0, y0, x1, y1 = roi
    return ((gx >= x0) & (gx <= x1) & (gy >= y0) & (gy <= y1)).ravel()


def suggest_next_pose(camera: Camera, board: BoardSpec, coverage: Coverage | None = None,
                      views: list | None = None, fits: list | None = None,
                      sigma2: float | None = None,
                      roi: tuple[float, float, float, float] | None = None,
                      grid_step_px: float = 16.0, free: np.ndarray | None = None
                      ) -> Suggestion:
    """The next board placement.

    Args:
        camera: Current estimate (or a guess before the first solve).
        board: The target.
        coverage: Current coverage (used before a model exists).
        views: The solved views (:class:`~drovisio.calibration.solve.ViewInput`), with
            ``fits`` their poses (:class:`~drovisio.calibration.solve.ViewFit`) and ``sigma2``
            the corner noise variance of the solve. Without them the hint follows coverage.
        roi: Image region the uncertainty is judged on (None: all of it).
        grid_step_px: Spacing of the evaluation grid.
        free: Mask (P,) of the estimated intrinsics (default: all of the camera's model).
    """
    if not views or not fits or sigma2 is None or len(views) < 3:     # no model yet
        return _coverage_hint(camera, board, coverage)
    free = (np.ones(len(param_names(camera)), bool) if free is None
            else np.asarray(free, bool))
    jac = [view_jacobian(v.object_points, f.rvec, f.tvec, camera)[:2]
           for v, f in zip(views, fits)]
    S0 = schur_information(jac, free)
    xs, ys = image_grid(camera.width, camera.height, grid_step_px)
    Jg = grid_jacobians(camera, xs, ys)[_roi_mask(xs, ys, roi)][:, :, free]
    Jg = Jg[np.all(np.isfinite(Jg), axis=(1, 2))]
    current = _p95(Jg, S0, sigma2)
    obj = board.object_points()
    best = None
    for region in _ANCHORS:
        for frac in BOARD_WIDTH_FRACTIONS:
            for tilt, axis in _TILTS:
                cand = _candidate(camera, board, region, frac, tilt, axis)
                if cand is None:
                    continue
                T, tp, _ = cand
                rvec = _rvec(T)
                A, B, _ = view_jacobian(obj, rvec, T[:3, 3], camera)
                S = S0 + schur_information([(A, B)], free)
                p95 = _p95(Jg, S, sigma2)
                # prefer simpler placements on near-ties (2 %)
                key = (p95 * (1 + 0.02 * (abs(tilt) > 0) + 0.01 * (frac != 0.45)))
                if best is None or key < best[0]:
                    best = (key, p95, region, T, tp, tilt)
    if best is None:
        return _coverage_hint(camera, board, coverage)
    _, p95, region, T, tp, tilt = best
    return _make(camera, board, region, T, tp, tilt, current, p95)


def _rvec(T: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(T[:3, :3], float))[0].ravel()


def _p95(Jg: np.ndarray, S: np.ndarray, sigma2: float) -> float:
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    cov = sigma2 * np.linalg.pinv(S / np.outer(d, d), rcond=1e-12) / np.outer(d, d)
    s = sigma_max(Jg, cov)
    return float(np.percentile(s, 95)) if s.size else math.nan


def _coverage_hint(camera: Camera, board: BoardSpec, coverage: Coverage | None) -> Suggestion:
    n = coverage.n_views if coverage is not None else 0
    if n == 0:
        region, tilt, axis = "centre", 0.0, 0.0
    else:
        order = ["top-left", "top-right", "bottom-right", "bottom-left", "top", "right",
                 "bottom", "left", "centre"]
        regions = coverage.regions if coverage is not None else {}
        region = min(order, key=lambda r: (regions.get(r, 0.0), order.index(r)))
        tilt, axis = _TILTS[1 + (n % 4)]
    cand = _candidate(camera, board, region, 0.45, tilt, axis)
    if cand is None:  # the board cannot fit at this size: farther, facing the camera
        cand = _candidate(camera, board, "centre", 0.3, 0.0, 0.0)
        region, tilt = "centre", 0.0
    if cand is None:
        raise ValueError("the board cannot be placed fully inside this camera's image")
    T, tp, _ = cand
    return _make(camera, board, region, T, tp, tilt)

