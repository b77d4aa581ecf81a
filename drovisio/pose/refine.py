"""Refinement of one brick's pose in pixels through the full lens model: weighted
Gauss–Newton (Levenberg-damped) with an optional flat-lying prior, Huber weights, whole codes
left out when they disagree, and the pose covariance from the information matrix.

Conventions: ``camera_from_object`` as (rvec, tvec); pixels are distorted image pixels;
``Winv`` is the (2N, 2N) inverse covariance of the image points in the order x0, y0, x1, ...
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.pose.ambiguity import MIN_DOF_FOR_SCALE, noise_scale
from drovisio.pose.candidate import PoseCandidate

__all__ = ["gauss_newton", "group_outliers", "measured_scale", "point_distances",
           "points_information", "pose_covariance", "robust_weights"]


def points_information(points_cov: np.ndarray | None, n: int, default_sigma: float
                       ) -> np.ndarray:
    """Inverse covariance (2n, 2n) of the image points."""
    if points_cov is None:
        return np.eye(2 * n) / default_sigma ** 2
    C = np.asarray(points_cov, np.float64)
    if C.ndim == 0 or C.size == 1:
        return np.eye(2 * n) / float(C) ** 2  # a scalar sigma
    if C.ndim == 1:  # per-point sigma
        return np.diag(np.repeat(1.0 / C ** 2, 2))
    try:
        return np.linalg.inv(C)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(C)


def _up_residual(rvec: np.ndarray, up_axis: np.ndarray, g: np.ndarray, sigma: float):
    """Residual (3,) of the flat-lying prior, (R·up + g)/sigma, and its Jacobian (3, 3)."""
    R, dR = cv2.Rodrigues(rvec.reshape(3, 1))  # dR: (3, 9), dR[k, 3 i + j] = d R_ij / d r_k
    r0 = (R @ up_axis + g) / sigma
    J = (dR.reshape(3, 3, 3) @ up_axis).T / sigma  # J[i, k] = sum_j dR_ij/dr_k up_j
    return r0, J


def gauss_newton(obj, img, cand: PoseCandidate, camera: Camera, Winv, iterations: int = 2,
                  prior: tuple[np.ndarray, np.ndarray, float] | None = None
                  ) -> tuple[PoseCandidate, np.ndarray]:
    """Weighted Gauss–Newton in pixels (Levenberg-damped), optionally with the flat-lying
    prior ``(up_axis, gravity, sigma_rad)``. Returns the refined candidate (χ² of the image
    part) and the information matrix (6×6, prior included) at it."""
    rvec, tvec = cand.rvec.copy(), cand.tvec.copy()
    best_rt = (rvec, tvec)
    best_cost = np.inf
    best_chi2 = np.inf
    best_sq = np.inf
    best_d = None
    info = None
    lam = 1e-6
    obj3 = obj.reshape(-1, 1, 3)
    for it in range(iterations + 1):
        last = it == iterations
        if last and it > 0:  # the final check needs no Jacobian (the information matrix
            # is taken at the previous point: one small step away)
            px, _ = camera.project_points(obj3, rvec, tvec)
            J = None
        else:
            px, J = camera.project_points(obj3, rvec, tvec)
        d = img - px.reshape(-1, 2)
        r = d.ravel()
        chi2 = float(r @ Winv @ r)
        cost = chi2
        if J is not None:
            JW = J.T @ Winv
            A = JW @ J
            b = JW @ r
        if prior is not None:
            rp, Jp = _up_residual(rvec, *prior)
            cost += float(rp @ rp)
            if J is not None:
                A[:3, :3] += Jp.T @ Jp
                b[:3] -= Jp.T @ rp
        if cost <= best_cost:
            best_cost, best_chi2, best_rt = cost, chi2, (rvec, tvec)
            if J is not None:
                info = A
            best_sq = float((d * d).sum())
            best_d = d
            lam = max(lam * 0.1, 1e-9)
        else:  # worse: back to the best, damp more
            rvec, tvec = best_rt
            lam *= 100.0
            continue
        if it == iterations:
            break
        A_d = A.copy()
        A_d.flat[::7] *= 1.0 + lam
        ok, step = cv2.solve(A_d, b.reshape(6, 1), flags=cv2.DECOMP_CHOLESKY)
        if not ok:
            ok, step = cv2.solve(A_d, b.reshape(6, 1), flags=cv2.DECOMP_SVD)
            if not ok:
                break
        step = step.ravel()
        if (float(np.abs(step[:3]).max()) < 1e-9
                and float(np.abs(step[3:]).max()) < 1e-9 * (1.0 + float(np.abs(tvec).max()))):
            break  # converged: the next point would be this one
        rvec = rvec + step[:3]
        tvec = tvec + step[3:]
    n = len(obj)
    out = PoseCandidate(best_rt[0].copy(), best_rt[1].copy(), math.sqrt(best_sq / n), best_chi2)
    if best_d is not None:
        out.__dict__["_residual"] = best_d  # (N, 2) image - projection, px (for the weights)
    return out, np.zeros((6, 6)) if info is None else info   # None: no finite cost at all


def robust_weights(obj, img, cand: PoseCandidate, camera: Camera, Winv: np.ndarray,
                    k: float) -> np.ndarray:
    """Huber weights (N,) of the points at a pose: 1 for a point whose reprojection residual
    is within ``k`` standard deviations of its own covariance (the 2×2 block of the inverse
    of ``Winv``), ``k / d`` for one ``d > k`` away."""
    r = cand.__dict__.get("_residual")
    if r is None:
        px, _ = camera.project_points(obj.reshape(-1, 1, 3), cand.rvec, cand.tvec)
        r = img - px.reshape(-1, 2)
    rr = r.ravel()
    if not float(rr @ Winv @ rr) > k * k:
        # a point's own Mahalanobis distance is at most the whole residual's (a marginal
        # of a Gaussian): nothing to weigh down, no inversion
        return np.ones(len(obj))
    ok, C = cv2.invert(Winv, flags=cv2.DECOMP_CHOLESKY)
    if not ok:
        return np.ones(len(obj))
    n = len(obj)
    blocks = C.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n), :]  # (n, 2, 2)
    a, b, d = blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 1, 1]
    det = a * d - b * b
    x, y = r[:, 0], r[:, 1]
    m = np.where(det > 0, (d * x * x - 2 * b * x * y + a * y * y) / np.where(det > 0, det, 1),
                 0.0)
    dist = np.sqrt(np.maximum(m, 0.0))
    return np.where(dist > k, k / np.maximum(dist, 1e-12), 1.0)


def point_distances(obj, img, cand: PoseCandidate, camera: Camera, Winv: np.ndarray
                     ) -> np.ndarray | None:
    """Squared Mahalanobis distance (N,) of each point's reprojection residual at a pose, by
    its own 2×2 covariance (the diagonal block of the inverse of ``Winv``); None when
    ``Winv`` is not invertible."""
    n = len(obj)
    px, _ = camera.project_points(obj.reshape(-1, 1, 3), cand.rvec, cand.tvec)
    r = img - px.reshape(-1, 2)
    ok, C = cv2.invert(Winv, flags=cv2.DECOMP_CHOLESKY)
    if not ok:
        return None
    blocks = C.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n), :]  # (n, 2, 2)
    a, b, d = blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 1, 1]
    det = a * d - b * b
    x, y = r[:, 0], r[:, 1]
    return np.where(det > 0, (d * x * x - 2 * b * x * y + a * y * y)
                    / np.where(det > 0, det, 1.0), 0.0)


def group_outliers(m: np.ndarray, groups: np.ndarray, dof: int) -> np.ndarray:
    """Which groups of points (codes) to leave out of a pose: those with a point beyond
    what the brick's own residuals allow. Returns a weight per point (N,), 0 or 1.

    Huber weights (:func:`robust_weights`) bound a wrong corner's pull but keep it at
    ``ROBUST_K`` (:mod:`drovisio.pose.solve`) standard deviations: a code fitted to the wrong edges (its corners 1-4 px
    off on a 19-px code) still moved a two-code brick's pose by a centimetre through a
    fisheye's rim. Its other corners share its wrong homography, so the whole code goes.
    The noise scale is measured robustly from the brick itself (the median squared distance
    against χ²(2)'s, 1.386, corrected for the fitted parameters; never below the assumed
    noise); the limit is the χ²(2) quantile a right point exceeds with chance 0.1 % over the
    brick's points, ``2 ln(N / 0.001)``. At least one group always stays.

    Args:
        m: (N,) squared Mahalanobis distances of the points (:func:`point_distances`).
        groups: (N,) group label of each point (the code it belongs to).
        dof: Degrees of freedom of the fit (2N − 6).
    """
    n = len(m)
    s2 = max(1.0, float(np.median(m)) / 1.386 * (2.0 * n / max(dof, 1)))
    bad_pts = m / s2 > 2.0 * math.log(n / 0.001)
    if not bad_pts.any():
        return np.ones(n)
    labels, inv = np.unique(groups, return_inverse=True)
    bad = np.zeros(len(labels), bool)
    np.logical_or.at(bad, inv, bad_pts)
    if bad.all():   # nothing to tell the pose from: keep everything
        return np.ones(n)
    return np.where(bad[inv], 0.0, 1.0)


def pose_covariance(info: np.ndarray, chi2: float, dof: int) -> np.ndarray:
    """(Jᵀ Σ⁻¹ J)⁻¹, inflated by χ²/dof when the residuals show more noise than assumed."""
    ok, cov = cv2.invert(info, flags=cv2.DECOMP_CHOLESKY)
    if not ok:  # not positive definite (a degenerate view): the pseudo-inverse
        cov = np.linalg.pinv(info)
    if dof > 0 and chi2 / dof > 1.0:
        cov = cov * (chi2 / dof)
    return 0.5 * (cov + cov.T)


def measured_scale(obj, img, cand: PoseCandidate, camera: Camera, Winv: np.ndarray,
                    dof: int) -> float:
    """The point noise the best candidate's residuals show, as a factor on the assumed
    variance (:func:`drovisio.pose.ambiguity.noise_scale`)."""
    if dof < MIN_DOF_FOR_SCALE:
        return 1.0
    px, _ = camera.project_points(obj.reshape(-1, 1, 3), cand.rvec, cand.tvec)
    r = (px.reshape(-1, 2) - img).ravel()
    try:  # whitened: e = Lᵀ r with L Lᵀ = Winv, so |e|² = χ²
        e = np.linalg.cholesky(Winv).T @ r
    except np.linalg.LinAlgError:
        return 1.0
    return noise_scale(e, dof)
