"""Poses of many bricks at once, in normalised image coordinates (the dot detector's stage).

Everything works in *normalised* image coordinates (x/z, y/z of the OpenCV camera frame):
the measured points are undistorted once, after which the camera is an ideal pinhole (and a
dot — a circle on a plane — projects to an exact ellipse).

:func:`ippe_batch` gives each brick's two planar solutions (IPPE from a normalised-DLT
homography; SQPnP and :func:`mirror_pose` serve where three of four points are in a line).
Then, for all bricks and both solutions in one batch (numpy here; the same arithmetic
compiled in :mod:`drovisio.pose.batch_kernels` and :mod:`drovisio.pose.ippe_kernels` when
numba is there — the choice is made inside each function, never by a caller):

* :func:`refine_poses`: Levenberg–Marquardt on the reprojection error (after a dot was
  dropped or added);
* :func:`conic_center_offsets`: where the centre of a projected circle's ellipse lies relative
  to the projection of the circle's centre (they differ under perspective). The measured
  centres are ellipse centres; subtracting the offset predicted by the pose and taking one
  Gauss–Newton step (:func:`gn_step`, which also turns IPPE's pose into the least-squares
  one) gives unbiased poses and unbiased circle centres;
* :func:`pose_covariance_from_normal`: 6×6 covariance of (rvec, tvec).

:func:`homography_dlt` / :func:`pose_from_homography` (a pose from the plane-to-image
homography, batched) and :func:`layout_degeneracy` (is a subset of dots fit for a homography)
complete the set.

Conventions: ``camera_from_brick``: X_cam = R · X_brick + t; rotations as 3×3 matrices
inside, OpenCV rotation vectors at the edges.
"""

from __future__ import annotations

import numpy as np

from drovisio import _numba
from drovisio.geometry import skew, so3_exp, so3_log
from drovisio.pose import batch_kernels as _k
from drovisio.pose import ippe_kernels

__all__ = [
    "conic_center_offsets",
    "gn_step",
    "homography_dlt",
    "ippe_batch",
    "layout_degeneracy",
    "mirror_pose",
    "pose_covariance",
    "pose_covariance_from_normal",
    "pose_from_homography",
    "project_normalized",
    "refine_poses",
    "rotation_vectors",
]


