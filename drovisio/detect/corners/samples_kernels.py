"""Compiled kernel of the code fit's sample selection (:func:`.samples.select_samples`), numba.

Choosing the pixels of each code that enter the photometric fit — every pixel of the code's
box (a random subset of a big box), its place in the code's cells through the start
homography, kept when it lies in the fit region within a band of a modelled edge, at most
``M`` per code at random — takes a dozen numpy passes over ~1 600 candidates a code. This
kernel does it in one pass with the same table of random numbers, so that it selects exactly
the samples the numpy code selects (tests compare them). The fit itself stays in numpy: its
dense float32 arithmetic is faster vectorised than in scalar loops (measured).
"""

from __future__ import annotations

import numpy as np

from drovisio._numba import jit

__all__ = ["select_samples"]


@jit
def _candidates(grid, gray, x0, y0, bw, P, P_box, K, centre, scale, g, lo, hi, band, ns, bits,
                rnd):
    """Every candidate pixel of each code's box (a random subset of a big box) that lies in
    the fit region within the band of a modelled edge, in code order.

    Returns:
        (code index, local x, local y, grey level: each (total,), valid up to ``nsel``;
        per-code counts (C,); ``nsel``).
    """
    C = P.shape[0]
    total = 0
    for c in range(C):
        total += P[c]
    nr = rnd.shape[0]
    sel_code = np.empty(total, np.int64)
    sel_lx = np.empty(total)
    sel_ly = np.empty(total)
    sel_val = np.empty(total)
    counts = np.zeros(C, np.int64)
    nsel = 0
    start = 0
    for c in range(C):
        big = P_box[c] > K
        inv_s = 1.0 / scale[c]
        nm1 = ns[c] - 1
        d = band[c]
        for k in range(P[c]):
            kk = k
            if big:
                kk = np.int64(rnd[((start + k) * 7919) % nr] * P_box[c])
            px = x0[c] + kk % bw[c]
            py = y0[c] + kk // bw[c]
            lx = (np.float64(grid[py, px, 0]) - centre[c, 0]) * inv_s
            ly = (np.float64(grid[py, px, 1]) - centre[c, 1]) * inv_s
            D = g[c, 6] * lx + g[c, 7] * ly + 1.0
            u = (g[c, 0] * lx + g[c, 1] * ly + g[c, 2]) / D
            v = (g[c, 3] * lx + g[c, 4] * ly + g[c, 5]) / D
            if not (u >= lo[c] and u <= hi[c] and v >= lo[c] and v <= hi[c]):
                continue
            if not _near_edge(u, v, d, nm1, bits, c):
                continue
            sel_code[nsel] = c
            sel_lx[nsel] = lx
            sel_ly[nsel] = ly
            sel_val[nsel] = gray[py, px]
            counts[c] += 1
            nsel += 1
        start += P[c]
    return sel_code, sel_lx, sel_ly, sel_val, counts, nsel


@jit
def _near_edge(u, v, d, nm1, bits, c):
    """Whether the cell across the nearest cell boundary (within ``d`` cells) of the point
    (u, v) of code ``c`` differs from the point's own cell."""
    fu = np.floor(u)
    fv = np.floor(v)
    ru = u - fu
    rv = v - fv
    ui = min(max(np.int64(fu), 0), nm1)
    vi = min(max(np.int64(fv), 0), nm1)
    uj = ui - (1 if ru < d else 0) + (1 if ru > 1.0 - d else 0)
    vj = vi - (1 if rv < d else 0) + (1 if rv > 1.0 - d else 0)
    uj = min(max(uj, 0), nm1)
    vj = min(max(vj, 0), nm1)
    here = bits[c, vi, ui]
    return not (bits[c, vi, uj] == here and bits[c, vj, ui] == here
                and bits[c, vj, uj] == here)


@jit
def _at_most(sel_code, sel_lx, sel_ly, sel_val, counts, nsel, rnd, M):
    """At most ``M`` candidates per code, at random (the numpy code sorts by code + a random
    key by position), packed into (C, Mc) rows."""
    C = counts.shape[0]
    nr = rnd.shape[0]
    over = False
    for c in range(C):
        if counts[c] > M:
            over = True
    first = np.zeros(C, np.int64)
    for c in range(1, C):
        first[c] = first[c - 1] + counts[c - 1]
    order = np.arange(nsel)
    if over:
        key = np.empty(nsel)
        for i in range(nsel):
            key[i] = sel_code[i] + rnd[i % nr]
        order = np.argsort(key, kind="mergesort")
    cnt = np.minimum(counts, M)
    Mc = 1
    for c in range(C):
        Mc = max(Mc, cnt[c])
    xs = np.zeros((C, Mc))
    ys = np.zeros((C, Mc))
    vals = np.zeros((C, Mc))
    wts = np.zeros((C, Mc))
    for j in range(nsel):
        i = order[j]
        c = sel_code[i]
        rank = j - first[c]
        if rank < M:
            xs[c, rank] = sel_lx[i]
            ys[c, rank] = sel_ly[i]
            vals[c, rank] = sel_val[i]
            wts[c, rank] = 1.0
    return xs, ys, vals, wts, cnt


@jit
def select_samples(grid, gray, x0, y0, bw, P, P_box, K, centre, scale, g, lo, hi, band, ns,
                   bits, rnd, M):
    """The fit's samples of C codes.

    Args:
        grid: (H, W, 2) float32 normalised coordinates of the pixel centres; gray: (H, W).
        x0, y0, bw: (C,) the codes' boxes (top-left pixel, width); P: (C,) candidates per code
            (min(P_box, K)); P_box: (C,) pixels of each box; K: candidates per big box.
        centre, scale: (C, 2), (C,) the local frame; g: (C, 8) start homographies.
        lo, hi, band: (C,) fit region and edge band, cells; ns: (C,) cells per side.
        bits: (C, n, n) cells with border (padded); rnd: the random table; M: most samples.

    Returns:
        (xs, ys, vals, wts (C, Mc), counts (C,)) with Mc the largest count (≥ 1).
    """
    sel_code, sel_lx, sel_ly, sel_val, counts, nsel = _candidates(
        grid, gray, x0, y0, bw, P, P_box, K, centre, scale, g, lo, hi, band, ns, bits, rnd)
    return _at_most(sel_code, sel_lx, sel_ly, sel_val, counts, nsel, rnd, M)
