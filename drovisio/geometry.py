"""Rotations and rigid transforms, with the project's conventions stated once.

* Transforms are 4×4 matrices named ``a_from_b``: ``p_a = a_from_b @ p_b`` (homogeneous).
* A pose in OpenCV's (rvec, tvec) form is ``camera_from_object``: ``X_cam = R(rvec)·X + tvec``.
* Rotation vectors (axis × angle, radians) map to matrices by :func:`so3_exp` and back by
  :func:`so3_log` (angle in [0, π]); both accept batches (..., 3) / (..., 3, 3).
* Quaternions are (w, x, y, z) with w ≥ 0 (viser's order, MAVLink's ``q`` field).
* Euler angles appear only where a protocol fixes them: MAVLink's ZYX (yaw, pitch, roll)
  attitude in :func:`ned_from_body`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

__all__ = [
    "from_rvec_tvec",
    "invert",
    "ned_from_body",
    "quat_wxyz",
    "right_jacobian",
    "right_jacobian_inv",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_about",
    "rvec_tvec",
    "skew",
    "so3_exp",
    "so3_log",
    "transform",
    "yaw_quat_wxyz",
]

_SKEW_IDX = (np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1]))
_SKEW_SRC = np.array([2, 1, 2, 0, 1, 0])
_SKEW_SGN = np.array([-1.0, 1.0, 1.0, -1.0, -1.0, 1.0])


def skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3): ``skew(w) @ v = w × v``."""
    w = np.asarray(w, np.float64)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., _SKEW_IDX[0], _SKEW_IDX[1]] = w[..., _SKEW_SRC] * _SKEW_SGN
    return S


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues, batched)."""
    w = np.asarray(w, np.float64)
    th = np.sqrt(np.einsum("...i,...i->...", w, w))
    ths = np.maximum(th, 1e-12)
    a = (np.sin(th) / ths)[..., None, None]
    b = (2 * np.sin(th / 2) ** 2 / ths ** 2)[..., None, None]
    S = skew(w)
    return np.eye(3) + a * S + b * np.matmul(S, S)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3), angle in [0, π]; exact
    near 0 and near π (batched)."""
    R = np.asarray(R, np.float64)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    th = np.arccos(cos)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = np.sin(th)
    out = np.where((s > 1e-7)[..., None], v * (th / (2 * np.where(s > 1e-7, s, 1.0)))[..., None],
                   v / 2)
    near_pi = np.atleast_1d(th > np.pi - 1e-4)
    if np.any(near_pi):  # axis from the largest diagonal entry of (R + I) / 2
        shape = out.shape
        Rf, out, v, th = (R.reshape((-1, 3, 3)), out.reshape((-1, 3)).copy(),
                          v.reshape((-1, 3)), th.reshape(-1))
        for idx in np.nonzero(near_pi.reshape(-1))[0]:
            B = (Rf[idx] + np.eye(3)) / 2
            k = int(np.argmax(np.diag(B)))
            axis = B[:, k] / np.sqrt(max(B[k, k], 1e-12))
            axis /= np.linalg.norm(axis)
            if axis @ v[idx] < 0:
                axis = -axis
            out[idx] = th[idx] * axis
        out = out.reshape(shape)
    return out


def right_jacobian(w: np.ndarray) -> np.ndarray:
    """``J_r(w)``, SO(3)'s right Jacobian: ``exp(w + δw) ≈ exp(w) · exp(J_r(w) δw)``."""
    w = np.asarray(w, np.float64).ravel()
    th = float(np.linalg.norm(w))
    K = skew(w)
    if th < 1e-6:
        return np.eye(3) - 0.5 * K + K @ K / 6.0
    return (np.eye(3) - (1 - math.cos(th)) / th ** 2 * K
            + (th - math.sin(th)) / th ** 3 * K @ K)


def right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """``J_r(w)⁻¹``, in closed form away from |w| = π."""
    w = np.asarray(w, np.float64).ravel()
    th = float(np.linalg.norm(w))
    K = skew(w)
    if th < 1e-6:
        return np.eye(3) + 0.5 * K + K @ K / 12.0
    if th > math.pi - 1e-3:  # singular at 2π, ill-conditioned at π: fall back to a solve
        return np.linalg.inv(right_jacobian(w))
    return (np.eye(3) + 0.5 * K
            + (1 / th ** 2 - (1 + math.cos(th)) / (2 * th * math.sin(th))) * K @ K)


def rot_x(angle: float) -> np.ndarray:
    """3×3 rotation by ``angle`` (rad) about x (y turns toward z)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """3×3 rotation by ``angle`` (rad) about y (z turns toward x)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    """3×3 rotation by ``angle`` (rad) about z (x turns toward y)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_about(axis: Sequence[float] | np.ndarray, angle: float) -> np.ndarray:
    """3×3 rotation by ``angle`` (rad) about ``axis`` (3,), right-handed: OpenCV's Rodrigues
    of ``axis · angle``.

    The axis is used as given (a unit vector turns by exactly ``angle``): callers with any
    other length normalise it first, so that the arithmetic stays the one each result was
    measured with.
    """
    return cv2.Rodrigues(np.asarray(axis, np.float64).reshape(3, 1) * angle)[0]


def transform(R: np.ndarray | None = None, t: Sequence[float] | np.ndarray | None = None
              ) -> np.ndarray:
    """A 4×4 rigid transform from a rotation (3×3 matrix or rotation vector) and a
    translation."""
    T = np.eye(4)
    if R is not None:
        R = np.asarray(R, dtype=np.float64)
        T[:3, :3] = so3_exp(R.reshape(3)) if R.size == 3 else R.reshape(3, 3)
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def from_rvec_tvec(rvec: Sequence[float] | np.ndarray, tvec: Sequence[float] | np.ndarray
                   ) -> np.ndarray:
    """The 4×4 ``camera_from_object`` of OpenCV's (rvec, tvec)."""
    return transform(np.asarray(rvec, np.float64).reshape(3), tvec)


def rvec_tvec(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's (rvec, tvec) of a 4×4 transform."""
    T = np.asarray(T, np.float64)
    return so3_log(T[:3, :3]), T[:3, 3].copy()


def invert(T: np.ndarray) -> np.ndarray:
    """``b_from_a`` of a rigid ``a_from_b``."""
    T = np.asarray(T, np.float64)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def quat_wxyz(R: np.ndarray) -> list[float]:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix (Shepperd's method: the
    largest of the four candidates decides, so it is exact for every rotation)."""
    R = np.asarray(R, np.float64)
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    qa = np.asarray(q)
    qa /= np.linalg.norm(qa)
    if qa[0] < 0:
        qa = -qa
    return [float(x) for x in qa]


def yaw_quat_wxyz(yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation by ``yaw`` (rad) about z."""
    return (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))


def ned_from_body(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation NED ← FRD body from MAVLink ``ATTITUDE`` Euler angles (rad, ZYX order)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
