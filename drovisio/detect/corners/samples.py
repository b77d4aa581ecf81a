"""Which pixels of each code enter the code fit, and where they lie in the undistorted plane.

Every pixel of a code's box around its fit region (a random subset of a big box: a regular
one would alias with the edges) is placed in the code's cells through the start homography and
kept when it lies in the fit region within a band of a modelled edge, at most ``M`` per code at
random. :func:`select_samples` runs the compiled kernel (:mod:`.samples_kernels`) where numba
is enabled and the numpy reference (:func:`_select_samples`, the same samples) otherwise.
"""

from __future__ import annotations

import numpy as np

from drovisio import _numba
from drovisio.camera import Camera
from drovisio.detect.corners import samples_kernels as _ck

__all__ = ["RANDOM", "grid_lookup", "normalized_grid", "pixel_boxes", "select_samples"]

RANDOM = np.random.default_rng(12345).random(1 << 16) * 0.999
"""The fixed table of random numbers both paths draw from (deterministic samples)."""

_GRID_CACHE: dict[bytes, np.ndarray] = {}


def normalized_grid(camera: Camera) -> np.ndarray:
    """Undistorted normalised coordinates of every pixel centre: (H, W, 2) float32, cached
    per camera (a few tenths of a second once)."""
    key = camera.K.tobytes() + camera.dist.tobytes() + bytes(f"{camera.width}x{camera.height}",
                                                             "ascii")
    grid = _GRID_CACHE.get(key)
    if grid is None:
        gx, gy = np.meshgrid(np.arange(camera.width, dtype=np.float64),
                             np.arange(camera.height, dtype=np.float64))
        xy = camera.normalize(np.stack([gx.ravel(), gy.ravel()], axis=1))
        # float32: 6e-8 in normalised units is 3e-5 px, and half the memory to gather from
        grid = np.ascontiguousarray(xy.reshape(camera.height, camera.width, 2), np.float32)
        grid.flags.writeable = False
        if len(_GRID_CACHE) >= 4:
            _GRID_CACHE.pop(next(iter(_GRID_CACHE)))
        _GRID_CACHE[key] = grid
    return grid


