"""Frames of a mission, stated once.

* **Site frame** (the mission's world): x east, y north, z up, metres; origin at the site's
  benchmark (where the total station's coordinates are zero); the ground is the plane z = 0.
  Every position in a scenario file, a setpoint, a recording and the total station's readings
  is in this frame.
* **Heading / yaw** of the drone or of a brick: the angle, in radians inside (degrees only in
  files and printouts), from site +x (east) to the object's +x axis (the drone's *forward*
  axis, the brick's *length* axis), counter-clockwise seen from above (about +z). A drick is
  the same after a half-turn about z (two identical pyramids), so a brick's yaw error is taken
  modulo 180°.
* **Drone body frame**: FRD (x forward, y right, z down) as DESIGN.md says; with a level drone
  of heading ψ, ``site_from_body`` has columns forward = (cos ψ, sin ψ, 0),
  right = (sin ψ, −cos ψ, 0), down = (0, 0, −1).
* **Brick frame**: the layout's (origin at the centre of the body's top face, x along the
  length, z up). A brick resting level has ``site_from_brick = T(x, y, z_top) · Rz(yaw)``.
* The body origin is the point the total station's prism reading is reduced to (the ground
  station applies the prism offset) and the point setpoints refer to.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["wrap_pi", "wrap_half", "site_from_body", "site_from_brick", "yaw_of", "nearest_mod_pi",
           "rot2"]


def wrap_pi(a: float) -> float:
    """Angle wrapped to [−π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def wrap_half(a: float) -> float:
    """Angle wrapped to [−π/2, π/2): the error of a half-turn-symmetric brick's yaw."""
    return (a + math.pi / 2.0) % math.pi - math.pi / 2.0


def nearest_mod_pi(target: float, reference: float) -> float:
    """``target + kπ`` closest to ``reference`` (a drick can be taken either way round)."""
    return reference + wrap_half(target - reference)


def rot2(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def site_from_body(position: Sequence[float] | np.ndarray, yaw: float) -> np.ndarray:
    """4×4 ``site_from_body`` of a level drone (FRD body) at ``position`` with heading ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    T[:3, 3] = np.asarray(position, float)
    return T


def site_from_brick(position: Sequence[float] | np.ndarray, yaw: float) -> np.ndarray:
    """4×4 pose of a level brick whose top-face centre is at ``position``."""
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    T[:3, 3] = np.asarray(position, float)
    return T


def yaw_of(site_from_x: np.ndarray) -> float:
    """Heading of a frame's +x axis projected on the ground plane."""
    R = np.asarray(site_from_x)[:3, :3]
    return math.atan2(float(R[1, 0]), float(R[0, 0]))
