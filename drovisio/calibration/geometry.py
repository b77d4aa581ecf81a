"""Where a board is relative to the camera: placing it (for hints and renders) and describing it.

A board placement is given the way a person holds a board in front of a camera:

* ``target_px``: the image point where the centre of the board appears;
* ``distance``: camera-to-board-centre distance, metres;
* ``tilt_deg``: angle between the board's normal and the line of sight to its centre
  (0 = the board faces the camera);
* ``tilt_axis_deg``: direction, in the image, of the axis the board is turned about
  (0 = a horizontal axis: the top or bottom edge goes away; 90 = a vertical axis: the left or
  right edge goes away); the sign of ``tilt_deg`` picks which edge;
* ``roll_deg``: rotation of the board in its own plane.

Transforms are ``camera_from_board`` 4×4 matrices (board frame: OpenCV's calibration frame, see
:class:`drovisio.calibration.board.BoardSpec`).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio.calibration.board import BoardSpec
from drovisio.camera import Camera
from drovisio.geometry import rotation_about

__all__ = ["place_board", "fit_board", "board_outline_px", "board_pose_summary",
           "far_edge_name", "MARGIN_SQUARES"]

#: White margin around the squares that detection needs to see, in squares.
MARGIN_SQUARES = 0.6


def place_board(camera: Camera, board: BoardSpec, target_px, distance: float,
                tilt_deg: float = 0.0, tilt_axis_deg: float = 0.0,
                roll_deg: float = 0.0) -> np.ndarray:
    """``camera_from_board`` of a board centred on ``target_px`` at ``distance`` metres."""
    ray = camera.rays(np.asarray(target_px, float).reshape(1, 2))[0]
    # base orientation: board z (into the board) along the line of sight, board x ≈ camera x
    z = ray
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)  # columns: board axes in the camera frame
    R = R @ rotation_about(np.array([0.0, 0.0, 1.0]), math.radians(roll_deg))
    a = math.radians(tilt_axis_deg)
    axis_cam = math.cos(a) * x + math.sin(a) * y  # in-image direction of the tilt axis
    R = rotation_about(axis_cam, math.radians(tilt_deg)) @ R
    centre_b = np.array([(board.cols - 1) / 2 * board.square, (board.rows - 1) / 2 * board.square,
                         0.0])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = distance * ray - R @ centre_b
    return T


def board_outline_px(camera: Camera, board: BoardSpec, camera_from_board: np.ndarray,
                     margin_squares: float = MARGIN_SQUARES, samples: int = 8) -> np.ndarray:
    """Projected outline (4·samples, 2) of the board's squares plus a white margin."""
    s = board.square
    m = (1.0 + margin_squares) * s
    x0, y0, x1, y1 = -m, -m, (board.cols - 1) * s + m, (board.rows - 1) * s + m
    t = np.linspace(0, 1, samples, endpoint=False)
    pts = np.concatenate([
        np.stack([x0 + (x1 - x0) * t, np.full_like(t, y0)], 1),
        np.stack([np.full_like(t, x1), y0 + (y1 - y0) * t], 1),
        np.stack([x1 - (x1 - x0) * t, np.full_like(t, y1)], 1),
        np.stack([np.full_like(t, x0), y1 - (y1 - y0) * t], 1)])
    pts3 = np.concatenate([pts, np.zeros((len(pts), 1))], 1)
    pc = pts3 @ camera_from_board[:3, :3].T + camera_from_board[:3, 3]
    if np.any(pc[:, 2] <= 1e-3):
        return np.full((len(pts), 2), np.nan)
    return camera.project(pc)


def _inside(px: np.ndarray, camera: Camera, margin: float) -> bool:
    return bool(np.all(np.isfinite(px)) and px[:, 0].min() >= margin
                and px[:, 1].min() >= margin and px[:, 0].max() <= camera.width - 1 - margin
                and px[:, 1].max() <= camera.height - 1 - margin)


def fit_board(camera: Camera, board: BoardSpec, target_px, distance: float,
              tilt_deg: float = 0.0, tilt_axis_deg: float = 0.0, roll_deg: float = 0.0,
              margin_px: float = 4.0, max_distance: float | None = None
              ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Like :func:`place_board`, but shifts the board inward (and moves it farther away if it
    is too big) until all of it, margin included, is inside the image.

    Returns:
        (camera_from_board, target_px actually used, distance actually used), or None if even
        centred at ``max_distance`` (default 4 × distance) it does not fit.
    """
    target = np.asarray(target_px, float).copy()
    d = float(distance)
    max_d = 4.0 * d if max_distance is None else max_distance
    lo = margin_px
    hi = np.array([camera.width - 1 - margin_px, camera.height - 1 - margin_px])
    for _ in range(40):
        T = place_board(camera, board, target, d, tilt_deg, tilt_axis_deg, roll_deg)
        o = board_outline_px(camera, board, T)
        if not np.all(np.isfinite(o)):
            d *= 1.15
        else:
            mn, mx = o.min(axis=0), o.max(axis=0)
            if np.all(mn >= lo) and np.all(mx <= hi):
                return T, target, d
            too_big = (mx - mn) > (hi - lo)
            if np.any(too_big):
                d *= 1.15  # cannot fit at this size: farther away
            shift = np.where(mn < lo, lo - mn + 0.5, 0.0) + np.where(mx > hi, hi - mx - 0.5, 0.0)
            target = np.clip(target + np.where(too_big, 0.0, shift), 0,
                             [camera.width - 1, camera.height - 1])
        if d > max_d + 1e-9:
            return None
    return None


def far_edge_name(camera: Camera, board: BoardSpec, camera_from_board: np.ndarray) -> str:
    """Which edge of the board, as seen in the image (top/bottom/left/right), is farthest."""
    o = board_outline_px(camera, board, camera_from_board, samples=1)  # 4 outer corners
    s = board.square
    m = (1.0 + MARGIN_SQUARES) * s
    x0, y0, x1, y1 = -m, -m, (board.cols - 1) * s + m, (board.rows - 1) * s + m
    c3 = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]])
    depth = (c3 @ camera_from_board[:3, :3].T + camera_from_board[:3, 3])[:, 2]
    mids_px = (o + np.roll(o, -1, axis=0)) / 2
    mids_d = (depth + np.roll(depth, -1)) / 2
    k = int(np.argmax(mids_d))
    centre = o.mean(axis=0)
    v = mids_px[k] - centre
    if abs(v[0]) > abs(v[1]):
        return "right" if v[0] > 0 else "left"
    return "bottom" if v[1] > 0 else "top"


def board_pose_summary(camera_from_board: np.ndarray, board: BoardSpec) -> tuple[float, float]:
    """(distance to the board's centre in metres, tilt in degrees: angle between the board's
    normal and the line of sight to its centre)."""
    centre_b = np.array([(board.cols - 1) / 2 * board.square,
                         (board.rows - 1) / 2 * board.square, 0.0])
    c = camera_from_board[:3, :3] @ centre_b + camera_from_board[:3, 3]
    n = camera_from_board[:3, 2]
    cosang = abs(float(np.dot(n, c) / np.linalg.norm(c)))
    return float(np.linalg.norm(c)), math.degrees(math.acos(min(1.0, cosang)))