def grid_lookup(grid: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Normalised coordinates at sub-pixel positions (N, 2), bilinear in the grid; positions
    up to 3 px outside the image take the border's values (only a start for the fit), NaN
    beyond."""
    H, W = grid.shape[:2]
    x, y = px[:, 0], px[:, 1]
    inside = (x >= -3) & (y >= -3) & (x <= W + 2) & (y <= H + 2)   # False for NaN too
    x = np.minimum(np.maximum(np.where(inside, x, 0.0), 0.0), W - 1.000001)
    y = np.minimum(np.maximum(np.where(inside, y, 0.0), 0.0), H - 1.000001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    g = grid.reshape(-1, 2)
    i = y0 * W + x0
    out = ((g[i] * (1 - fx) + g[i + 1] * fx) * (1 - fy)
           + (g[i + W] * (1 - fx) + g[i + W + 1] * fx) * fy)
    out[~inside] = np.nan
    return out


def pixel_boxes(q: np.ndarray, scale: np.ndarray, shape: tuple[int, ...]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The box of pixels around each code's quad scaled about its centre, with 2 px more for
    perspective and the start's error, clipped to the image.

    Args:
        q: (C, 4, 2) corners, px.
        scale: (C,) how much the quad is grown (> 1) or shrunk about its centre.
        shape: The image's shape (H, W, ...).

    Returns:
        (x0, y0, bw, bh), each (C,) int64: top-left pixel, width and height.
    """
    H_img, W_img = shape[:2]
    qc = q.sum(axis=1, keepdims=True) * 0.25
    qr = qc + (q - qc) * scale[:, None, None]
    lo_xy = np.maximum(np.floor(qr.min(axis=1) - 2.0), 0.0).astype(np.int64)
    hi_xy = np.ceil(qr.max(axis=1) + 2.0).astype(np.int64)
    x0, y0 = lo_xy[:, 0], lo_xy[:, 1]
    bw = np.minimum(hi_xy[:, 0], W_img - 1) - x0 + 1
    bh = np.minimum(hi_xy[:, 1], H_img - 1) - y0 + 1
    return x0, y0, bw, bh


def _select_samples(grid: np.ndarray, gray: np.ndarray, x0: np.ndarray, y0: np.ndarray,
                    bw: np.ndarray, P: np.ndarray, P_box: np.ndarray, K: int,
                    centre: np.ndarray, scale: np.ndarray, g: np.ndarray, lo: np.ndarray,
                    hi: np.ndarray, band: np.ndarray, ns: np.ndarray, bits_pad: np.ndarray,
                    M: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The fit's samples (numpy reference of :func:`.samples_kernels.select_samples`, the
    same arguments but the random table)."""
    C = P.shape[0]
    W_img = grid.shape[1]
    code = np.repeat(np.arange(C), P)
    start = np.cumsum(P) - P
    k = np.arange(code.size) - np.repeat(start, P)
    big = np.repeat(P_box > K, P)
    if big.any():
        rnd = RANDOM[(np.arange(code.size) * 7919) % RANDOM.size]
        k = np.where(big, (rnd * np.repeat(P_box, P)).astype(np.int64), k)
    bwc = np.repeat(bw, P)
    px = np.repeat(x0, P) + k % bwc
    py = np.repeat(y0, P) + k // bwc
    xy = grid.reshape(-1, 2)[py * W_img + px]
    inv_scale = np.repeat(1.0 / scale, P)
    lx = (xy[:, 0] - np.repeat(centre[:, 0], P)) * inv_scale
    ly = (xy[:, 1] - np.repeat(centre[:, 1], P)) * inv_scale
    gc = np.repeat(g, P, axis=0)
    D = gc[:, 6] * lx + gc[:, 7] * ly + 1.0
    u = (gc[:, 0] * lx + gc[:, 1] * ly + gc[:, 2]) / D
    v = (gc[:, 3] * lx + gc[:, 4] * ly + gc[:, 5]) / D
    loc_, hic = np.repeat(lo, P), np.repeat(hi, P)
    inside = (u >= loc_) & (u <= hic) & (v >= loc_) & (v <= hic)
    nm1 = np.repeat(ns, P) - 1
    # near an edge: the cell across the nearest cell boundary (within `band`) differs
    d = np.repeat(band, P)
    fu, fv = np.floor(u), np.floor(v)
    ru, rv = u - fu, v - fv
    ui = np.minimum(np.maximum(fu.astype(np.int64), 0), nm1)
    vi = np.minimum(np.maximum(fv.astype(np.int64), 0), nm1)
    uj = np.minimum(np.maximum(ui - (ru < d) + (ru > 1.0 - d), 0), nm1)
    vj = np.minimum(np.maximum(vi - (rv < d) + (rv > 1.0 - d), 0), nm1)
    here = bits_pad[code, vi, ui]
    near = ((bits_pad[code, vi, uj] != here) | (bits_pad[code, vj, ui] != here)
            | (bits_pad[code, vj, uj] != here))
    sel = np.nonzero(inside & near)[0]
    # at most M per code, chosen at random (a fixed table: deterministic and cheap); `sel`
    # is sorted by code already
    sc = code[sel]
    counts = np.bincount(sc, minlength=C)
    if counts.max(initial=0) > M:  # shuffle within codes (only then is a subset taken)
        order = np.argsort(sc + RANDOM[np.arange(sel.size) % RANDOM.size], kind="stable")
        sel, sc = sel[order], sc[order]
    first = np.cumsum(counts) - counts
    rank = np.arange(sel.size) - first[sc]
    keep = rank < M
    sel, sc, rank = sel[keep], sc[keep], rank[keep]
    cnt = np.bincount(sc, minlength=C).astype(np.float64)
    M = max(int(cnt.max()), 1)  # pad to the largest code's count only
    xs = np.zeros((C, M))
    ys = np.zeros((C, M))
    vals = np.zeros((C, M))
    wts = np.zeros((C, M))
    xs[sc, rank] = lx[sel]
    ys[sc, rank] = ly[sel]
    vals[sc, rank] = gray[py[sel], px[sel]]
    wts[sc, rank] = 1.0
    return xs, ys, vals, wts, cnt


def select_samples(grid: np.ndarray, gray: np.ndarray, x0: np.ndarray, y0: np.ndarray,
                   bw: np.ndarray, P: np.ndarray, P_box: np.ndarray, K: int,
                   centre: np.ndarray, scale: np.ndarray, g: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray, band: np.ndarray, ns: np.ndarray, bits_pad: np.ndarray,
                   M: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The fit's samples of C codes, compiled where numba is enabled.

    Args:
        grid: (H, W, 2) float32 normalised coordinates of the pixel centres
            (:func:`normalized_grid`); gray: (H, W) the frame.
        x0, y0, bw: (C,) the codes' boxes (top-left pixel, width); P: (C,) candidates per
            code (min(P_box, K)); P_box: (C,) pixels of each box; K: candidates per big box.
        centre, scale: (C, 2), (C,) the local frame; g: (C, 8) start homographies.
        lo, hi, band: (C,) fit region and edge band, cells; ns: (C,) cells per side.
        bits_pad: (C, n, n) cells with border (padded); M: most samples per code.

    Returns:
        (xs, ys: the samples' local coordinates, vals: their grey levels, wts: 1 where a
        sample is, each (C, Mc); counts (C,)), Mc the largest count (≥ 1).
    """
    if _numba.enabled():   # one compiled pass, the same samples
        c_ = np.ascontiguousarray   # one compiled signature whatever the views
        return _ck.select_samples(
            grid, c_(gray), c_(x0), c_(y0), c_(bw), c_(P), c_(P_box), K, c_(centre), c_(scale),
            c_(g), c_(lo, np.float64), c_(hi, np.float64), c_(band, np.float64), c_(ns),
            c_(bits_pad), RANDOM, M)
    return _select_samples(grid, gray, x0, y0, bw, P, P_box, K, centre, scale, g, lo, hi,
                           band, ns, bits_pad, M)
