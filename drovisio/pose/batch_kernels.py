"""Compiled kernels of the batched poses (numba): Levenberg–Marquardt and Gauss–Newton
on the reprojection error, ellipse-centre offsets, SO(3) log and the pose covariance.

The numpy reference implementations are in :mod:`drovisio.pose.batch` (tests compare the two);
each function there chooses its kernel itself when :func:`drovisio._numba.enabled`.

Conventions are those of the numpy versions: pixel (0, 0) is the centre of the top-left
pixel; normalised image coordinates are x/z, y/z of the OpenCV camera frame; poses are
``camera_from_brick`` (X_cam = R · X + t).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import jit as _jit


@_jit
def _rodrigues(w0, w1, w2, R):
    th = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    ths = max(th, 1e-12)
    a = math.sin(th) / ths
    b = 2 * math.sin(th / 2) ** 2 / (ths * ths)
    # R = I + a·S + b·S², S = [w]x
    R[0, 0] = 1 - b * (w1 * w1 + w2 * w2)
    R[1, 1] = 1 - b * (w0 * w0 + w2 * w2)
    R[2, 2] = 1 - b * (w0 * w0 + w1 * w1)
    R[0, 1] = -a * w2 + b * w0 * w1
    R[1, 0] = a * w2 + b * w0 * w1
    R[0, 2] = a * w1 + b * w0 * w2
    R[2, 0] = -a * w1 + b * w0 * w2
    R[1, 2] = -a * w0 + b * w1 * w2
    R[2, 1] = a * w0 + b * w1 * w2


@_jit
def solve_sym(A, g, n, x):
    """x = A⁻¹ g for a small square system (Gaussian elimination, partial pivoting); returns
    False (x = 0) when singular. A and g are overwritten."""
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if abs(A[p, c]) < 1e-300:
            for r in range(n):
                x[r] = 0.0
            return False
        if p != c:
            for k in range(n):
                tmp = A[c, k]
                A[c, k] = A[p, k]
                A[p, k] = tmp
            tmp = g[c]
            g[c] = g[p]
            g[p] = tmp
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            if f != 0.0:
                for k in range(c, n):
                    A[r, k] -= f * A[c, k]
                g[r] -= f * g[c]
    for r in range(n - 1, -1, -1):
        s = g[r]
        for k in range(r + 1, n):
            s -= A[r, k] * x[k]
        x[r] = s / A[r, r]
    return True


@_jit
def _normal_eq(X, q, w, R, t, A, g):
    """JᵀJ (6×6) and Jᵀr (6) of one pose (parameters: left rotation increment, translation;
    as :func:`drovisio.pose.batch._residual_jacobian`), returns the cost."""
    for r in range(6):
        g[r] = 0.0
        for c in range(6):
            A[r, c] = 0.0
    cost = 0.0
    J = np.empty((2, 6))
    for n in range(X.shape[0]):
        wn = w[n]
        if wn == 0.0:
            continue
        rx = R[0, 0] * X[n, 0] + R[0, 1] * X[n, 1] + R[0, 2] * X[n, 2]
        ry = R[1, 0] * X[n, 0] + R[1, 1] * X[n, 1] + R[1, 2] * X[n, 2]
        rz = R[2, 0] * X[n, 0] + R[2, 1] * X[n, 1] + R[2, 2] * X[n, 2]
        Yz = rz + t[2]
        if Yz <= 1e-6:
            cost += 1e6
            zs = 1.0
        else:
            zs = Yz
        x = (rx + t[0]) / zs
        y = (ry + t[1]) / zs
        iz = wn / zs
        r0 = (q[n, 0] - x) * wn
        r1 = (q[n, 1] - y) * wn
        cost += r0 * r0 + r1 * r1
        # Jp = iz [[1, 0, -x], [0, 1, -y]];  J_rot = -(Jp @ [RX]x)
        # [RX]x = [[0, -rz, ry], [rz, 0, -rx], [-ry, rx, 0]]
        J[0, 0] = -(iz * 0 + 0 * rz + (-x * iz) * (-ry))
        J[0, 1] = -(iz * (-rz) + (-x * iz) * rx)
        J[0, 2] = -(iz * ry)
        J[1, 0] = -(iz * rz + (-y * iz) * (-ry))
        J[1, 1] = -((-y * iz) * rx)
        J[1, 2] = -(iz * (-rx))
        J[0, 3] = iz
        J[0, 4] = 0.0
        J[0, 5] = -x * iz
        J[1, 3] = 0.0
        J[1, 4] = iz
        J[1, 5] = -y * iz
        for a in range(6):
            g[a] += J[0, a] * r0 + J[1, a] * r1
            for c in range(a, 6):
                A[a, c] += J[0, a] * J[0, c] + J[1, a] * J[1, c]
    for a in range(6):
        for c in range(a):
            A[a, c] = A[c, a]
    return cost


@_jit
def _cost(X, q, w, R, t, resid):
    cost = 0.0
    for n in range(X.shape[0]):
        wn = w[n]
        Y0 = R[0, 0] * X[n, 0] + R[0, 1] * X[n, 1] + R[0, 2] * X[n, 2] + t[0]
        Y1 = R[1, 0] * X[n, 0] + R[1, 1] * X[n, 1] + R[1, 2] * X[n, 2] + t[1]
        Y2 = R[2, 0] * X[n, 0] + R[2, 1] * X[n, 1] + R[2, 2] * X[n, 2] + t[2]
        zs = Y2 if Y2 > 1e-6 else 1.0
        d0 = (q[n, 0] - Y0 / zs) * wn
        d1 = (q[n, 1] - Y1 / zs) * wn
        dd = d0 * d0 + d1 * d1
        resid[n] = math.sqrt(dd)
        cost += dd
        if Y2 <= 1e-6 and wn > 0:
            cost += 1e6
    return cost


@_jit
def _apply(delta, R, t, Rn, tn):
    dR = np.empty((3, 3))
    _rodrigues(delta[0], delta[1], delta[2], dR)
    for r in range(3):
        for c in range(3):
            Rn[r, c] = dR[r, 0] * R[0, c] + dR[r, 1] * R[1, c] + dR[r, 2] * R[2, c]
        tn[r] = t[r] + delta[3 + r]


@_jit
def refine_poses(X, q, w, R, t, iterations, tol):
    """Levenberg–Marquardt of many poses (as :func:`drovisio.pose.batch.refine_poses`; each pose
    stops on its own). Returns (R, t, cost) (new arrays)."""
    B = X.shape[0]
    Ro = R.copy()
    to = t.copy()
    cost_out = np.empty(B)
    A = np.empty((6, 6))
    Ad = np.empty((6, 6))
    g = np.empty(6)
    gd = np.empty(6)
    delta = np.empty(6)
    Rn = np.empty((3, 3))
    tn = np.empty(3)
    A2 = np.empty((6, 6))
    g2 = np.empty(6)
    for b in range(B):
        lam = 1e-6
        cost = _normal_eq(X[b], q[b], w[b], Ro[b], to[b], A, g)
        for _ in range(iterations):
            for r in range(6):
                gd[r] = g[r]
                for c in range(6):
                    Ad[r, c] = A[r, c]
                Ad[r, r] += lam * max(A[r, r], 1e-12)
            solve_sym(Ad, gd, 6, delta)
            _apply(delta, Ro[b], to[b], Rn, tn)
            cost_n = _normal_eq(X[b], q[b], w[b], Rn, tn, A2, g2)
            better = cost_n <= cost
            if better:
                Ro[b] = Rn
                to[b] = tn
                A[:, :] = A2
                g[:] = g2
                cost = cost_n
                lam = max(lam * 0.1, 1e-9)
            else:
                lam = lam * 10
            step = 0.0
            for r in range(6):
                step = max(step, abs(delta[r]))
            if step < tol or (not better and lam > 1e2):
                break
        cost_out[b] = cost
    return Ro, to, cost_out


@_jit
def gn_step(X, q, w, R, t):
    """One Gauss–Newton step of many poses (as :func:`drovisio.pose.batch.gn_step` with
    ``return_normal``): (R, t, cost, normal matrices (B, 6, 6), residuals (B, N))."""
    B = X.shape[0]
    N = X.shape[1]
    Ro = np.empty_like(R)
    to = np.empty_like(t)
    cost = np.empty(B)
    Aout = np.empty((B, 6, 6))
    resid = np.empty((B, N))
    A = np.empty((6, 6))
    g = np.empty(6)
    delta = np.empty(6)
    for b in range(B):
        _normal_eq(X[b], q[b], w[b], R[b], t[b], A, g)
        Aout[b] = A
        for r in range(6):
            A[r, r] += 1e-18
        solve_sym(A, g, 6, delta)
        _apply(delta, R[b], t[b], Ro[b], to[b])
        cost[b] = _cost(X[b], q[b], w[b], Ro[b], to[b], resid[b])
    return Ro, to, cost, Aout, resid


@_jit
def so3_log(R):
    """Rotation vectors (B, 3) of rotations (B, 3, 3) (as :func:`drovisio.pose.batch.so3_log`)."""
    B = R.shape[0]
    out = np.empty((B, 3))
    for b in range(B):
        tr = R[b, 0, 0] + R[b, 1, 1] + R[b, 2, 2]
        cos = min(max((tr - 1) / 2, -1.0), 1.0)
        th = math.acos(cos)
        v0 = R[b, 2, 1] - R[b, 1, 2]
        v1 = R[b, 0, 2] - R[b, 2, 0]
        v2 = R[b, 1, 0] - R[b, 0, 1]
        if th > math.pi - 1e-4:
            # axis from the largest diagonal entry of (R + I) / 2
            k = 0
            for i in range(1, 3):
                if R[b, i, i] > R[b, k, k]:
                    k = i
            d = max((R[b, k, k] + 1) / 2, 1e-12)
            a0 = (R[b, 0, k] + (1.0 if k == 0 else 0.0)) / 2 / math.sqrt(d)
            a1 = (R[b, 1, k] + (1.0 if k == 1 else 0.0)) / 2 / math.sqrt(d)
            a2 = (R[b, 2, k] + (1.0 if k == 2 else 0.0)) / 2 / math.sqrt(d)
            nrm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            a0 /= nrm
            a1 /= nrm
            a2 /= nrm
            if a0 * v0 + a1 * v1 + a2 * v2 < 0:
                a0, a1, a2 = -a0, -a1, -a2
            out[b, 0] = a0 * th
            out[b, 1] = a1 * th
            out[b, 2] = a2 * th
        else:
            sn = math.sin(th)
            f = th / (2 * sn) if sn > 1e-7 else 0.5
            out[b, 0] = v0 * f
            out[b, 1] = v1 * f
            out[b, 2] = v2 * f
    return out


@_jit
def _invert6(A, b, M):
    """Inverse of A[b] + 1e-18·I into M[:, 6:] (Gauss–Jordan with partial pivoting on the
    augmented (6, 12) matrix M); False when singular."""
    for r in range(6):
        for c in range(6):
            M[r, c] = A[b, r, c] + (1e-18 if r == c else 0.0)
            M[r, 6 + c] = 1.0 if r == c else 0.0
    for c in range(6):
        p = c
        for r in range(c + 1, 6):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if abs(M[p, c]) < 1e-300:
            return False
        if p != c:
            for k in range(12):
                tmp = M[c, k]
                M[c, k] = M[p, k]
                M[p, k] = tmp
        piv = M[c, c]
        for k in range(12):
            M[c, k] /= piv
        for r in range(6):
            if r != c and M[r, c] != 0.0:
                f = M[r, c]
                for k in range(12):
                    M[r, k] -= f * M[c, k]
    return True


@_jit
def _left_jacobian_inv(rvec, b, Jl):
    """Inverse left Jacobian of SO(3) at rotation vector rvec[b] into Jl (3, 3)."""
    p0 = rvec[b, 0]
    p1 = rvec[b, 1]
    p2 = rvec[b, 2]
    th = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if th < 1e-6:
        cc = 1.0 / 12.0
    else:
        sn = math.sin(th)
        if abs(sn) < 1e-12:
            sn = 1e-12
        cc = 1.0 / (th * th) - (1 + math.cos(th)) / (2 * th * sn)
    S = np.empty((3, 3))
    S[0, 0] = 0.0
    S[0, 1] = -p2
    S[0, 2] = p1
    S[1, 0] = p2
    S[1, 1] = 0.0
    S[1, 2] = -p0
    S[2, 0] = -p1
    S[2, 1] = p0
    S[2, 2] = 0.0
    for r in range(3):
        for c in range(3):
            ss = 0.0
            for k in range(3):
                ss += S[r, k] * S[k, c]
            Jl[r, c] = (1.0 if r == c else 0.0) - 0.5 * S[r, c] + cc * ss


@_jit
def _sandwich(Jl, C, out, b):
    """out[b] = M C Mᵀ with M = diag(Jl, I) (6, 6), skipping M's zeros."""
    for r in range(6):
        for c in range(6):
            acc = 0.0
            for i in range(6):
                mri = (Jl[r, i] if i < 3 else 0.0) if r < 3 else (1.0 if i == r else 0.0)
                if mri == 0.0:
                    continue
                for j in range(6):
                    mcj = (Jl[c, j] if j < 3 else 0.0) if c < 3 else (1.0 if j == c else 0.0)
                    if mcj != 0.0:
                        acc += mri * C[i, j] * mcj
            out[b, r, c] = acc


