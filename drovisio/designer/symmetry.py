"""Symmetries of a dot pattern: the turns that map the dots onto themselves, the layout
file's half-turn about z, and a colour change that breaks them (metres)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from drovisio.designer.model import DesignMarker
from drovisio.layout import SYMMETRY_TOL_M

__all__ = ["dot_symmetries", "rot180_z_symmetric", "symmetry_breaking_colour"]


def _dot_plane(markers: list[DesignMarker]) -> np.ndarray:
    """(N, 2) dot centres in the dots' own plane, about their mean (metres)."""
    pts = np.array([m.center for m in markers], np.float64)
    n = np.mean([m.n for m in markers], axis=0)
    n = n / np.linalg.norm(n) if np.linalg.norm(n) > 0 else np.array([0, 0, 1.0])
    c = pts.mean(axis=0)
    u = np.cross(n, [1.0, 0, 0])
    if np.linalg.norm(u) < 0.3:
        u = np.cross(n, [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    xy = np.stack([(pts - c) @ u, (pts - c) @ v], axis=1)
    return xy


def dot_symmetries(markers: list[DesignMarker], tol: float = SYMMETRY_TOL_M) -> list[float]:
    """Angles (deg, in (0, 360)) of the rotations about the dot pattern's own centre and
    normal that map every dot onto a dot of the same colour and diameter.

    An empty list means the dots alone fix the brick's yaw; ``[180.0]`` is the thesis's
    red-blue-red pattern (yaw ambiguous by 180 deg).
    """
    if len(markers) < 2:
        return []
    xy = _dot_plane(markers)
    rho = np.linalg.norm(xy, axis=1)
    keys = [(m.color, round(m.size / tol)) for m in markers]
    ref = int(np.argmax(rho))
    if rho[ref] <= tol:
        return []
    base = math.atan2(xy[ref, 1], xy[ref, 0])
    out: list[float] = []
    for j in range(len(markers)):
        if j == ref or keys[j] != keys[ref] or abs(rho[j] - rho[ref]) > 2 * tol:
            continue
        th = math.atan2(xy[j, 1], xy[j, 0]) - base
        c, s = math.cos(th), math.sin(th)
        rot = xy @ np.array([[c, s], [-s, c]])
        ok = True
        for k in range(len(markers)):
            d = np.linalg.norm(xy - rot[k], axis=1)
            if not any(d[q] <= 2 * tol and keys[q] == keys[k] for q in range(len(markers))):
                ok = False
                break
        if ok:
            deg = math.degrees(th) % 360.0
            if 0.5 < deg < 359.5:
                out.append(round(deg, 1))
    return sorted(set(out))


def rot180_z_symmetric(markers: list[DesignMarker], tol: float = SYMMETRY_TOL_M) -> bool:
    """The layout file's ``rot180_z``: a half-turn about the brick's z axis (through the
    origin) maps the dots onto dots of the same colour and diameter (brick frame)."""
    if not markers:
        return False
    pts = np.array([m.center for m in markers], np.float64)
    rot = pts * np.array([-1.0, -1.0, 1.0])
    for j, d in enumerate(markers):
        dist = np.linalg.norm(pts - rot[j], axis=1)
        if not any(dist[k] <= tol and markers[k].color == d.color
                   and abs(markers[k].size - d.size) <= tol for k in range(len(markers))):
            return False
    return True


def symmetry_breaking_colour(markers: list[DesignMarker], palette: list[str]
                             ) -> tuple[int, str] | None:
    """A single dot colour change that leaves the pattern with no symmetry:
    ``(index into markers, new colour)``, preferring colours already used, or None."""
    used = list(dict.fromkeys(m.dot_color for m in markers))
    order = used + [c for c in palette if c not in used]
    for i, m in enumerate(markers):
        for c in order:
            if c == m.color:
                continue
            trial = list(markers)
            trial[i] = replace(m, color=c)
            if not dot_symmetries(trial):
                return i, c
    return None
