"""Errors of an estimated brick pose against the true one, as the dot benchmark and the study
measure them (one definition, used by both).

Poses are ``camera_from_brick`` (X_cam = R · X_brick + t), metres.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["pose_errors"]


def _angle_deg(R: np.ndarray) -> float:
    """Rotation angle of a rotation matrix (3, 3), degrees."""
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))


def pose_errors(camera_from_brick: np.ndarray | list, R_est: np.ndarray, t_est: np.ndarray,
                symmetric: bool) -> dict[str, float]:
    """The errors of an estimated pose.

    Args:
        camera_from_brick: (4, 4) the true pose.
        R_est: (3, 3) and t_est: (3,) the estimated pose.
        symmetric: The layout is symmetric under a half-turn about the brick's z axis (yaw
            modulo 180°, the rotation error to the nearer of the two).

    Returns:
        ``lateral_m`` (|(Δx, Δy)| of t in the camera frame), ``depth_rel`` (|Δz| / z),
        ``yaw_deg`` (|rotation about the brick's z of R_trueᵀ·R_est|), ``rot_deg`` (angle of
        R_trueᵀ·R_est) and ``dist_m`` (distance of the true brick from the camera).
    """
    T = np.asarray(camera_from_brick)
    Rt, tt = T[:3, :3], T[:3, 3]
    E = Rt.T @ R_est
    yaw = math.degrees(math.atan2(E[1, 0] - E[0, 1], E[0, 0] + E[1, 1]))
    period = 180.0 if symmetric else 360.0
    yaw = (yaw + period / 2) % period - period / 2
    rot = _angle_deg(E)
    if symmetric:
        rot = min(rot, _angle_deg(E @ np.diag([-1.0, -1.0, 1.0])))
    return {"lateral_m": float(np.hypot(*(t_est - tt)[:2])),
            "depth_rel": float(abs(t_est[2] - tt[2]) / tt[2]),
            "yaw_deg": abs(yaw), "rot_deg": rot, "dist_m": float(np.linalg.norm(tt))}
