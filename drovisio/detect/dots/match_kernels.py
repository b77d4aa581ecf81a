"""Compiled kernels of the dot detector's matching stage (numba): pair-seeded hypotheses and
the greedy assignment of blobs to bricks.

The numpy reference implementations are in :mod:`.match` (tests compare the two); the stage
chooses the kernel inside its own functions.

Conventions are those of the numpy versions: pixel (0, 0) is the centre of the top-left
pixel; normalised image coordinates are x/z, y/z of the OpenCV camera frame; poses are
``camera_from_brick`` (X_cam = R · X + t).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import jit as _jit


# one compiled loop nest on purpose: the per-seed scoring loop is the detector's hottest
# code, and its state (candidate lists, scratch rows) would have to cross calls if split
@_jit
def hypotheses(qq, col, S, Si, semi_major, pairs, pcm, pair_len, pair_vec, pair_mid,
               pair_ra_half, pair_rb_half, pair_ia, pair_ib, P, colors, min_spacing,
               reach_per_semi_axis, seeds_per_blob, ratio_tol, match_tol, min_dots,
               orientation):
    """Pair-seeded hypotheses of one layout (the loops of
    :func:`.match.generate_hypotheses`, same order and scores).

    Returns:
        (assign (H, N) indices into ``qq`` or -1, score (H,), scale (H,), A (H, 2, 2),
        origin (H, 2)), hypotheses with at least ``min_dots`` dots, in generation order.
    """
    M = qq.shape[0]
    N = P.shape[0]
    Np = pairs.shape[0]
    K = min(M - 1, N + 3)
    order = np.empty((M, K), np.int64)
    near = np.zeros((M, K), np.bool_)
    bestd = np.empty(K)
    xo = np.argsort(qq[:, 0])          # sweep in x: stop where x alone is farther than the K-th
    rank = np.empty(M, np.int64)
    for r in range(M):
        rank[xo[r]] = r
    for i in range(M):
        # the K nearest other blobs, nearest first (insertion into a short sorted list)
        cnt = 0
        lo_r = rank[i] - 1
        hi_r = rank[i] + 1
        while lo_r >= 0 or hi_r < M:
            for side in range(2):
                if side == 0:
                    if lo_r < 0:
                        continue
                    j = xo[lo_r]
                else:
                    if hi_r >= M:
                        continue
                    j = xo[hi_r]
                dx = qq[i, 0] - qq[j, 0]
                if cnt == K and dx * dx >= bestd[K - 1]:
                    if side == 0:
                        lo_r = -1
                    else:
                        hi_r = M
                    continue
                if side == 0:
                    lo_r -= 1
                else:
                    hi_r += 1
                dy = qq[i, 1] - qq[j, 1]
                d2 = dx * dx + dy * dy
                if cnt == K and d2 >= bestd[K - 1]:
                    continue
                p = cnt if cnt < K else K - 1
                while p > 0 and bestd[p - 1] > d2:
                    if p < K:
                        bestd[p] = bestd[p - 1]
                        order[i, p] = order[i, p - 1]
                    p -= 1
                bestd[p] = d2
                order[i, p] = j
                if cnt < K:
                    cnt += 1
        reach = semi_major[i] * reach_per_semi_axis
        for k in range(K):
            near[i, k] = bestd[k] <= reach * reach
    # each blob's candidates for the other dots (itself and its near blobs), by colour, in
    # the order of distance (the seed first)
    n_col = pcm.shape[0]
    by_col = np.empty((M, n_col, K + 1), np.int64)
    n_by = np.zeros((M, n_col), np.int64)
    for i in range(M):
        for c in range(K + 1):
            if c == 0:
                cb = i
            else:
                if not near[i, c - 1]:
                    continue
                cb = order[i, c - 1]
            cc = col[cb]
            by_col[i, cc, n_by[i, cc]] = cb
            n_by[i, cc] += 1
    ks = min(seeds_per_blob, K)
    keys = np.empty(M * ks, np.int64)
    nk = 0
    for i in range(M):
        for s in range(ks):
            if near[i, s]:
                j = order[i, s]
                keys[nk] = min(i, j) * M + max(i, j)
                nk += 1
    keys = np.unique(keys[:nk])
    cap = 2 * M + 16            # grown when full (keys × pairs would be far too many)
    assign = np.empty((cap, N), np.int64)
    score = np.empty(cap)
    scale = np.empty(cap)
    Aout = np.empty((cap, 2, 2))
    origin = np.empty((cap, 2))
    nh = 0
    lo_r = 1.0 / ratio_tol
    # blobs of a complete, tight hypothesis: another seed pair of the same brick would only
    # find the same dots again, so pairs of two such blobs are not tried
    explained = np.zeros(M, np.bool_)
    for kk in range(keys.shape[0]):
        i = keys[kk] // M
        j = keys[kk] - i * M
        if explained[i] and explained[j]:
            continue
        fx = qq[j, 0] - qq[i, 0]
        fy = qq[j, 1] - qq[i, 1]
        gi0 = Si[i, 0, 0] * fx + Si[i, 0, 1] * fy
        gi1 = Si[i, 1, 0] * fx + Si[i, 1, 1] * fy
        gj0 = Si[j, 0, 0] * fx + Si[j, 0, 1] * fy
        gj1 = Si[j, 1, 0] * fx + Si[j, 1, 1] * fy
        ni_ = math.sqrt(gi0 * gi0 + gi1 * gi1)
        nj_ = math.sqrt(gj0 * gj0 + gj1 * gj1)
        for hp in range(Np):
            if not pcm[col[i], col[j], hp]:
                continue
            le = pair_len[hp]
            ri = ni_ * pair_ra_half[hp] / le
            rj = nj_ * pair_rb_half[hp] / le
            if not (ri < ratio_tol and ri > lo_r and rj < ratio_tol and rj > lo_r):
                continue
            if nh == cap:
                cap *= 2
                assign2 = np.empty((cap, N), np.int64)
                assign2[:nh] = assign[:nh]
                assign = assign2
                score2 = np.empty(cap)
                score2[:nh] = score[:nh]
                score = score2
                scale2 = np.empty(cap)
                scale2[:nh] = scale[:nh]
                scale = scale2
                A2_ = np.empty((cap, 2, 2))
                A2_[:nh] = Aout[:nh]
                Aout = A2_
                o2 = np.empty((cap, 2))
                o2[:nh] = origin[:nh]
                origin = o2
            a = pairs[hp, 0]
            b = pairs[hp, 1]
            ia = pair_ia[hp]
            ib = pair_ib[hp]
            s00 = S[i, 0, 0] * ia + S[j, 0, 0] * ib
            s01 = S[i, 0, 1] * ia + S[j, 0, 1] * ib
            s10 = S[i, 1, 0] * ia + S[j, 1, 0] * ib
            s11 = S[i, 1, 1] * ia + S[j, 1, 1] * ib
            dS = s00 * s11 - s01 * s01
            g0 = (s11 * fx - s01 * fy) / dS
            g1 = (s00 * fy - s01 * fx) / dS
            lg = math.sqrt(g0 * g0 + g1 * g1)
            e0 = pair_vec[hp, 0] / le
            e1 = pair_vec[hp, 1] / le
            h0 = g0 / lg
            h1 = g1 / lg
            if orientation < 0:
                c2 = e0 * h0 - e1 * h1
                s2 = e0 * h1 + e1 * h0
                q00, q01, q10, q11 = c2, s2, s2, -c2
            else:
                c1 = e0 * h0 + e1 * h1
                s1 = e0 * h1 - e1 * h0
                q00, q01, q10, q11 = c1, -s1, s1, c1
            f = lg / le
            A00 = (s00 * q00 + s01 * q10) * f
            A01 = (s00 * q01 + s01 * q11) * f
            A10 = (s10 * q00 + s11 * q10) * f
            A11 = (s10 * q01 + s11 * q11) * f
            mx = pair_mid[hp, 0]
            my = pair_mid[hp, 1]
            o0 = 0.5 * (qq[i, 0] + qq[j, 0]) - (A00 * mx + A01 * my)
            o1 = 0.5 * (qq[i, 1] + qq[j, 1]) - (A10 * mx + A11 * my)
            t00 = A00 * A00 + A10 * A10
            t01 = A00 * A01 + A10 * A11
            t11 = A01 * A01 + A11 * A11
            tr = t00 + t11
            dt = t00 * t11 - t01 * t01
            sv_min = math.sqrt(max(tr / 2 - math.sqrt(max(tr * tr / 4 - dt, 0.0)), 0.0))
            sc = sv_min * min_spacing
            tol2 = (match_tol * sc) ** 2
            count = 0
            close = 0.0
            for d in range(N):
                px = o0 + A00 * P[d, 0] + A01 * P[d, 1]
                py = o1 + A10 * P[d, 0] + A11 * P[d, 1]
                best = -1
                bd = np.inf
                if d == a or d == b:
                    ncand = 0           # the seed's own dots: no search
                else:
                    ncand = n_by[i, colors[d]]
                for c in range(ncand):
                    cb = by_col[i, colors[d], c]
                    dx = px - qq[cb, 0]
                    dy = py - qq[cb, 1]
                    dd = dx * dx + dy * dy
                    if dd < bd:
                        bd = dd
                        best = cb
                if d == a:
                    assign[nh, d] = i
                elif d == b:
                    assign[nh, d] = j
                elif best >= 0 and bd <= tol2:
                    assign[nh, d] = best
                    close += math.sqrt(bd / tol2)
                else:
                    assign[nh, d] = -1
                if assign[nh, d] >= 0:
                    count += 1
                elif count + N - 1 - d < min_dots:
                    break       # too few dots left to reach min_dots
            if count < min_dots:
                continue
            score[nh] = count - 0.5 * close / max(count - 2, 1)
            if count == N and close <= 0.25 * (N - 2):
                for d in range(N):
                    explained[assign[nh, d]] = True
            scale[nh] = sc
            Aout[nh, 0, 0] = A00
            Aout[nh, 0, 1] = A01
            Aout[nh, 1, 0] = A10
            Aout[nh, 1, 1] = A11
            origin[nh, 0] = o0
            origin[nh, 1] = o1
            nh += 1
    return assign[:nh], score[:nh], scale[:nh], Aout[:nh], origin[:nh]


@_jit
def assign_greedy(A, min_dots, taken):
    """Rows of ``A`` (hypotheses' blob per dot, best first) taken one by one: a row is
    accepted when at least ``min_dots`` of its blobs are still free (a blob met twice in a
    row counts for its first dot); it keeps those. ``taken`` is updated in place.

    Returns:
        (accepted row indices, (rows, W) their free blobs, -1 elsewhere).
    """
    R = A.shape[0]
    W = A.shape[1]
    acc = np.empty(R, np.int64)
    out = np.full((R, W), -1, np.int64)
    na = 0
    row = np.empty(W, np.int64)
    for r in range(R):
        cnt = 0
        for d in range(W):
            bl = A[r, d]
            row[d] = -1
            if bl < 0 or taken[bl]:
                continue
            dup = False
            for e in range(d):
                if A[r, e] == bl:
                    dup = True
                    break
            if not dup:
                row[d] = bl
                cnt += 1
        if cnt >= min_dots:
            for d in range(W):
                if row[d] >= 0:
                    taken[row[d]] = True
                out[na, d] = row[d]
            acc[na] = r
            na += 1
    return acc[:na], out[:na]
