"""Frames and the pose covariance as ROS 2 states them (REP 103, ``PoseWithCovariance``).

* ROS bodies are **FLU** (x forward, y left, z up; REP 103); Drovisio's body is **FRD**
  (x forward, y right, z down; MAVLink's ``MAV_FRAME_BODY_FRD``, DESIGN.md). The two share x
  and differ by a half-turn about it: ``flu_from_frd = diag(1, −1, −1)``. Every body-frame
  pose and the mount are converted with it before they are published.
* The camera frame is OpenCV's (x right, y down, z forward), which is ROS's *optical* frame
  convention: camera poses pass unchanged, under the frame id ``camera_optical_frame``.
* ``PoseWithCovariance.covariance``: 6×6 row-major, order ``(x, y, z, rotation about X,
  rotation about Y, rotation about Z)`` of the message's (parent) frame, metres and radians;
  the rotation error is a small rotation about the parent's fixed axes,
  ``R_true = exp([δφ]×) · R`` — the convention of :mod:`drovisio.pose.covariance`, so the
  conversion from the JSON output's covariance is only a change of axes.
* Quaternions in ROS messages are ``(x, y, z, w)``.
"""

from __future__ import annotations

import numpy as np

from drovisio.geometry import quat_wxyz, so3_exp
from drovisio.pose.covariance import parent_covariance, rotate_parent_covariance

__all__ = [
    "BODY_FRAME",
    "CAMERA_FRAME",
    "FLU_FROM_FRD",
    "flu_from_camera",
    "pose_fields",
    "quat_xyzw",
    "ros_covariance",
]

#: The FLU body frame (REP 103's ``base_link``).
BODY_FRAME = "base_link"
#: The camera with OpenCV's axes (REP 103's optical frame convention).
CAMERA_FRAME = "camera_optical_frame"

#: 4×4 ``flu_from_frd``: a half-turn about the shared forward axis.
FLU_FROM_FRD = np.diag([1.0, -1.0, -1.0, 1.0])


def flu_from_camera(body_from_camera: np.ndarray) -> np.ndarray:
    """4×4 ``flu_from_camera`` of a mount's (FRD) ``body_from_camera``."""
    return FLU_FROM_FRD @ np.asarray(body_from_camera, np.float64)


def quat_xyzw(R: np.ndarray) -> list[float]:
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix (ROS's order)."""
    w, x, y, z = quat_wxyz(np.asarray(R, np.float64))
    return [float(x), float(y), float(z), float(w)]


def pose_fields(T: np.ndarray) -> dict:
    """A ``geometry_msgs/Pose`` (as a dict) of a 4×4 ``parent_from_child``."""
    T = np.asarray(T, np.float64)
    qx, qy, qz, qw = quat_xyzw(T[:3, :3])
    return {"position": {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3])},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def ros_covariance(rvec: np.ndarray, cov_rvec_tvec: np.ndarray,
                   parent_from_camera: np.ndarray | None = None) -> np.ndarray:
    """The 6×6 ROS covariance of a ``camera_from_x`` pose given by ``(rvec, tvec)`` and the
    covariance of those parameters, expressed in ``parent_from_camera``'s parent frame (e.g.
    :func:`flu_from_camera`; None: the camera optical frame itself).

    The translation of ``parent_from_camera`` is exact, so only its rotation turns both the
    position and the rotation errors.
    """
    C = parent_covariance(rvec, cov_rvec_tvec)
    if parent_from_camera is not None:
        C = rotate_parent_covariance(parent_from_camera, C)
    return C


def pose_of(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """4×4 of ``(rvec, tvec)``."""
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.asarray(rvec, np.float64).ravel())
    T[:3, 3] = np.ravel(tvec)
    return T