def project_normalized(X: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    """Camera-frame points and normalised projections of (B, N, 3) points under (B) poses."""
    Y = np.einsum("bij,bnj->bni", R, X) + t[:, None, :]
    z = Y[..., 2]
    zs = np.where(np.abs(z) < 1e-12, 1e-12, z)
    return Y, Y[..., :2] / zs[..., None]


def layout_degeneracy(P: np.ndarray) -> float:
    """How far planar points are from a degenerate homography configuration.

    Returns the second-smallest singular value ratio of the DLT system of the points mapped
    onto themselves (after normalisation): ~0 when no four of them are in general position
    (e.g. three collinear and one more), ≳0.05 for a well-spread set.
    """
    P = np.asarray(P, np.float64)
    if P.shape[0] < 4:
        return 0.0
    _, s = _dlt(P[None], P[None], np.ones((1, P.shape[0])))
    return float(s[0, 7] / s[0, 0])


def _normalizer(p: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Hartley normalisation (B, 3, 3) of weighted 2-D points (B, N, 2)."""
    sw = np.maximum(w.sum(axis=1), 1e-12)
    c = (p * w[..., None]).sum(axis=1) / sw[:, None]
    d = np.sqrt(((p - c[:, None, :]) ** 2).sum(axis=2))
    md = (d * w).sum(axis=1) / sw
    s = np.sqrt(2) / np.maximum(md, 1e-12)
    T = np.zeros((p.shape[0], 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = s
    T[:, 0, 2] = -s * c[:, 0]
    T[:, 1, 2] = -s * c[:, 1]
    T[:, 2, 2] = 1
    return T


def _dlt(P: np.ndarray, q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    B = P.shape[0]
    Tp = _normalizer(P, w)
    Tq = _normalizer(q, w)
    Pn = P @ Tp[:, :2, :2].transpose(0, 2, 1) + Tp[:, None, :2, 2]
    qn = q @ Tq[:, :2, :2].transpose(0, 2, 1) + Tq[:, None, :2, 2]
    x, y = Pn[..., 0], Pn[..., 1]
    u, v = qn[..., 0], qn[..., 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    r1 = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], axis=-1)
    r2 = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], axis=-1)
    A = np.concatenate([r1, r2], axis=1) * np.concatenate([w, w], axis=1)[..., None]
    _, s, Vt = np.linalg.svd(A)
    Hn = Vt[:, -1, :].reshape(B, 3, 3)
    H = np.linalg.inv(Tq) @ Hn @ Tp
    return H, s


def ippe_batch(P: np.ndarray, q: np.ndarray, w: np.ndarray, plane_from_brick: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Both planar solutions of many bricks of one layout.

    Args:
        P: (B, N, 2) the points in the layout's plane frame (z = 0 there).
        q: (B, N, 2) normalised image points.
        w: (B, N) 1 = used, 0 = absent (at least 4 used, not degenerate).
        plane_from_brick: (4, 4) of the layout.

    Returns:
        (R (B, 2, 3, 3), t (B, 2, 3), cost (B, 2), ok (B,)): ``camera_from_brick``, best
        first; cost is the sum of squared normalised residuals (as :func:`refine_poses`).
    """
    Rpb = np.ascontiguousarray(plane_from_brick[:3, :3], np.float64)
    tpb = np.ascontiguousarray(plane_from_brick[:3, 3], np.float64)
    if _numba.enabled():
        R, t, half_cost, ok = ippe_kernels.ippe(*_f64(P, q, w), Rpb, tpb)
        return R, t, 2.0 * half_cost, ok
    import cv2

    B = P.shape[0]
    R = np.tile(np.eye(3), (B, 2, 1, 1))
    t = np.zeros((B, 2, 3))
    cost = np.full((B, 2), np.inf)
    ok = np.zeros(B, bool)
    for b in range(B):
        sel = w[b] > 0
        Pl = np.concatenate([P[b][sel], np.zeros((int(sel.sum()), 1))], axis=1)
        try:
            n, rvs, tvs, err = cv2.solvePnPGeneric(Pl.reshape(-1, 1, 3),
                                                   q[b][sel].reshape(-1, 1, 2), np.eye(3),
                                                   None, flags=cv2.SOLVEPNP_IPPE)
        except cv2.error:
            n = 0
        if not n:
            continue
        for k in range(2):
            j = min(k, n - 1)
            Rcp = cv2.Rodrigues(rvs[j])[0]                # camera_from_plane
            R[b, k] = Rcp @ Rpb
            t[b, k] = Rcp @ tpb + np.ravel(tvs[j])
            # OpenCV's error is the RMS over the 2N coordinates
            cost[b, k] = 2.0 * float(err[j, 0]) ** 2 * int(sel.sum())
        ok[b] = True
    return R, t, cost, ok


def homography_dlt(P: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Plane-to-image homographies by normalised DLT, batched.

    Args:
        P: (B, N, 2) plane coordinates.
        q: (B, N, 2) image points (normalised coordinates).
        w: (B, N) weights (0 = point absent).

    Returns:
        (B, 3, 3) homographies with ``q ~ H · [P, 1]``.
    """
    return _dlt(np.asarray(P, float), np.asarray(q, float), np.asarray(w, float))[0]


def pose_from_homography(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``camera_from_plane`` (R, t) from plane-to-normalised-image homographies (batched).

    The plane is z = 0 of its frame; the solution has the plane in front of the camera.
    """
    h1, h2, h3 = H[:, :, 0], H[:, :, 1], H[:, :, 2]
    lam = 1.0 / np.sqrt(np.maximum(np.linalg.norm(h1, axis=1) * np.linalg.norm(h2, axis=1),
                                   1e-300))
    lam = np.where(h3[:, 2] < 0, -lam, lam)
    r1, r2 = h1 * lam[:, None], h2 * lam[:, None]
    M = np.stack([r1, r2, np.cross(r1, r2)], axis=2)
    U, _, Vt = np.linalg.svd(M)
    D = np.ones((H.shape[0], 3))
    D[:, 2] = np.sign(np.linalg.det(U @ Vt))
    R = (U * D[:, None, :]) @ Vt
    return R, h3 * lam[:, None]


def mirror_pose(R: np.ndarray, t: np.ndarray, center: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """The planar pose ambiguity's other solution (to first order), batched.

    The plane's tilt is reflected about the line of sight through ``center`` (a point of the
    plane, in the plane's frame, e.g. the dots' centroid), which keeps that point and, under
    weak perspective, every image point where they are.

    Args:
        R, t: (B, 3, 3), (B, 3) ``camera_from_plane`` with the plane at its frame's z = 0.
        center: (B, 3) point of the plane in its frame.
    """
    c = np.einsum("bij,bj->bi", R, center) + t
    d = c / np.linalg.norm(c, axis=1, keepdims=True)
    refl = np.eye(3) - 2 * d[:, :, None] * d[:, None, :]
    R2 = refl @ R * np.array([1.0, 1.0, -1.0])[None, None, :]
    t2 = c - np.einsum("bij,bj->bi", R2, center)
    return R2, t2


def _residual_jacobian(X, q, w, R, t):
    """Weighted residuals (B, 2N), Jacobian (B, 2N, 6) w.r.t. (left rotation increment,
    translation), and the cost (B,) of poses; points behind the camera are penalised."""
    B, N = X.shape[:2]
    RX = X @ R.transpose(0, 2, 1)                            # (B, N, 3)
    Y = RX + t[:, None, :]
    z = Y[..., 2]
    bad = (z <= 1e-6) & (w > 0)
    iz = w / np.where(z > 1e-6, z, 1.0)                      # weight folded in
    xy = Y[..., :2] / np.where(z > 1e-6, z, 1.0)[..., None]
    res = ((q - xy) * w[..., None]).reshape(B, 2 * N)
    # d(x, y)/d(Y) = iz·[[1, 0, -x], [0, 1, -y]];  d(Y)/d(theta) = -[R·X]x,  d(Y)/d(t) = I
    Jp = np.zeros((B, N, 2, 3))
    Jp[..., 0, 0] = iz
    Jp[..., 1, 1] = iz
    Jp[..., :, 2] = -xy * iz[..., None]
    J = np.concatenate([Jp @ skew(RX), Jp], axis=3).reshape(B, 2 * N, 6)
    J[..., :3] *= -1.0
    cost = (res * res).sum(axis=1) + 1e6 * bad.sum(axis=1)
    return res, J, cost


def refine_poses(X: np.ndarray, q: np.ndarray, w: np.ndarray, R: np.ndarray, t: np.ndarray,
                 iterations: int = 6, tol: float = 1e-8
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levenberg–Marquardt refinement of many poses at once.

    Args:
        X: (B, N, 3) object points (brick frame).
        q: (B, N, 2) measured normalised image points.
        w: (B, N) weights (0 = absent).
        R, t: (B, 3, 3), (B, 3) initial ``camera_from_brick``.
        iterations: Most iterations.
        tol: Stop when no pose moves more than this (radians; metres per metre of depth).

    Returns:
        (R, t, cost) with cost the weighted sum of squared residuals (normalised units²).
    """
    if _numba.enabled():
        return _k.refine_poses(*_f64(X, q, w, R, t), int(iterations), float(tol))
    R = np.array(R, np.float64)
    t = np.array(t, np.float64)
    lam = np.full(R.shape[0], 1e-6)
    res, J, cost = _residual_jacobian(X, q, w, R, t)
    eye = np.eye(6)
    for _ in range(iterations):
        Jt = J.transpose(0, 2, 1)
        A = np.matmul(Jt, J)
        g = np.matmul(Jt, res[..., None])
        diag = A[:, np.arange(6), np.arange(6)]
        Ad = A + (lam[:, None] * np.maximum(diag, 1e-12))[:, :, None] * eye
        try:
            delta = np.linalg.solve(Ad, g)[..., 0]
        except np.linalg.LinAlgError:
            delta = np.stack([np.linalg.lstsq(Ad[b], g[b, :, 0], rcond=None)[0]
                              for b in range(R.shape[0])])
        R_new = np.matmul(so3_exp(delta[:, :3]), R)
        t_new = t + delta[:, 3:]
        res_n, J_n, cost_n = _residual_jacobian(X, q, w, R_new, t_new)
        better = cost_n <= cost
        if np.all(better):
            R, t, res, J, cost = R_new, t_new, res_n, J_n, cost_n
        else:
            R = np.where(better[:, None, None], R_new, R)
            t = np.where(better[:, None], t_new, t)
            J = np.where(better[:, None, None], J_n, J)
            res = np.where(better[:, None], res_n, res)
            cost = np.where(better, cost_n, cost)
        lam = np.where(better, np.maximum(lam * 0.1, 1e-9), lam * 10)
        step = np.abs(delta).max(axis=1)
        if np.all((step < tol) | (~better & (lam > 1e2))):
            break
    return R, t, cost


def gn_step(X: np.ndarray, q: np.ndarray, w: np.ndarray, R: np.ndarray, t: np.ndarray,
            return_normal: bool = False):
    """One Gauss–Newton step from (nearly) converged poses, e.g. IPPE's, or after a small
    change of the measurements (the ellipse-centre correction).

    Returns:
        (R, t, cost) at the new poses; with ``return_normal`` also the normal matrices JᵀJ
        (B, 6, 6) (for the covariance) and each point's residual distance (B, N).
    """
    if _numba.enabled():
        R, t, cost, A, resid = _k.gn_step(*_f64(X, q, w, R, t))
        return (R, t, cost, A, resid) if return_normal else (R, t, cost)
    res, J, _ = _residual_jacobian(X, q, w, R, t)
    Jt = J.transpose(0, 2, 1)
    A = Jt @ J
    delta = np.linalg.solve(A + 1e-18 * np.eye(6), Jt @ res[..., None])[..., 0]
    R = so3_exp(delta[:, :3]) @ R
    t = t + delta[:, 3:]
    cost, resid = _cost(X, q, w, R, t)
    return (R, t, cost, A, resid) if return_normal else (R, t, cost)


def _f64(*arrays):
    """C-contiguous float64 copies-if-needed (one compiled specialisation per kernel)."""
    return tuple(np.ascontiguousarray(a, np.float64) for a in arrays)


def _cost(X, q, w, R, t):
    """Costs (B,) and each point's residual distance (B, N) (normalised units)."""
    Y = X @ R.transpose(0, 2, 1) + t[:, None, :]
    z = Y[..., 2]
    d = (q - Y[..., :2] / np.where(z > 1e-6, z, 1.0)[..., None]) * w[..., None]
    d2 = (d * d).sum(axis=2)
    return d2.sum(axis=1) + 1e6 * ((z <= 1e-6) & (w > 0)).sum(axis=1), np.sqrt(d2)


def _jacobian(X, R, t):
    """Unweighted Jacobian (B, N, 2, 6) of the normalised projections."""
    w = np.ones(X.shape[:2])
    _, J, _ = _residual_jacobian(X, np.zeros(X.shape[:2] + (2,)), w, R, t)
    return J.reshape(X.shape[0], X.shape[1], 2, 6), None, None


def conic_center_offsets(X: np.ndarray, normals: np.ndarray, radii: np.ndarray,
                         R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Ellipse centre minus projected circle centre, normalised coordinates (B, N, 2).

    A circle of radius r, centre C and unit normal n (brick frame) projects under a pinhole to
    a conic whose centre is the pole of the line at infinity:
    c ∝ r²(e_z − n_c n_c,z) − Y Y_z, with Y = R·C + t and n_c = R·n (camera frame).
    """
    if _numba.enabled():
        return _k.conic_center_offsets(*_f64(X, normals, radii, R, t))
    Y = np.einsum("bij,bnj->bni", R, X) + t[:, None, :]
    nc = np.einsum("bij,bnj->bni", R, normals)
    r2 = (radii ** 2)[..., None]
    c = r2 * (np.array([0.0, 0.0, 1.0]) - nc * nc[..., 2:3]) - Y * Y[..., 2:3]
    cz = np.where(np.abs(c[..., 2]) < 1e-300, 1e-300, c[..., 2])
    yz = np.where(np.abs(Y[..., 2]) < 1e-12, 1e-12, Y[..., 2])
    return c[..., :2] / cz[..., None] - Y[..., :2] / yz[..., None]


def _jl_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian of SO(3) at rotation vectors (B, 3)."""
    th = np.linalg.norm(phi, axis=1)[:, None, None]
    S = skew(phi)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    sn = np.sin(ths)
    sn = np.where(np.abs(sn) < 1e-12, 1e-12, sn)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths ** 2 - (1 + np.cos(ths)) / (2 * ths * sn))
    return np.eye(3) - 0.5 * S + c * (S @ S)


def pose_covariance_from_normal(A: np.ndarray, R: np.ndarray, t: np.ndarray,
                                rvec: np.ndarray, sigma_norm: np.ndarray) -> np.ndarray:
    """6×6 covariances of (rvec, tvec) from normal matrices JᵀJ (B, 6, 6) of the
    (left rotation increment, translation) parametrisation, batched.

    Args:
        A: (B, 6, 6) normal matrices; R, t: the poses; rvec: (B, 3) their rotation vectors.
        sigma_norm: (B,) standard deviation of one image coordinate, normalised units.
    """
    if _numba.enabled():
        return _k.pose_covariance(*_f64(A, rvec, sigma_norm))
    try:
        cov = np.linalg.inv(A + 1e-18 * np.eye(6))
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(A)
    cov = cov * (sigma_norm ** 2)[:, None, None]
    M = np.zeros_like(cov)
    M[:, :3, :3] = _jl_inv(rvec)
    M[:, 3:, 3:] = np.eye(3)
    return M @ cov @ M.transpose(0, 2, 1)


def rotation_vectors(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (B, 3) of rotations (B, 3, 3) (OpenCV's Rodrigues for a few)."""
    if _numba.enabled():
        return _k.so3_log(*_f64(R))
    if R.shape[0] > 6:
        return so3_log(R)
    import cv2

    return np.array([cv2.Rodrigues(Rk)[0].ravel() for Rk in R]).reshape(-1, 3)


def pose_covariance(X: np.ndarray, w: np.ndarray, R: np.ndarray, t: np.ndarray,
                    sigma_norm: np.ndarray) -> np.ndarray:
    """6×6 covariances of (rvec, tvec), batched.

    Args:
        X: (B, N, 3) object points; w: (B, N) weights; R, t: poses.
        sigma_norm: (B,) standard deviation of one image coordinate, normalised units.
    """
    J, _, _ = _jacobian(X, R, t)
    wJ = J * w[..., None, None]
    A = np.einsum("bnki,bnkj->bij", wJ, J)
    cov = np.linalg.pinv(A) * (sigma_norm ** 2)[:, None, None]
    M = np.zeros_like(cov)
    M[:, :3, :3] = _jl_inv(so3_log(R))
    M[:, 3:, 3:] = np.eye(3)
    return M @ cov @ M.transpose(0, 2, 1)
