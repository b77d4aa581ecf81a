"""Compiled kernel of the dot model (numba): the clearance of the dots from the shadows of the
brick's own mesh.

The numpy reference is :func:`.model.occluded_dots` (tests compare the two), which chooses
this kernel itself.
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import jit as _jit


@_jit
def occlusion_clearance(Vp, P, radii, Cp):
    """Clearance of each dot from the shadows of occluding triangles, in dot radii (the
    loops of :func:`.match.occluded_dots` with ``clearance=True``).

    Args:
        Vp: (T, 3, 3) occluding triangles, plane frame (x, y, height).
        P: (N, 2) dot centres, plane frame.
        radii: (N,) dot radii.
        Cp: (B, 3) camera centres, plane frame.
    """
    B = Cp.shape[0]
    T = Vp.shape[0]
    N = P.shape[0]
    d2 = np.full((B, N), np.inf)
    S = np.empty((3, 2))
    for b in range(B):
        ch = Cp[b, 2]
        if ch <= 0:
            continue
        for t in range(T):
            ok = True
            for v in range(3):
                h = max(Vp[t, v, 2], 0.0)
                if not h < ch:
                    ok = False
                    break
                k = ch / max(ch - h, 1e-9)
                S[v, 0] = Cp[b, 0] + (Vp[t, v, 0] - Cp[b, 0]) * k
                S[v, 1] = Cp[b, 1] + (Vp[t, v, 1] - Cp[b, 1]) * k
            if not ok:
                continue
            for d in range(N):
                pos = True
                neg = True
                best = np.inf
                for v in range(3):
                    w = v + 1 if v < 2 else 0
                    ex = S[w, 0] - S[v, 0]
                    ey = S[w, 1] - S[v, 1]
                    wx = P[d, 0] - S[v, 0]
                    wy = P[d, 1] - S[v, 1]
                    cr = ex * wy - ey * wx
                    if cr < 0:
                        pos = False
                    if cr > 0:
                        neg = False
                    ee = max(ex * ex + ey * ey, 1e-18)
                    tt = min(max((wx * ex + wy * ey) / ee, 0.0), 1.0)
                    gx = wx - tt * ex
                    gy = wy - tt * ey
                    g = gx * gx + gy * gy
                    if g < best:
                        best = g
                if pos or neg:
                    best = 0.0
                if best < d2[b, d]:
                    d2[b, d] = best
    out = np.empty((B, N))
    for b in range(B):
        for d in range(N):
            out[b, d] = math.sqrt(d2[b, d]) / radii[d]
    return out
