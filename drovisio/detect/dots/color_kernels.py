"""Compiled kernels of the dot detector's colour stage (numba): CLAHE on V evaluated at blob
centres only.

The numpy reference implementation is :class:`.color.ClaheMap` (tests compare the two).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import jit as _jit


@_jit
def _clahe_table(hsv, tile, tx, th, tw, stride, scale, clip, area, table):
    """One tile's CLAHE table (as :meth:`.color.ClaheMap.lut`) into ``table`` (256,)."""
    tyi = tile // tx
    txi = tile - tyi * tx
    ys = tyi * th
    xs = txi * tw
    hist = np.zeros(256, np.int64)
    y = ((ys + stride - 1) // stride) * stride
    while y < ys + th:
        x = ((xs + stride - 1) // stride) * stride
        while x < xs + tw:
            hist[hsv[y, x, 2]] += 1
            x += stride
        y += stride
    if scale != 1.0:
        for b in range(256):
            hist[b] = int(np.rint(hist[b] * scale))
    if clip > 0:
        excess = 0
        for b in range(256):
            if hist[b] > clip:
                excess += hist[b] - clip
                hist[b] = clip
        batch = excess // 256
        residual = excess - batch * 256
        step = max(256 // max(residual, 1), 1)
        for b in range(256):
            hist[b] += batch
            if residual > 0 and b % step == 0 and b // step < residual:
                hist[b] += 1
    acc = 0
    k = 255.0 / area
    for b in range(256):
        acc += hist[b]
        table[b] = min(np.rint(acc * k), 255.0)


@_jit
def clahe_at(hsv, x, y, tx, ty, stride, clip_limit):
    """CLAHE-equalised V (float) at blob centres (x, y): the 5-pixel mean of raw V there,
    mapped as :class:`.color.ClaheMap` does, building only the tiles it needs. The frame
    must be a multiple of the tile grid."""
    H = hsv.shape[0]
    W = hsv.shape[1]
    tw = W // tx
    th = H // ty
    area = tw * th
    nsub = ((H + stride - 1) // stride) * ((W + stride - 1) // stride) // (tx * ty)
    scale = area / max(1, nsub) if stride > 1 else 1.0
    clip = max(int(clip_limit * area / 256), 1) if clip_limit > 0 else 0
    tables = np.empty((tx * ty, 256))
    done = np.zeros(tx * ty, np.bool_)
    n = x.shape[0]
    out = np.empty(n)
    for k in range(n):
        xi = min(max(int(np.rint(x[k])), 1), W - 2)
        yi = min(max(int(np.rint(y[k])), 1), H - 2)
        raw = (float(hsv[yi, xi, 2]) + hsv[yi - 1, xi, 2] + hsv[yi + 1, xi, 2]
               + hsv[yi, xi - 1, 2] + hsv[yi, xi + 1, 2]) / 5.0
        v = int(min(max(np.rint(raw), 0.0), 255.0))
        txf = x[k] / tw - 0.5
        tyf = y[k] / th - 0.5
        fx = math.floor(txf)
        fy = math.floor(tyf)
        xa = txf - fx
        ya = tyf - fy
        tx1 = int(fx)
        ty1 = int(fy)
        tx2 = min(max(tx1 + 1, 0), tx - 1)
        ty2 = min(max(ty1 + 1, 0), ty - 1)
        tx1 = min(max(tx1, 0), tx - 1)
        ty1 = min(max(ty1, 0), ty - 1)
        L = np.empty(4)
        tiles = (ty1 * tx + tx1, ty1 * tx + tx2, ty2 * tx + tx1, ty2 * tx + tx2)
        for c in range(4):
            t = tiles[c]
            if not done[t]:
                _clahe_table(hsv, t, tx, th, tw, stride, scale, clip, area, tables[t])
                done[t] = True
            L[c] = tables[t, v]
        top = L[0] * (1 - xa) + L[1] * xa
        bot = L[2] * (1 - xa) + L[3] * xa
        out[k] = top * (1 - ya) + bot * ya
    return out
