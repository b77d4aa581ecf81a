"""Covariance-weighted fusion of a brick's code pose and dot pose, and the SO(3) tools for it.

A brick type may carry both ArUco codes and colour dots. In one frame the two detectors then
give two independent measurements of the same ``camera_from_brick``; :func:`fuse_frame`
pairs them (same layout, close enough) and :func:`fuse_pair` combines them as two Gaussian
measurements of one pose (information-weighted mean, in the tangent space of the code pose).

Covariance conventions:

* :class:`~drovisio.detect.result.BrickPose` carries the 6×6 covariance of ``(rvec, tvec)``
  (the rotation-vector *parameters*, as the PnP Jacobian gives it).
* Filtering and fusion work with a **right perturbation**: ``R = R̂ · exp([δθ]×)``, state
  ``(δθ, t)``. The two are related by the right Jacobian of SO(3):
  ``δθ = J_r(rvec) · δrvec`` (:func:`rvec_cov_to_tangent`, :func:`tangent_cov_to_rvec`).

Units: radians and metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from drovisio.detect.result import BrickPose
from drovisio.geometry import right_jacobian, right_jacobian_inv, skew, so3_exp, so3_log

__all__ = [
    "CHI2_6_999",
    "default_covariance",
    "dots_half_turn_symmetric",
    "fuse_frame",
    "fuse_pair",
    "pose_candidates",
    "right_jacobian",
    "right_jacobian_inv",
    "rot_z180",
    "rvec_cov_to_tangent",
    "skew",
    "so3_exp",
    "so3_log",
    "tangent_cov_to_rvec",
]

#: χ²(6) quantile at 0.999: two measurements further apart than this do not describe one pose.
CHI2_6_999 = 22.458

#: Used when a detector gives no covariance: 2° and 2 cm (1σ), uncorrelated.
DEFAULT_SIGMA_ROT = math.radians(2.0)
DEFAULT_SIGMA_T = 0.02


def _block_j(rvec: np.ndarray, inv: bool = False) -> np.ndarray:
    J = np.eye(6)
    J[:3, :3] = right_jacobian_inv(rvec) if inv else right_jacobian(rvec)
    return J


def rvec_cov_to_tangent(rvec: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """6×6 covariance of ``(rvec, tvec)`` → covariance of ``(δθ, t)`` (right perturbation)."""
    J = _block_j(rvec)
    return J @ np.asarray(cov, np.float64) @ J.T


def tangent_cov_to_rvec(rvec: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rvec_cov_to_tangent`."""
    J = _block_j(rvec, inv=True)
    return J @ np.asarray(cov, np.float64) @ J.T


def default_covariance() -> np.ndarray:
    return np.diag([DEFAULT_SIGMA_ROT ** 2] * 3 + [DEFAULT_SIGMA_T ** 2] * 3)


def _tangent_cov(p: BrickPose, floor_rot: float = 0.0, floor_t: float = 0.0) -> np.ndarray:
    cov = p.covariance
    if cov is None or not np.all(np.isfinite(cov)):
        return default_covariance()
    C = rvec_cov_to_tangent(p.rvec, cov)
    C = 0.5 * (C + C.T)
    C[np.diag_indices(3)] += floor_rot ** 2
    C[3 + np.arange(3), 3 + np.arange(3)] += floor_t ** 2
    return C


rot_z180 = np.diag([-1.0, -1.0, 1.0])


