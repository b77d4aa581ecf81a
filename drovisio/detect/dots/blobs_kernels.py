"""Compiled kernels of the dot detector's blob stage (numba): contour measures, convex hulls
and sub-pixel centres.

The numpy reference implementations are in :mod:`.blobs` (tests compare the two); the stage
chooses the kernel inside its own functions when :func:`drovisio._numba.enabled`. Pixel (0, 0)
is the centre of the top-left pixel.
"""

from __future__ import annotations

import math

import numpy as np

from drovisio._numba import jit as _jit


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
    """Shape measures of contours (the loops of :func:`.blobs._measure`).

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
def _window_sizes(need):
    """Window side per blob from the side each needs (n,): blobs whose windows are within a
    factor 2 share the largest."""
    n = need.shape[0]
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
    return wsize


@_jit
def _touch_windows(img, bx, by, wsize, max_w):
    """Load the first and last pixel of every window row (a sum the caller checks, so the
    loads stay)."""
    H = img.shape[0]
    W = img.shape[1]
    sink = 0
    for k in range(bx.shape[0]):
        if wsize[k] > max_w:
            continue
        cx = int(np.rint(bx[k]))
        cy = int(np.rint(by[k]))
        half = wsize[k] // 2
        xa = min(max(cx - half, 0), W - 1)
        xb = min(max(cx + half, 0), W - 1)
        for y in range(max(cy - half, 0), min(cy + half, H - 1) + 1):
            sink += img[y, xa, 0] + img[y, xb, 2]
    return sink


@_jit
def refine_centers(img, bx, by, ba, bb, cov, margin, max_w):
    """Colour-coverage centroids of blobs (the loops of :func:`.blobs.refine_centers`,
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
    wsize = _window_sizes(need)
    sup_x = np.empty(max_w * max_w, np.int64)
    sup_y = np.empty(max_w * max_w, np.int64)
    # visit blobs band by band, left to right: neighbouring windows share cache lines
    visit = np.argsort(np.floor(by / 16.0) * 1e5 + bx)
    # touch every window row first: a new frame is seldom in the cache, and these loads are
    # independent, so they overlap (-25 % with a cold cache); the windows then fit in L2
    if _touch_windows(img, bx, by, wsize, max_w) == 1234567891234:  # never: keeps the loads
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
