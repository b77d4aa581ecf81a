"""Markers on their faces: whether one fits its flat face, the largest size that does, and
whether two markers overlap (mesh frame, metres)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from drovisio.designer.model import DesignDocument, DesignMarker

__all__ = ["OVERHANG_TOL_M", "markers_overlap", "fits", "fit_size"]

#: Edge tolerance of the overhang test (printing and cutting are not more precise).
OVERHANG_TOL_M = 0.0002


def _plane_coords(m: DesignMarker, origin: np.ndarray, r: np.ndarray, u: np.ndarray
                  ) -> np.ndarray:
    d = m.c - origin
    return np.array([d @ r, d @ u])


def _square2d(m: DesignMarker, origin: np.ndarray, r: np.ndarray, u: np.ndarray
              ) -> np.ndarray:
    return np.array([[p @ r, p @ u] for p in (m.corners() - origin)])


def _sat(a: np.ndarray, b: np.ndarray, gap: float = 0.0) -> bool:
    """Do two convex 2D polygons overlap (by more than -gap)?"""
    for poly in (a, b):
        for i in range(len(poly)):
            e = poly[(i + 1) % len(poly)] - poly[i]
            axis = np.array([-e[1], e[0]])
            n = np.linalg.norm(axis)
            if n == 0:
                continue
            axis /= n
            pa, pb = a @ axis, b @ axis
            if pa.max() <= pb.min() + gap or pb.max() <= pa.min() + gap:
                return False
    return True


def _circle_polygon(center: np.ndarray, radius: float, poly: np.ndarray) -> bool:
    # inside?
    inside = True
    sign = None
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        cr = (b[0] - a[0]) * (center[1] - a[1]) - (b[1] - a[1]) * (center[0] - a[0])
        s = cr >= 0
        if sign is None:
            sign = s
        elif s != sign:
            inside = False
    if inside:
        return True
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        ab = b - a
        t = np.clip((center - a) @ ab / max(ab @ ab, 1e-30), 0, 1)
        if np.linalg.norm(center - (a + t * ab)) < radius:
            return True
    return False


def markers_overlap(a: DesignMarker, b: DesignMarker) -> bool:
    """Do two markers on (nearly) the same plane overlap? Markers on different planes
    never count (they sit on different faces)."""
    if a.n @ b.n < math.cos(math.radians(5)):
        return False
    if abs((b.c - a.c) @ a.n) > 0.002:
        return False
    origin, r, u = a.c, a.r, a.u
    if a.kind == "dot" and b.kind == "dot":
        return float(np.linalg.norm(_plane_coords(b, origin, r, u))) < (a.size + b.size) / 2
    if a.kind == "aruco" and b.kind == "aruco":
        return _sat(_square2d(a, origin, r, u), _square2d(b, origin, r, u))
    code, dot = (a, b) if a.kind == "aruco" else (b, a)
    return _circle_polygon(_plane_coords(dot, origin, r, u), dot.size / 2,
                           _square2d(code, origin, r, u))


def fits(doc: DesignDocument, m: DesignMarker) -> bool:
    """Whether the marker lies wholly on its flat face (within :data:`OVERHANG_TOL_M`)."""
    if m.face is None:
        return False
    face = doc.faces.faces[m.face]
    return bool(np.all(doc.faces.contains(face, m.outline(), tol=OVERHANG_TOL_M,
                                          plane_tol=0.001)))


def fit_size(doc: DesignDocument, m: DesignMarker, min_size: float = 0.005) -> float | None:
    """The largest size (whole millimetres, at most the current size) at which the marker
    fits its face where it is, or None if not even ``min_size`` fits."""
    if m.face is None:
        return None
    lo, hi = min_size, m.size
    if not fits(doc, replace(m, size=lo)):
        return None
    for _ in range(30):
        mid = (lo + hi) / 2
        if fits(doc, replace(m, size=mid)):
            lo = mid
        else:
            hi = mid
    return math.floor(lo * 1000 + 1e-9) / 1000