@_jit
def pose_covariance(A, rvec, sigma):
    """6×6 covariances of (rvec, tvec) from normal matrices (as
    :func:`drovisio.pose.batch.pose_covariance_from_normal`)."""
    B = A.shape[0]
    out = np.empty((B, 6, 6))
    M = np.empty((6, 12))
    Jl = np.empty((3, 3))
    C = np.empty((6, 6))
    for b in range(B):
        if not _invert6(A, b, M):
            for r in range(6):
                for c in range(6):
                    out[b, r, c] = np.inf if r == c else 0.0
            continue
        s2 = sigma[b] * sigma[b]
        for r in range(6):
            for c in range(6):
                C[r, c] = M[r, 6 + c] * s2
        _left_jacobian_inv(rvec, b, Jl)
        _sandwich(Jl, C, out, b)
    return out


@_jit
def conic_center_offsets(X, normals, radii, R, t):
    """Ellipse centre minus projected circle centre, normalised (B, N, 2) (as
    :func:`drovisio.pose.batch.conic_center_offsets`)."""
    B = X.shape[0]
    N = X.shape[1]
    out = np.empty((B, N, 2))
    for b in range(B):
        for n in range(N):
            Y0 = R[b, 0, 0] * X[b, n, 0] + R[b, 0, 1] * X[b, n, 1] + R[b, 0, 2] * X[b, n, 2] \
                + t[b, 0]
            Y1 = R[b, 1, 0] * X[b, n, 0] + R[b, 1, 1] * X[b, n, 1] + R[b, 1, 2] * X[b, n, 2] \
                + t[b, 1]
            Y2 = R[b, 2, 0] * X[b, n, 0] + R[b, 2, 1] * X[b, n, 1] + R[b, 2, 2] * X[b, n, 2] \
                + t[b, 2]
            n0 = R[b, 0, 0] * normals[b, n, 0] + R[b, 0, 1] * normals[b, n, 1] \
                + R[b, 0, 2] * normals[b, n, 2]
            n1 = R[b, 1, 0] * normals[b, n, 0] + R[b, 1, 1] * normals[b, n, 1] \
                + R[b, 1, 2] * normals[b, n, 2]
            n2 = R[b, 2, 0] * normals[b, n, 0] + R[b, 2, 1] * normals[b, n, 1] \
                + R[b, 2, 2] * normals[b, n, 2]
            r2 = radii[b, n] * radii[b, n]
            c0 = r2 * (-n0 * n2) - Y0 * Y2
            c1 = r2 * (-n1 * n2) - Y1 * Y2
            c2 = r2 * (1.0 - n2 * n2) - Y2 * Y2
            if abs(c2) < 1e-300:
                c2 = 1e-300
            yz = Y2 if abs(Y2) >= 1e-12 else 1e-12
            out[b, n, 0] = c0 / c2 - Y0 / yz
            out[b, n, 1] = c1 / c2 - Y1 / yz
    return out
