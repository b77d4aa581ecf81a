"""Compiled kernels of the dot detector's per-frame geometry (numba).

The dot detector's stages are written once with numpy (the reference implementations in
:mod:`.dots_blobs`, :mod:`.dots_color`, :mod:`.dots_match`, :mod:`drovisio.pose.batch`). Vectorised
numpy is fast for big arrays but a frame of the dot detector is made of many *small* ones: a
few blobs, a few bricks of six dots. There each numpy call costs more in dispatch than in
arithmetic, and a 640×480 frame needed ~1 300 of them. These kernels do the same arithmetic
in plain loops, compiled once by numba (``cache=True``: the machine code is kept next to this
file, so only the first run on a machine compiles, ~30 s; :mod:`.warmup` does it ahead).

The detector uses them when numba is importable (it is a dependency on x86-64 and 64-bit ARM;
32-bit ARM boards such as the Odroid XU4 have no numba wheels and run the numpy versions) and
``DROVISIO_NUMBA`` is not ``0`` (:mod:`drovisio._numba`). Tests check every kernel against
its numpy reference.

Conventions are those of the numpy versions: pixel (0, 0) is the centre of the top-left
pixel; normalised image coordinates are x/z, y/z of the OpenCV camera frame; poses are
``camera_from_brick`` (X_cam = R · X + t).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import AVAILABLE, enabled, missing_cache, set_enabled
from drovisio._numba import jit as _jit

__all__ = ["AVAILABLE", "enabled", "notice_first_compile", "set_enabled"]

_NOTICED = False


def notice_first_compile(log) -> None:
    """Once per process: tell the user when the kernels have no compiled cache yet (the first
    frame then waits for numba, ~30 s once per machine)."""
    global _NOTICED
    if _NOTICED or not enabled():
        return
    _NOTICED = True
    missing = missing_cache(globals())
    if missing:
        log.warning("first use of the colour-dot detector on this machine: compiling its "
                    "kernels (%d functions, about 3 min on a small laptop, kept for later runs)", len(missing))


# ================================================================================ blobs
@_jit
def _cross(ox, oy, ax, ay, bx, by):
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@_jit
def _hull_area(pts, s0, m):
    """Area of the convex hull of m contour points (Andrew's monotone chain)."""
    if m < 3:
        return 0.0
    key = np.empty(m, np.int64)
    for i in range(m):
        key[i] = (np.int64(pts[s0 + i, 0]) << 32) + np.int64(pts[s0 + i, 1])
    order = np.argsort(key)
    hx = np.empty(2 * m + 1, np.int64)
    hy = np.empty(2 * m + 1, np.int64)
    k = 0
    for ii in range(m):
        i = order[ii]
        x = np.int64(pts[s0 + i, 0])
        y = np.int64(pts[s0 + i, 1])
        while k >= 2 and _cross(hx[k - 2], hy[k - 2], hx[k - 1], hy[k - 1], x, y) <= 0:
            k -= 1
        hx[k] = x
        hy[k] = y
        k += 1
    lower = k + 1
    for ii in range(m - 2, -1, -1):
        i = order[ii]
        x = np.int64(pts[s0 + i, 0])
        y = np.int64(pts[s0 + i, 1])
        while k >= lower and _cross(hx[k - 2], hy[k - 2], hx[k - 1], hy[k - 1], x, y) <= 0:
            k -= 1
        hx[k] = x
        hy[k] = y
        k += 1
    a2 = 0
    for i in range(k - 1):
        a2 += hx[i] * hy[i + 1] - hx[i + 1] * hy[i]
    return abs(a2) / 2.0


@_jit
def polygon_areas(pts, starts, npts):
    """|Area| of each polygon (as ``cv2.contourArea``)."""
    n = starts.shape[0]
    out = np.empty(n)
    for j in range(n):
        s0 = starts[j]
        m = npts[j]
        a2 = 0.0
        for i in range(m):
            k = i + 1 if i + 1 < m else 0
            a2 += float(pts[s0 + i, 0]) * pts[s0 + k, 1] - float(pts[s0 + k, 0]) * pts[s0 + i, 1]
        out[j] = abs(a2) / 2.0
    return out


@_jit
def measure_contours(pts, starts, npts, H, W, hull_gate):
    """Shape measures of contours (the loops of :func:`.dots_blobs._measure`).

    Args:
        pts: (P, 2) int32 contour points of all contours, concatenated.
        starts, npts: (n,) first point and point count of each contour.
        H, W: Frame size (for the border flag).
        hull_gate: (7,) min area, max area, min aspect, min circularity, min fill, max
            ellipse error, ellipse error px: the convexity is measured only for contours
            within the first five and with a doubtful shape (NaN for the others).

    Returns:
        out (n, 13) float64: cx, cy, area, a, b, angle, perimeter, circularity, fill,
        ellipse_err, cov00, cov01, cov11, convexity (polygon area / convex hull area, as
        ``cv2.contourArea`` of the contour and of ``cv2.convexHull``); bbox (n, 4) int64;
        border (n,) bool.
    """
    n = starts.shape[0]
    out = np.empty((n, 14))
    bbox = np.empty((n, 4), np.int64)
    border = np.zeros(n, np.bool_)
    for j in range(n):
        s0 = starts[j]
        m = npts[j]
        ox = float(pts[s0, 0])
        oy = float(pts[s0, 1])
        a2 = 0.0
        sx = 0.0
        sy = 0.0
        sxx = 0.0
        syy = 0.0
        sxy = 0.0
        per = 0.0
        mx0 = pts[s0, 0]
        my0 = pts[s0, 1]
        mx1 = mx0
        my1 = my0
        mean_x = 0.0
        mean_y = 0.0
        for i in range(m):
            px = pts[s0 + i, 0]
            py = pts[s0 + i, 1]
            if px < mx0:
                mx0 = px
            if px > mx1:
                mx1 = px
            if py < my0:
                my0 = py
            if py > my1:
                my1 = py
            k = i + 1 if i + 1 < m else 0
            x0 = px - ox
            y0 = py - oy
            x1 = pts[s0 + k, 0] - ox
            y1 = pts[s0 + k, 1] - oy
            mean_x += x0
            mean_y += y0
            cr = x0 * y1 - x1 * y0
            a2 += cr
            sx += (x0 + x1) * cr
            sy += (y0 + y1) * cr
            sxx += (x0 * x0 + x0 * x1 + x1 * x1) * cr
            syy += (y0 * y0 + y0 * y1 + y1 * y1) * cr
            sxy += (x0 * y1 + 2 * x0 * y0 + 2 * x1 * y1 + x1 * y0) * cr
            per += math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
        area_poly = abs(a2) / 2
        deg = area_poly <= 0
        if deg:
            cx = mean_x / m
            cy = mean_y / m
            ixx = 0.0
            iyy = 0.0
            ixy = 0.0
        else:
            cx = sx / (3 * a2)
            cy = sy / (3 * a2)
            ixx = sxx / (6 * a2) - cx * cx
            iyy = syy / (6 * a2) - cy * cy
            ixy = sxy / (12 * a2) - cx * cy
        tr = ixx + iyy
        dd = math.sqrt(max((ixx - iyy) ** 2 / 4 + ixy * ixy, 0.0))
        l1 = max(tr / 2 + dd, 0.0)
        l2 = max(tr / 2 - dd, 0.0)
        angle = 0.5 * math.atan2(2 * ixy, ixx - iyy)
        a_poly = 2 * math.sqrt(l1)
        b_poly = 2 * math.sqrt(l2)
        fill = area_poly / (math.pi * max(a_poly * b_poly, 1e-12)) if a_poly * b_poly > 0 \
            else 0.0
        a_reg = a_poly + 0.5
        b_reg = b_poly + 0.5
        area = area_poly + m / 2.0 + 1.0
        perimeter = per + math.pi
        circ = 4 * math.pi * area / max(perimeter, 1e-9) ** 2
        c = math.cos(angle)
        sn = math.sin(angle)
        A2 = (a_reg / 2) ** 2
        B2 = (b_reg / 2) ** 2
        if deg:
            err = np.inf
        else:
            det = max(ixx * iyy - ixy * ixy, 1e-12)
            kxx = iyy / det
            kxy = ixy / det
            kyy = ixx / det
            acc = 0.0
            for i in range(m):
                dx = (pts[s0 + i, 0] - ox) - cx
                dy = (pts[s0 + i, 1] - oy) - cy
                r2 = (kxx * dx * dx - 2 * kxy * dx * dy + kyy * dy * dy) / 4.0
                dev = math.sqrt(r2) - 1.0
                acc += dev * dev
            err = math.sqrt(acc / m)
        out[j, 0] = cx + ox
        out[j, 1] = cy + oy
        out[j, 2] = area
        out[j, 3] = a_reg
        out[j, 4] = b_reg
        out[j, 5] = angle
        out[j, 6] = perimeter
        out[j, 7] = circ
        out[j, 8] = fill
        out[j, 9] = err
        out[j, 10] = A2 * c * c + B2 * sn * sn
        out[j, 11] = (A2 - B2) * c * sn
        out[j, 12] = A2 * sn * sn + B2 * c * c
        # convexity only where the shape filters may keep the blob (the hull is the costly part)
        # (and where the other measures leave a doubt: a clean ellipse is convex; the same
        # rule as filter_blobs)
        doubt_err = 0.5 * (hull_gate[5] + hull_gate[6] / max(b_reg - 0.5, 0.5))
        if (hull_gate[0] <= area <= hull_gate[1] and b_reg >= hull_gate[2] * a_reg
                and circ >= hull_gate[3] and fill >= hull_gate[4]
                and (fill < 0.97 or err > doubt_err)):
            hull = _hull_area(pts, s0, m)
            out[j, 13] = area_poly / hull if hull > 0 else 0.0
        else:
            out[j, 13] = np.nan
        bbox[j, 0] = mx0
        bbox[j, 1] = my0
        bbox[j, 2] = mx1
        bbox[j, 3] = my1
        border[j] = (mx0 <= 0) or (my0 <= 0) or (mx1 >= W - 1) or (my1 >= H - 1)
    return out, bbox, border


@_jit
def refine_centers(img, bx, by, ba, bb, cov, margin, max_w):
    """Colour-coverage centroids of blobs (the loops of :func:`.dots_blobs.refine_centers`,
    same windows, same estimates; float64 instead of float32)."""
    n = bx.shape[0]
    H = img.shape[0]
    W = img.shape[1]
    out = np.empty((n, 2))
    contrast = np.zeros(n)
    need = np.empty(n, np.int64)
    for k in range(n):
        out[k, 0] = bx[k]
        out[k, 1] = by[k]
        need[k] = int(2 * (math.ceil(ba[k] + margin) + 2) + 1)
    # window sizes: blobs whose windows are within a factor 2 share the largest
    wsize = np.zeros(n, np.int64)
    left = n
    while left > 0:
        lo = 1 << 60
        for k in range(n):
            if wsize[k] == 0 and need[k] < lo:
                lo = need[k]
        hi = 0
        for k in range(n):
            if wsize[k] == 0 and need[k] <= 2 * lo and need[k] > hi:
                hi = need[k]
        for k in range(n):
            if wsize[k] == 0 and need[k] <= 2 * lo:
                wsize[k] = hi
                left -= 1
    sup_x = np.empty(max_w * max_w, np.int64)
    sup_y = np.empty(max_w * max_w, np.int64)
    # visit blobs band by band, left to right: neighbouring windows share cache lines
    visit = np.argsort(np.floor(by / 16.0) * 1e5 + bx)
    # touch every window row first: a new frame is seldom in the cache, and these loads are
    # independent, so they overlap (-25 % with a cold cache); the windows then fit in L2
    sink = 0
    for k in range(n):
        if wsize[k] > max_w:
            continue
        cx = int(np.rint(bx[k]))
        cy = int(np.rint(by[k]))
        half = wsize[k] // 2
        xa = min(max(cx - half, 0), W - 1)
        xb = min(max(cx + half, 0), W - 1)
        for y in range(max(cy - half, 0), min(cy + half, H - 1) + 1):
            sink += img[y, xa, 0] + img[y, xb, 2]
    if sink == 1234567891234:      # never: keeps the loads from being optimised away
        contrast[0] = -1.0
    for kk in range(n):
        k = visit[kk]
        w = wsize[k]
        if w > max_w:
            continue
        half = w // 2
        cx = int(np.rint(bx[k]))
        cy = int(np.rint(by[k]))
        c00 = cov[k, 0, 0]
        c01 = cov[k, 0, 1]
        c11 = cov[k, 1, 1]
        det = max(c00 * c11 - c01 * c01, 1e-9)
        k00 = c11 / (4 * det)
        k01 = -c01 / (2 * det)
        k11 = c00 / (4 * det)
        grow2 = (1.0 + margin / max(bb[k], 0.5)) ** 2
        bg0 = 0.0
        bg1 = 0.0
        bg2 = 0.0
        fg0 = 0.0
        fg1 = 0.0
        fg2 = 0.0
        no = 0
        ni = 0
        y0 = max(cy - half, 0)
        y1 = min(cy + half, H - 1)
        x0 = max(cx - half, 0)
        x1 = min(cx + half, W - 1)
        ns = 0
        for y in range(y0, y1 + 1):
            dy = y - by[k]
            row = img[y]
            for x in range(x0, x1 + 1):
                dx = x - bx[k]
                q = k00 * dx * dx + k01 * dy * dx + k11 * dy * dy
                if q > grow2:
                    bg0 += row[x, 0]
                    bg1 += row[x, 1]
                    bg2 += row[x, 2]
                    no += 1
                else:
                    sup_x[ns] = x
                    sup_y[ns] = y
                    ns += 1
                    if q <= 0.25:
                        fg0 += row[x, 0]
                        fg1 += row[x, 1]
                        fg2 += row[x, 2]
                        ni += 1
        if no == 0 or ni == 0:
            continue
        bg0 /= no
        bg1 /= no
        bg2 /= no
        d0 = fg0 / ni - bg0
        d1 = fg1 / ni - bg1
        d2 = fg2 / ni - bg2
        mean = (d0 + d1 + d2) / 3
        d0 -= mean
        d1 -= mean
        d2 -= mean
        dn = d0 * d0 + d1 * d1 + d2 * d2
        if dn <= 100.0:
            continue
        d0 /= dn
        d1 /= dn
        d2 /= dn
        base = bg0 * d0 + bg1 * d1 + bg2 * d2
        s = 0.0
        sx = 0.0
        sy = 0.0
        for e in range(ns):
            x = sup_x[e]
            y = sup_y[e]
            c = img[y, x, 0] * d0 + img[y, x, 1] * d1 + img[y, x, 2] * d2 - base
            s += c
            sx += c * x
            sy += c * y
        if s > 1.0:
            out[k, 0] = sx / s
            out[k, 1] = sy / s
            contrast[k] = math.sqrt(dn)
    return out, contrast


# ================================================================================ colour
@_jit
def _clahe_table(hsv, tile, tx, th, tw, stride, scale, clip, area, table):
    """One tile's CLAHE table (as :meth:`.dots_color.ClaheMap.lut`) into ``table`` (256,)."""
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
    mapped as :class:`.dots_color.ClaheMap` does, building only the tiles it needs. The frame
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


# ================================================================================ matching
@_jit
def hypotheses(qq, col, S, Si, semi_major, pairs, pcm, pair_len, pair_vec, pair_mid,
               pair_ra_half, pair_rb_half, pair_ia, pair_ib, P, colors, min_spacing,
               reach_per_semi_axis, seeds_per_blob, ratio_tol, match_tol, min_dots,
               orientation):
    """Pair-seeded hypotheses of one layout (the loops of
    :func:`.dots_match.generate_hypotheses`, same order and scores).

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
def occlusion_clearance(Vp, P, radii, Cp):
    """Clearance of each dot from the shadows of occluding triangles, in dot radii (the
    loops of :func:`.dots_match.occluded_dots` with ``clearance=True``).

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


# ================================================================================ poses
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
def _solve_sym(A, g, n, x):
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
            _solve_sym(Ad, gd, 6, delta)
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
        _solve_sym(A, g, 6, delta)
        _apply(delta, R[b], t[b], Ro[b], to[b])
        cost[b] = _cost(X[b], q[b], w[b], Ro[b], to[b], resid[b])
    return Ro, to, cost, Aout, resid


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
    if not _solve_sym(M, v, 8, h):
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
    return _solve_sym(A, g, 3, t)


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
def pose_covariance(A, rvec, sigma):
    """6×6 covariances of (rvec, tvec) from normal matrices (as
    :func:`drovisio.pose.batch.pose_covariance_from_normal`)."""
    B = A.shape[0]
    out = np.empty((B, 6, 6))
    M = np.empty((6, 12))
    Jl = np.empty((3, 3))
    C = np.empty((6, 6))
    for b in range(B):
        # inverse by Gauss–Jordan with partial pivoting
        for r in range(6):
            for c in range(6):
                M[r, c] = A[b, r, c] + (1e-18 if r == c else 0.0)
                M[r, 6 + c] = 1.0 if r == c else 0.0
        singular = False
        for c in range(6):
            p = c
            for r in range(c + 1, 6):
                if abs(M[r, c]) > abs(M[p, c]):
                    p = r
            if abs(M[p, c]) < 1e-300:
                singular = True
                break
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
        if singular:
            for r in range(6):
                for c in range(6):
                    out[b, r, c] = np.inf if r == c else 0.0
            continue
        s2 = sigma[b] * sigma[b]
        for r in range(6):
            for c in range(6):
                C[r, c] = M[r, 6 + c] * s2
        # inverse left Jacobian of SO(3) at rvec
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
        # out = M C Mᵀ with M = diag(Jl, I)
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
    return out


# ================================================================================ camera
@_jit
def undistort(px, fx, fy, cx, cy, d):
    """Normalised coordinates of distorted pixels and the local Jacobian d(normalised)/d(pixel)
    (OpenCV's rational + thin-prism model, 12 coefficients ``d``; no tilt), by Newton's method
    on the distortion with its analytic Jacobian.

    Returns:
        (q (n, 2), J (n, 2, 2)).
    """
    n = px.shape[0]
    q = np.empty((n, 2))
    Jout = np.empty((n, 2, 2))
    k1, k2, p1, p2, k3, k4, k5, k6 = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
    s1, s2, s3, s4 = d[8], d[9], d[10], d[11]
    for i in range(n):
        ux = (px[i, 0] - cx) / fx
        uy = (px[i, 1] - cy) / fy
        x = ux
        y = uy
        a00 = 1.0
        a01 = 0.0
        a10 = 0.0
        a11 = 1.0
        for _ in range(12):
            r2 = x * x + y * y
            Nn = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            Dd = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
            rad = Nn / Dd
            dN = k1 + r2 * (2 * k2 + 3 * k3 * r2)
            dD = k4 + r2 * (2 * k5 + 3 * k6 * r2)
            drad = (dN * Dd - Nn * dD) / (Dd * Dd)
            ex = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
            ey = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
            sx = s1 + 2 * s2 * r2
            sy = s3 + 2 * s4 * r2
            a00 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * sx * x
            a01 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * sx * y
            a10 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * sy * x
            a11 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * sy * y
            rx = ux - ex
            ry = uy - ey
            det = a00 * a11 - a01 * a10
            if det == 0.0:
                break
            dx = (a11 * rx - a01 * ry) / det
            dy = (a00 * ry - a10 * rx) / det
            x += dx
            y += dy
            if abs(dx) + abs(dy) < 1e-15:
                break
        q[i, 0] = x
        q[i, 1] = y
        det = a00 * a11 - a01 * a10
        if det == 0.0:
            det = 1e-300
        # d(normalised)/d(pixel) = A⁻¹ · diag(1/fx, 1/fy)
        Jout[i, 0, 0] = a11 / det / fx
        Jout[i, 0, 1] = -a01 / det / fy
        Jout[i, 1, 0] = -a10 / det / fx
        Jout[i, 1, 1] = a00 / det / fy
    return q, Jout


@_jit
def project(Y, fx, fy, cx, cy, d):
    """Distorted pixels (n, 2) of camera-frame points (n, 3) (the model of :func:`undistort`;
    as ``cv2.projectPoints`` with zero pose)."""
    n = Y.shape[0]
    out = np.empty((n, 2))
    k1, k2, p1, p2, k3, k4, k5, k6 = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
    s1, s2, s3, s4 = d[8], d[9], d[10], d[11]
    for i in range(n):
        z = Y[i, 2]
        iz = 1.0 / z if z != 0 else 1.0
        x = Y[i, 0] * iz
        y = Y[i, 1] * iz
        r2 = x * x + y * y
        rad = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
        out[i, 0] = fx * xd + cx
        out[i, 1] = fy * yd + cy
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
