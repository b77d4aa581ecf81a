"""The pose covariance as the outputs state it, and in words a person reads.

Inside, a pose's covariance is that of its parameters ``(rvec, tvec)`` (what the PnP
Jacobian gives, :class:`drovisio.detect.result.BrickPose`). Outside (the JSON output, ROS 2
messages) one convention is used, ROS's ``PoseWithCovariance`` one:

* parameters in the order ``(x, y, z, rotation about X, rotation about Y, rotation about Z)``;
* ``x, y, z``: the error of the translation, metres, in the *parent* frame (for
  ``camera_from_brick``: the camera frame, OpenCV axes);
* the rotation error is a small rotation ``δφ`` (radians) about the parent frame's fixed
  axes: ``R_true = exp([δφ]×) · R_reported`` (a left perturbation);
* units m², m·rad, rad²; a 6×6 symmetric matrix, row-major.

The rotation-vector parameters and ``δφ`` are related by the left Jacobian of SO(3):
``δφ = J_l(rvec) · δrvec`` with ``J_l(rvec) = R · J_r(rvec)``.
"""

from __future__ import annotations

import math

import numpy as np

from drovisio.geometry import right_jacobian, so3_exp, so3_log

__all__ = [
    "mahalanobis2",
    "parent_covariance",
    "pose_error",
    "rotate_parent_covariance",
    "sigma_summary",
    "uncertainty_words",
]


def parent_covariance(rvec: np.ndarray, cov_rvec_tvec: np.ndarray) -> np.ndarray:
    """6×6 covariance of ``(rvec, tvec)`` → the output convention (module doc).

    Args:
        rvec: Rotation vector of the pose (``parent_from_child``), radians.
        cov_rvec_tvec: 6×6 covariance of ``(rvec, tvec)`` (rad², m²).

    Returns:
        6×6 covariance of ``(x, y, z, δφx, δφy, δφz)`` in the parent frame (m², rad²).
    """
    r = np.asarray(rvec, np.float64).ravel()
    J_l = so3_exp(r) @ right_jacobian(r)
    M = np.zeros((6, 6))
    M[:3, 3:] = np.eye(3)   # position from tvec
    M[3:, :3] = J_l         # δφ from δrvec
    C = M @ np.asarray(cov_rvec_tvec, np.float64) @ M.T
    return 0.5 * (C + C.T)


def rotate_parent_covariance(new_from_parent: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """A covariance in the output convention, re-expressed with another parent frame.

    When the new parent is a rigid transform of the old one (``T_new = A · T_parent``, A a
    4×4 with rotation ``Q``), the position error and the left rotation error both turn by
    ``Q`` (the translation of A adds nothing: it is exact).
    """
    Q = np.asarray(new_from_parent, np.float64)[:3, :3]
    B = np.zeros((6, 6))
    B[:3, :3] = Q
    B[3:, 3:] = Q
    C = B @ np.asarray(cov, np.float64) @ B.T
    return 0.5 * (C + C.T)


def pose_error(R_est: np.ndarray, t_est: np.ndarray, R_true: np.ndarray,
               t_true: np.ndarray) -> np.ndarray:
    """``(t_est − t_true, log(R_est · R_trueᵀ))``: the error in the output convention (m,
    rad), whose covariance the reported one predicts."""
    return np.r_[np.ravel(t_est) - np.ravel(t_true), so3_log(np.asarray(R_est) @ np.asarray(R_true).T)]


def mahalanobis2(error: np.ndarray, cov: np.ndarray) -> float:
    """Squared Mahalanobis distance ``eᵀ C⁻¹ e`` (χ²(6) when the covariance is honest)."""
    e = np.ravel(error)
    return float(e @ np.linalg.solve(np.asarray(cov, np.float64), e))


def sigma_summary(cov: np.ndarray) -> tuple[float, float]:
    """One-sigma position (m) and rotation (rad) along the worst direction: the square roots
    of the largest eigenvalues of the position and rotation blocks."""
    C = np.asarray(cov, np.float64)
    pos = float(np.linalg.eigvalsh(0.5 * (C[:3, :3] + C[:3, :3].T))[-1])
    rot = float(np.linalg.eigvalsh(0.5 * (C[3:, 3:] + C[3:, 3:].T))[-1])
    return math.sqrt(max(pos, 0.0)), math.sqrt(max(rot, 0.0))


def uncertainty_words(cov: np.ndarray | None) -> str:
    """``"± 4 mm, ± 0.3°"`` (one sigma, worst direction) for a covariance in the output
    convention; ``""`` when there is none."""
    if cov is None or not np.all(np.isfinite(cov)):
        return ""
    s_t, s_r = sigma_summary(cov)
    mm = s_t * 1000.0
    pos = f"± {mm:.1f} mm" if mm < 10 else f"± {mm:.0f} mm" if mm < 1000 else \
        f"± {s_t:.1f} m"
    deg = math.degrees(s_r)
    rot = f"± {deg:.2f}°" if deg < 1 else f"± {deg:.1f}°"
    return f"{pos}, {rot}"
