"""The measures ``drovisio bench real`` takes of each method on a photo: timing, corner
distances between two readings of one code, a code's pose by IPPE, angles, summary figures,
and AprilTag 3 when it is installed."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.study.apriltag import APRILTAG_PIXEL_OFFSET, AprilTagReader, apriltag_reader

__all__ = ["APRILTAG_PIXEL_OFFSET", "angle_deg", "apriltag", "ippe_pose", "match_corners",
           "roll_like", "stats", "timed"]


def timed(fn: Callable[[], Any], repeat: int) -> tuple[Any, float]:
    """``fn()``'s result and its fastest time (s) over ``repeat`` runs."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def match_corners(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-corner distances (4,) between two quads of one code, b's corners rolled (and
    mirrored: AprilTag turns the other way) to fit a's best."""
    best = None
    for cand in (b, b[::-1]):
        for k in range(4):
            d = np.linalg.norm(np.roll(cand, k, axis=0) - a, axis=1)
            if best is None or d.max() < best.max():
                best = d
    assert best is not None
    return best


def ippe_pose(camera: Camera, size: float, corners: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """The pose (camera_from_code rotation (3, 3), translation (3,) m) of a square code of
    side ``size`` m from its (4, 2) corners in pixels, by IPPE; None when it fails."""
    obj = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]], np.float64) * size / 2
    xn = camera.normalize(np.asarray(corners, np.float64).reshape(4, 2))
    if not np.all(np.isfinite(xn)):
        return None
    ok, rv, tv = cv2.solvePnP(obj, xn.reshape(-1, 1, 2), np.eye(3), None,
                              flags=cv2.SOLVEPNP_IPPE_SQUARE)
    return (cv2.Rodrigues(rv)[0], tv.ravel()) if ok else None


def angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """The angle (degrees) of the rotation between two (3, 3) rotations."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def stats(x: Iterable[float]) -> dict[str, Any]:
    """Count, median, 90th percentile and maximum of ``x`` (None each when empty)."""
    a = np.asarray(list(x), np.float64)
    if a.size == 0:
        return {"n": 0, "median": None, "p90": None, "max": None}
    return {"n": int(a.size), "median": float(np.median(a)),
            "p90": float(np.percentile(a, 90)), "max": float(a.max())}


def apriltag(dictionary: str) -> tuple[AprilTagReader | None, str | None]:
    """AprilTag 3 reading ``dictionary`` (any of OpenCV's: :mod:`drovisio.study.apriltag`),
    or (None, why)."""
    try:
        return apriltag_reader(dictionary), None
    except ImportError:
        return None, ("AprilTag 3 not installed (pip install drovisio[peers], i.e. "
                      "pupil-apriltags): its columns are left out")


def roll_like(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``q``'s corners in ``ref``'s order (rolled or mirrored to fit best)."""
    best, out = np.inf, q
    for cand in (q, q[::-1]):
        for k in range(4):
            r = np.roll(cand, k, axis=0)
            e = float(np.abs(r - ref).max())
            if e < best:
                best, out = e, r
    return out
