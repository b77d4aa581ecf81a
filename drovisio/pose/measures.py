"""Angles between poses, for the detectors and their benchmarks."""

from __future__ import annotations

import math

import numpy as np

from drovisio.geometry import quat_wxyz

__all__ = ["is_planar", "rotation_angle_deg", "tilt_deg", "yaw_about_axis_deg"]


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the rotation between two rotation matrices, degrees."""
    c = (np.trace(np.asarray(R_a).T @ np.asarray(R_b)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


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
