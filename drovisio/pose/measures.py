"""Angles between poses and pose errors, for the detectors, the benchmarks, the study and
the designer.

Two measures of the yaw error (the twist about the brick's z of ``R_true.T @ R_est``), equal
up to rounding for a layout without symmetry:

* :func:`yaw_about_axis_deg`: by the swing–twist decomposition about any axis, in
  (−180°, 180°]; the code benchmarks (``drovisio bench aruco``, ``lens``) and the study's code
  methods, which first turn a symmetric layout's estimate by the half turn that fits best;
* :func:`yaw_error_deg`: in closed form from the error's top-left 2×2 block, wrapped to the
  layout's symmetry (±90° when it looks the same after a half turn, so that a half-turned
  pose of a symmetric brick is no error); the dot benchmark (``drovisio bench dots``) and the
  study's dot methods.
"""

from __future__ import annotations

import math

import numpy as np

from drovisio.geometry import quat_wxyz

__all__ = ["is_planar", "rotation_angle_deg", "rotation_angles_deg", "tilt_deg",
           "yaw_about_axis_deg", "yaw_error_deg"]


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the rotation between two rotation matrices, degrees."""
    c = (np.trace(np.asarray(R_a).T @ np.asarray(R_b)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def rotation_angles_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Rotation angles between batches of rotations (..., 3, 3), degrees (...)."""
    c = (np.einsum("...ij,...ij->...", Ra, Rb) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def tilt_deg(R: np.ndarray, gravity: np.ndarray, up_axis=(0.0, 0.0, 1.0)) -> float:
    """Angle between the object's ``up_axis`` (in the camera frame) and −gravity, degrees."""
    up = np.asarray(R) @ np.asarray(up_axis, np.float64)
    g = np.asarray(gravity, np.float64)
    c = float(-up @ g / math.sqrt(float(up @ up) * float(g @ g)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def yaw_about_axis_deg(R_true: np.ndarray, R_est: np.ndarray, axis=(0.0, 0.0, 1.0)) -> float:
    """Signed rotation about the object's ``axis`` between truth and estimate, degrees.

    Computed from ``R_true.T @ R_est`` (the error in the object frame) by the swing–twist
    decomposition: the twist about ``axis``.
    """
    dR = np.asarray(R_true).T @ np.asarray(R_est)
    q = np.asarray(quat_wxyz(dR))
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    p = float(q[1:] @ a)
    ang = 2.0 * math.atan2(p, q[0])
    ang = (ang + math.pi) % (2 * math.pi) - math.pi
    return math.degrees(ang)


def yaw_error_deg(R_true: np.ndarray, R_est: np.ndarray, symmetric: bool = False) -> float:
    """Signed yaw error (degrees): the rotation about the brick's z of ``R_true.T @ R_est``
    from its top-left 2×2 block, ``atan2(E₁₀ − E₀₁, E₀₀ + E₁₁)``, wrapped to [−90°, 90°)
    when the layout looks the same after a half turn about z (``symmetric``), else to
    [−180°, 180°) (module doc: when to use it rather than :func:`yaw_about_axis_deg`).

    Args:
        R_true: (3, 3) ``camera_from_brick`` rotation of the truth.
        R_est: (3, 3) the estimate's.
        symmetric: The layout is half-turn symmetric about its z.
    """
    E = np.asarray(R_true).T @ np.asarray(R_est)
    yaw = math.degrees(math.atan2(E[1, 0] - E[0, 1], E[0, 0] + E[1, 1]))
    period = 180.0 if symmetric else 360.0
    return (yaw + period / 2) % period - period / 2


def is_planar(points: np.ndarray, rel_tol: float = 1e-3) -> bool:
    """True if 3D points lie on one plane within ``rel_tol`` of their extent."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    if len(P) < 4:
        return True
    if np.ptp(P[:, 2]) == 0.0:  # the common case: a flat face at z = const
        return True
    c = P - P.mean(axis=0)
    s = np.linalg.svd(c, compute_uv=False)
    return bool(s[-1] <= rel_tol * max(s[0], 1e-12))
