"""Rendered calibration sessions with known truth (tests, the sample session, the web page).

:func:`render_calibration_views` places a chessboard ``n`` times in front of a camera the way a
careful operator would: the board centre visits the nine regions of the image in turn (the
corners first), the board fills 35–70 % of the image width, it is tilted 10–45° about a random
in-image axis and rolled up to ±20°, and every view is pulled inward (then back) until the whole
board, white margin included, is in the image. Each view is rendered with
:func:`drovisio.synth.render_chessboard` (exact ray casting through the distortion model) with
sensor noise, so its true corners are known exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drovisio.calibration.board import BoardSpec
from drovisio.calibration.geometry import board_pose_summary, fit_board
from drovisio.camera import Camera
from drovisio.synth import Effects, render_chessboard

__all__ = ["SyntheticView", "render_calibration_views", "calibration_poses", "DEFAULT_BOARD"]

#: The board of the rendered sessions: 9×6 inner corners, 3 cm squares (30 × 21 cm).
DEFAULT_BOARD = BoardSpec("chessboard", 9, 6, 0.03)

# region centres as fractions of the image (corners first, then edges, then the centre)
_REGIONS = [(0.1, 0.1), (0.9, 0.9), (0.9, 0.1), (0.1, 0.9), (0.5, 0.1), (0.5, 0.9),
            (0.1, 0.5), (0.9, 0.5), (0.5, 0.5)]


@dataclass
class SyntheticView:
    """One rendered view."""

    name: str
    image: np.ndarray
    """BGR uint8."""
    true_corners: np.ndarray
    """(rows·cols, 2) exact projections of the inner corners (distorted pixels)."""
    camera_from_board: np.ndarray
    distance_m: float
    tilt_deg: float


def calibration_poses(camera: Camera, n: int, seed: int = 0,
                      board: BoardSpec = DEFAULT_BOARD) -> list[np.ndarray]:
    """``n`` ``camera_from_board`` poses covering the image, distances and tilts (no rendering)."""
    rng = np.random.default_rng(seed)
    poses: list[np.ndarray] = []
    order = list(range(len(_REGIONS)))
    k = 0
    while len(poses) < n:
        if k % len(_REGIONS) == 0 and k:
            rng.shuffle(order)
        fx, fy = _REGIONS[order[k % len(_REGIONS)]]
        k += 1
        target = np.array([fx * (camera.width - 1), fy * (camera.height - 1)])
        target += rng.normal(0, 0.04, 2) * [camera.width, camera.height]
        frac = rng.uniform(0.35, 0.7)  # board width / image width
        dist = camera.fx * board.width_m / (frac * camera.width)
        tilt = rng.uniform(10.0, 45.0) * rng.choice([-1.0, 1.0])
        axis = rng.uniform(0.0, 180.0)
        roll = rng.uniform(-20.0, 20.0)
        fit = fit_board(camera, board, target, dist, tilt, axis, roll, margin_px=6.0)
        if fit is None:
            continue
        poses.append(fit[0])
    return poses


def render_calibration_views(camera: Camera, n: int = 20, seed: int = 0,
                             board: BoardSpec = DEFAULT_BOARD, noise_sigma: float = 1.0,
                             ss: int = 4, effects=None) -> list[SyntheticView]:
    """Render ``n`` chessboard views of ``camera`` with known truth.

    Args:
        camera: The true camera (distortion included).
        n: Number of views.
        seed: Seed of the poses and of the noise.
        board: The chessboard (default :data:`DEFAULT_BOARD`).
        noise_sigma: Sensor noise, 8-bit levels.
        ss: Renderer samples per pixel per axis.
        effects: A :class:`drovisio.synth.Effects` overriding ``noise_sigma`` (its seed is
            offset per view).

    Returns:
        The views, named ``view00.png`` … in order.
    """
    if board.kind != "chessboard":
        raise ValueError("render_calibration_views renders chessboards only")
    views = []
    for i, T in enumerate(calibration_poses(camera, n, seed, board)):
        fx = (replace(effects, seed=effects.seed + 1000 * seed + i) if effects is not None
              else Effects(noise_sigma=noise_sigma, seed=1000 * seed + i))
        img, truth, _ = render_chessboard(camera, T, board.cols, board.rows, board.square,
                                          effects=fx, ss=ss)
        d, tilt = board_pose_summary(T, board)
        views.append(SyntheticView(f"view{i:02d}.png", img, truth, T, d, tilt))
    return views