def pose_candidates(p: BrickPose, half_turn: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """(R, t) poses the measurement allows: the pose, its ambiguity alternatives and, for a
    symmetric layout (``rot180_z``) or when ``half_turn``, each of them turned half a turn
    about the brick's z."""
    out = [(so3_exp(p.rvec), np.asarray(p.tvec, np.float64).ravel())]
    for r, t in (p.alternatives or []):
        out.append((so3_exp(r), np.asarray(t, np.float64).ravel()))
    if p.symmetric or half_turn:
        out += [(R @ rot_z180, t) for R, t in out]
    return out


def dots_half_turn_symmetric(layout, tol: float = 1e-4) -> bool:
    """True when the layout's *dots alone* look the same after a half-turn about z (then a
    dot pose of a brick that also has codes may come in either half-turn)."""
    dots = layout.dot_markers() if getattr(layout, "has_dots", False) else []
    if not dots:
        return False
    pts = layout.dot_centers_m()
    colors = [d.color for d in dots]
    for j, p in enumerate(pts):
        q = p * np.array([-1.0, -1.0, 1.0])
        if not any(np.linalg.norm(pts[k] - q) <= tol and colors[k] == colors[j]
                   for k in range(len(pts))):
            return False
    return True


def _residual(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray) -> np.ndarray:
    return np.r_[so3_log(Ra.T @ Rb), tb - ta]


def fuse_pair(code: BrickPose, dots: BrickPose, gate: float = CHI2_6_999,
              half_turn: bool = False) -> tuple[BrickPose, float]:
    """Fuse a brick's code pose with its dot pose; return (pose, Mahalanobis² distance).

    The dot pose's candidate (alternative / half-turn; ``half_turn``: the layout's dots are
    symmetric even if the layout is not) nearest to the code pose is used. If
    the two disagree beyond ``gate`` (χ², 6 dof) the code pose is returned unchanged (its
    identity is certain; the dots may belong to a neighbour), with the distance.

    The result has ``method="fused"``, the code's instance and markers, the dot pose's image
    points appended, and the fused covariance of ``(rvec, tvec)``.
    """
    Ra, ta = so3_exp(code.rvec), np.asarray(code.tvec, np.float64).ravel()
    Ca = _tangent_cov(code)
    Cb = _tangent_cov(dots)
    scored = []
    for Rb, tb in pose_candidates(dots, half_turn):
        e = _residual(Ra, ta, Rb, tb)
        scored.append((float(e @ np.linalg.solve(Ca + Cb, e)), e))
    d2, e = min(scored, key=lambda x: x[0])
    if not np.isfinite(d2) or d2 > gate:
        return code, d2
    Ia, Ib = np.linalg.inv(Ca), np.linalg.inv(Cb)
    C = np.linalg.inv(Ia + Ib)
    C = 0.5 * (C + C.T)
    dx = C @ (Ib @ e)
    R = Ra @ so3_exp(dx[:3])
    t = ta + dx[3:]
    rvec = so3_log(R)
    pts = [x for x in (code.image_points, dots.image_points) if x is not None]
    rmse = math.sqrt(0.5 * (code.reprojection_rmse_px ** 2 + dots.reprojection_rmse_px ** 2))
    fused = replace(code, method="fused", rvec=rvec, tvec=t, reprojection_rmse_px=rmse,
                    ambiguous=False, alternatives=[], symmetric=False,
                    covariance=tangent_cov_to_rvec(rvec, C),
                    image_points=np.concatenate(pts) if pts else None)
    return fused, d2


def fuse_frame(poses: Sequence[BrickPose], layouts_with_both: set[str] | None = None,
               max_distance_m: float = 0.15, symmetric_dots: set[str] | None = None
               ) -> list[BrickPose]:
    """Per brick, fuse the code pose and the dot pose of one frame when both exist.

    Dot poses (``method == "dots"``) are paired with the nearest code pose of the same layout
    (translations closer than ``max_distance_m``, greedily, nearest pairs first); each pair
    becomes one fused pose. Unpaired poses pass unchanged. ``layouts_with_both`` limits the
    pairing to those layouts (None: any layout that has poses of both kinds);
    ``symmetric_dots`` names layouts whose dots alone are half-turn symmetric
    (:func:`dots_half_turn_symmetric`).
    """
    codes = [i for i, p in enumerate(poses) if p.method == "aruco"]
    dots = [i for i, p in enumerate(poses) if p.method == "dots"]
    if not codes or not dots:
        return list(poses)
    pairs = _close_pairs(poses, codes, dots, layouts_with_both, max_distance_m)
    used: set[int] = set()
    out: dict[int, BrickPose] = {}
    for _d, i, j in pairs:
        if i in used or j in used:
            continue
        fused, d2 = fuse_pair(poses[i], poses[j],
                              half_turn=poses[i].layout in (symmetric_dots or ()))
        if fused is poses[i]:  # disagreement: keep both as separate measurements
            continue
        used.update((i, j))
        out[i] = fused
    return [out.get(i, p) for i, p in enumerate(poses) if i not in used or i in out]


def _close_pairs(poses: Sequence[BrickPose], codes: list[int], dots: list[int],
                 layouts_with_both: set[str] | None, max_distance_m: float
                 ) -> list[tuple[float, int, int]]:
    """(distance m, code index, dot index) of each code and dot pose of the same layout
    closer than ``max_distance_m``, nearest first."""
    pairs = []
    for i in codes:
        for j in dots:
            a, b = poses[i], poses[j]
            if a.layout != b.layout:
                continue
            if layouts_with_both is not None and a.layout not in layouts_with_both:
                continue
            d = float(np.linalg.norm(np.ravel(a.tvec) - np.ravel(b.tvec)))
            if d <= max_distance_m:
                pairs.append((d, i, j))
    pairs.sort()
    return pairs
