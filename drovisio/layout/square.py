"""A square code's geometry: its corners from a centre and two directions, and the checks
that four given corners form the square the code's ``size`` says."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drovisio.layout.errors import Located

__all__ = [
    "SQUARE_SIDE_REL_TOL",
    "SQUARE_ANGLE_TOL_DEG",
    "SQUARE_PLANAR_REL_TOL",
    "unit",
    "square_corners",
    "square_issues",
]

# Geometric tolerances (documented in the error messages).
SQUARE_SIDE_REL_TOL = 0.01  #: code sides must equal ``size`` within 1 %.
SQUARE_ANGLE_TOL_DEG = 1.0  #: code corners must be right angles within 1 degree.
SQUARE_PLANAR_REL_TOL = 0.01  #: code corners within 1 % of ``size`` of their plane.

_CORNER_NAMES = ("top-left", "top-right", "bottom-right", "bottom-left")


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to length 1 (no guard: callers check for the zero vector)."""
    return v / np.linalg.norm(v)


def square_corners(center: Sequence[float], normal: Sequence[float], up: Sequence[float],
                   size: float) -> np.ndarray:
    """Corners of a square code from its centre, facing direction and up direction.

    n = normalize(normal), u = normalize(up - (up.n) n), r = u x n;
    TL = c - r s/2 + u s/2, TR = c + r s/2 + u s/2, BR = c + r s/2 - u s/2,
    BL = c - r s/2 - u s/2 (OpenCV / ``cv2.aruco.Board`` order). With n = +z, up = +y this
    is OpenCV's square object points (-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0),
    (-s/2, -s/2, 0).

    Args:
        center: square centre [x, y, z] (any length unit).
        normal: direction the printed face looks toward (out of the surface).
        up: direction toward the printed image's top edge (need not be exactly
            perpendicular to ``normal``).
        size: side of the outer black border, same unit as ``center``.

    Returns:
        (4, 3) float64 array TL, TR, BR, BL, in the unit of ``center``.
    """
    c = np.asarray(center, np.float64)
    n = unit(np.asarray(normal, np.float64))
    up_v = np.asarray(up, np.float64)
    u = unit(up_v - np.dot(up_v, n) * n)
    r = np.cross(u, n)
    h = size / 2.0
    return np.array([c - r * h + u * h, c + r * h + u * h, c + r * h - u * h, c - r * h - u * h])


def _side_issue(c: np.ndarray, s: float) -> Located | None:
    for i in range(4):
        side = float(np.linalg.norm(c[(i + 1) % 4] - c[i]))
        if abs(side - s) > SQUARE_SIDE_REL_TOL * s:
            return (("corners",), f"side {_CORNER_NAMES[i]} -> {_CORNER_NAMES[(i + 1) % 4]} "
                    f"is {side:.6g} but size is {s:.6g} (must agree within "
                    f"{SQUARE_SIDE_REL_TOL:.0%}); list the 4 corners of a square "
                    "of side 'size' in order TL, TR, BR, BL")
    return None


def _angle_issue(c: np.ndarray) -> Located | None:
    for i in range(4):
        a = c[(i + 1) % 4] - c[i]
        b = c[i - 1] - c[i]
        cosang = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
        ang = math.degrees(math.acos(max(-1.0, min(1.0, cosang))))
        if abs(ang - 90.0) > SQUARE_ANGLE_TOL_DEG:
            return (("corners",), f"angle at the {_CORNER_NAMES[i]} corner is "
                    f"{ang:.2f} deg, not 90 (tolerance {SQUARE_ANGLE_TOL_DEG:g} "
                    "deg); the corners must form a square, in order TL, TR, BR, "
                    "BL")
    return None


def _planarity_issue(c: np.ndarray, s: float) -> Located | None:
    centred = c - c.mean(axis=0)
    normal = np.linalg.svd(centred)[2][2]
    dev = float(np.max(np.abs(centred @ normal)))
    if dev > SQUARE_PLANAR_REL_TOL * s:
        return (("corners",), f"the corners are not planar ({dev:.6g} off "
                f"their plane, tolerance {SQUARE_PLANAR_REL_TOL:.0%} of size)")
    return None


def square_issues(corners: np.ndarray, size: float) -> list[Located]:
    """The first problem (if any) that keeps four corners from being a code's square.

    Args:
        corners: (4, 3) float64 corners TL, TR, BR, BL, in the layout's units.
        size: the code's side, same unit.

    Returns:
        At most one located problem: sides first, then right angles, then planarity.
    """
    issue = (_side_issue(corners, size) or _angle_issue(corners)
             or _planarity_issue(corners, size))
    return [issue] if issue is not None else []
