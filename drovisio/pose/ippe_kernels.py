"""Compiled IPPE (numba): both solutions of the planar ambiguity of many bricks at once, from
a normalised-DLT homography of each brick's plane.

The numpy / OpenCV reference is :func:`drovisio.pose.batch.ippe_batch`, which chooses this
kernel itself when :func:`drovisio._numba.enabled` (tests compare the two). Poses are
``camera_from_brick`` (X_cam = R · X + t); image points are normalised (x/z, y/z).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import jit as _jit
from drovisio.pose.batch_kernels import solve_sym


@_jit
def _mm3(A, B, out):
    """out = A·B for 3×3 matrices (no BLAS: numba's needs SciPy)."""
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for k in range(3):
                acc += A[r, k] * B[k, c]
            out[r, c] = acc


@_jit
def _homography(P, q, w, H):
    """Plane → image homography of weighted points (normalised DLT with h33 = 1, solved from
    its normal equations); False when degenerate."""
    n = P.shape[0]
    sw = 0.0
    cpx = cpy = cqx = cqy = 0.0
    for k in range(n):
        if w[k] > 0:
            sw += 1.0
            cpx += P[k, 0]
            cpy += P[k, 1]
            cqx += q[k, 0]
            cqy += q[k, 1]
    if sw < 4:
        return False
    cpx /= sw
    cpy /= sw
    cqx /= sw
    cqy /= sw
    mp = mq = 0.0
    for k in range(n):
        if w[k] > 0:
            mp += math.sqrt((P[k, 0] - cpx) ** 2 + (P[k, 1] - cpy) ** 2)
            mq += math.sqrt((q[k, 0] - cqx) ** 2 + (q[k, 1] - cqy) ** 2)
    sp = math.sqrt(2.0) * sw / max(mp, 1e-300)
    sq = math.sqrt(2.0) * sw / max(mq, 1e-300)
    M = np.zeros((8, 8))
    v = np.zeros(8)
    row = np.empty(8)
    for k in range(n):
        if w[k] <= 0:
            continue
        x = (P[k, 0] - cpx) * sp
        y = (P[k, 1] - cpy) * sp
        u = (q[k, 0] - cqx) * sq
        vv = (q[k, 1] - cqy) * sq
        for e in range(2):
            if e == 0:
                row[0] = x
                row[1] = y
                row[2] = 1.0
                row[3] = 0.0
                row[4] = 0.0
                row[5] = 0.0
                row[6] = -u * x
                row[7] = -u * y
                rhs = u
            else:
                row[0] = 0.0
                row[1] = 0.0
                row[2] = 0.0
                row[3] = x
                row[4] = y
                row[5] = 1.0
                row[6] = -vv * x
                row[7] = -vv * y
                rhs = vv
            for a in range(8):
                v[a] += row[a] * rhs
                for c in range(8):
                    M[a, c] += row[a] * row[c]
    h = np.empty(8)
    if not solve_sym(M, v, 8, h):
        return False
    Hn = np.empty((3, 3))
    Hn[0, 0] = h[0]
    Hn[0, 1] = h[1]
    Hn[0, 2] = h[2]
    Hn[1, 0] = h[3]
    Hn[1, 1] = h[4]
    Hn[1, 2] = h[5]
    Hn[2, 0] = h[6]
    Hn[2, 1] = h[7]
    Hn[2, 2] = 1.0
    # H = Tq⁻¹ · Hn · Tp
    Tp = np.zeros((3, 3))
    Tp[0, 0] = sp
    Tp[1, 1] = sp
    Tp[0, 2] = -sp * cpx
    Tp[1, 2] = -sp * cpy
    Tp[2, 2] = 1.0
    Tqi = np.zeros((3, 3))
    Tqi[0, 0] = 1.0 / sq
    Tqi[1, 1] = 1.0 / sq
    Tqi[0, 2] = cqx
    Tqi[1, 2] = cqy
    Tqi[2, 2] = 1.0
    tmp = np.empty((3, 3))
    _mm3(Hn, Tp, tmp)
    _mm3(Tqi, tmp, H)
    return True


@_jit
def _ippe_rotations(v0, v1, J, R1, R2):
    """IPPE's two rotations (Collins & Bartoli 2014, Algorithm 1) from the image point v of the
    plane origin and the homography's 2×2 Jacobian J there."""
    Rv = np.eye(3)
    tn = math.sqrt(v0 * v0 + v1 * v1)
    if tn > 1e-12:
        s = math.sqrt(v0 * v0 + v1 * v1 + 1.0)
        costh = 1.0 / s
        sinth = math.sqrt(max(1.0 - 1.0 / (s * s), 0.0))
        K = np.zeros((3, 3))
        K[0, 2] = v0 / tn
        K[1, 2] = v1 / tn
        K[2, 0] = -v0 / tn
        K[2, 1] = -v1 / tn
        K2 = np.empty((3, 3))
        _mm3(K, K, K2)
        for r in range(3):
            for c in range(3):
                Rv[r, c] += sinth * K[r, c] + (1.0 - costh) * K2[r, c]
    # B = [I, -v] · Rv[:, :2]
    b00 = Rv[0, 0] - v0 * Rv[2, 0]
    b01 = Rv[0, 1] - v0 * Rv[2, 1]
    b10 = Rv[1, 0] - v1 * Rv[2, 0]
    b11 = Rv[1, 1] - v1 * Rv[2, 1]
    dd = b00 * b11 - b01 * b10
    if abs(dd) < 1e-300:
        return False
    i00 = b11 / dd
    i01 = -b01 / dd
    i10 = -b10 / dd
    i11 = b00 / dd
    a00 = i00 * J[0, 0] + i01 * J[1, 0]
    a01 = i00 * J[0, 1] + i01 * J[1, 1]
    a10 = i10 * J[0, 0] + i11 * J[1, 0]
    a11 = i10 * J[0, 1] + i11 * J[1, 1]
    p00 = a00 * a00 + a01 * a01
    p01 = a00 * a10 + a01 * a11
    p11 = a10 * a10 + a11 * a11
    gamma = math.sqrt(0.5 * (p00 + p11 + math.sqrt((p00 - p11) ** 2 + 4 * p01 * p01)))
    if gamma <= 0:
        return False
    r00 = a00 / gamma
    r01 = a01 / gamma
    r10 = a10 / gamma
    r11 = a11 / gamma
    h00 = 1.0 - (r00 * r00 + r10 * r10)
    h01 = -(r00 * r01 + r10 * r11)
    h11 = 1.0 - (r01 * r01 + r11 * r11)
    b0 = math.sqrt(max(h00, 0.0))
    b1 = math.sqrt(max(h11, 0.0))
    if h01 < 0:
        b1 = -b1
    # d = [r00, r10, b0] x [r01, r11, b1]
    c0 = r10 * b1 - b0 * r11
    c1 = b0 * r01 - r00 * b1
    a = r00 * r11 - r10 * r01
    M1 = np.empty((3, 3))
    M2 = np.empty((3, 3))
    M1[0, 0] = r00
    M1[0, 1] = r01
    M1[0, 2] = c0
    M1[1, 0] = r10
    M1[1, 1] = r11
    M1[1, 2] = c1
    M1[2, 0] = b0
    M1[2, 1] = b1
    M1[2, 2] = a
    M2[:, :] = M1
    M2[0, 2] = -c0
    M2[1, 2] = -c1
    M2[2, 0] = -b0
    M2[2, 1] = -b1
    _mm3(Rv, M1, R1)
    _mm3(Rv, M2, R2)
    return True


@_jit
def _ippe_translation(P, q, w, R, t):
    """Least-squares translation of a rotation (IPPE's linear system in t)."""
    A = np.zeros((3, 3))
    g = np.zeros(3)
    for k in range(P.shape[0]):
        if w[k] <= 0:
            continue
        rx = R[0, 0] * P[k, 0] + R[0, 1] * P[k, 1]
        ry = R[1, 0] * P[k, 0] + R[1, 1] * P[k, 1]
        rz = R[2, 0] * P[k, 0] + R[2, 1] * P[k, 1]
        x = q[k, 0]
        y = q[k, 1]
        # rows: [1, 0, -x]·t = x·rz − rx ;  [0, 1, -y]·t = y·rz − ry
        bx = x * rz - rx
        by = y * rz - ry
        A[0, 0] += 1.0
        A[0, 2] += -x
        A[1, 1] += 1.0
        A[1, 2] += -y
        A[2, 2] += x * x + y * y
        g[0] += bx
        g[1] += by
        g[2] += -x * bx - y * by
    A[2, 0] = A[0, 2]
    A[2, 1] = A[1, 2]
    return solve_sym(A, g, 3, t)


@_jit
def ippe(P, q, w, Rpb, tpb):
    """Both planar solutions of many bricks (IPPE from a normalised-DLT homography).

    Args:
        P: (B, N, 2) dot centres in the plane frame; q: (B, N, 2) normalised image points;
        w: (B, N) 1 = used, 0 = absent (≥ 4 used, not degenerate).
        Rpb, tpb: (3, 3), (3,) ``plane_from_brick`` of the layout.

    Returns:
        (R (B, 2, 3, 3), t (B, 2, 3), cost (B, 2), ok (B,)) ``camera_from_brick``, best first;
        cost is half the sum of squared residuals (as OpenCV's IPPE error² × n).
    """
    B = P.shape[0]
    N = P.shape[1]
    Rout = np.empty((B, 2, 3, 3))
    tout = np.empty((B, 2, 3))
    cout = np.full((B, 2), np.inf)
    ok = np.zeros(B, np.bool_)
    H = np.empty((3, 3))
    J = np.empty((2, 2))
    Rs = np.empty((2, 3, 3))
    ts = np.empty((2, 3))
    Pc = np.empty((N, 2))
    for b in range(B):
        # centre the plane points: IPPE decomposes at the plane origin
        cx = 0.0
        cy = 0.0
        sw = 0.0
        for k in range(N):
            if w[b, k] > 0:
                cx += P[b, k, 0]
                cy += P[b, k, 1]
                sw += 1.0
        if sw < 4:
            continue
        cx /= sw
        cy /= sw
        for k in range(N):
            Pc[k, 0] = P[b, k, 0] - cx
            Pc[k, 1] = P[b, k, 1] - cy
        if not _homography(Pc, q[b], w[b], H):
            continue
        h22 = H[2, 2]
        if abs(h22) < 1e-300:
            continue
        v0 = H[0, 2] / h22
        v1 = H[1, 2] / h22
        for r in range(2):
            for c in range(2):
                J[r, c] = (H[r, c] - H[2, c] * (v0 if r == 0 else v1)) / h22
        if not _ippe_rotations(v0, v1, J, Rs[0], Rs[1]):
            continue
        cst = np.empty(2)
        good = True
        for s in range(2):
            if not _ippe_translation(Pc, q[b], w[b], Rs[s], ts[s]):
                good = False
                break
            c = 0.0
            for k in range(N):
                if w[b, k] <= 0:
                    continue
                Y0 = Rs[s, 0, 0] * Pc[k, 0] + Rs[s, 0, 1] * Pc[k, 1] + ts[s, 0]
                Y1 = Rs[s, 1, 0] * Pc[k, 0] + Rs[s, 1, 1] * Pc[k, 1] + ts[s, 1]
                Y2 = Rs[s, 2, 0] * Pc[k, 0] + Rs[s, 2, 1] * Pc[k, 1] + ts[s, 2]
                zs = Y2 if abs(Y2) > 1e-12 else 1e-12
                d0 = Y0 / zs - q[b, k, 0]
                d1 = Y1 / zs - q[b, k, 1]
                c += d0 * d0 + d1 * d1
            cst[s] = c / 2.0
        if not good:
            continue
        first = 0 if cst[0] <= cst[1] else 1
        for s in range(2):
            src = first if s == 0 else 1 - first
            # camera_from_brick = camera_from_centred_plane ∘ centred_plane_from_brick;
            # centred plane = plane − (cx, cy, 0)
            for r in range(3):
                for c in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += Rs[src, r, k] * Rpb[k, c]
                    Rout[b, s, r, c] = acc
                tt = ts[src, r]
                for k in range(3):
                    tt += Rs[src, r, k] * tpb[k]
                tt -= Rs[src, r, 0] * cx + Rs[src, r, 1] * cy
                tout[b, s, r] = tt
            cout[b, s] = cst[src]
        ok[b] = True
    return Rout, tout, cout, ok
