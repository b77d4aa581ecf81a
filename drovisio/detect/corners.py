"""Unbiased sub-pixel corners of square fiducial codes by fitting a photometric model.

Why not OpenCV's corner refinement: the outer edge of a printed code sits between its black
border and whatever is around it (a thin strip of paper, then the brick); once blurred, that
neighbourhood pulls every local edge or corner estimator (gradient peak, threshold crossing,
``cornerSubPix``) by 0.3–0.7 px, a bias measured on renders. Here the outer edge is not used
at all. Each code is fitted *as a whole* from the inside: knowing the code's bits (from its
decoded id), the model predicts every pixel of the code's interior,

    I(p) = B + (W − B) · S(u, v),        (u, v) = G(x(p))

where ``x(p)`` is the undistorted, normalised image coordinate of pixel ``p`` (exact, from
the camera model), ``G`` the 8-parameter homography from the image plane to the code plane in
cell units (the outer border spans [0, n]², n = bits + 2), and ``S`` the code's white cells
blurred by a separable Gaussian (``s_u``, ``s_v`` in cells: defocus, motion, pixel area). The
twelve parameters (G, B, W, s_u, s_v) are fitted by Levenberg–Marquardt to the pixels of the
region [1 − a, n − 1 + a]² (the inner edges of the border and every bit edge) that lie within
a couple of pixels of a modelled edge (a random subset for big codes: a regular one aliases
with the edges), batched over all codes of a frame. Blur acts symmetrically on every modelled
edge, so the fitted homography, and the outer corners ``G⁻¹((0,0), (n,0), (n,n), (0,n))``,
carry no blur bias; working in undistorted coordinates makes lens distortion exact as well.

The fit also yields, per code, the corners' 8×8 covariance (from the Jacobian and the fit's
residual noise), the contrast, the blur, and two checks used to reject decoys and partly
hidden codes: the goodness of fit, and a deblurred read-back of every inner cell at the fitted
geometry, judged by the code's own two brightness classes (:func:`cell_verdicts`: real JPEGs
read cells at 0.7 / 0.3 that still lie 15+ spreads apart); a corner that moved farther from
its start than the frame's measured start noise allows is refused too (:func:`_move_limits`).

Measured on rendered drick scenes (``drovisio bench aruco``, blur σ ≤ 1 px, 2852 corners):
mean signed radial error +0.004 px, RMS 0.20 px; OpenCV's corners at the detector's settings
−1.04 px and 1.21 px.

The choice of the samples runs compiled (:mod:`.corners_kernels`, numba) where numba is
installed, with the same samples as :func:`_select_samples`; the fit stays numpy (its dense
float32 arithmetic is faster vectorised).

Conventions: pixel (0, 0) is the centre of the top-left pixel; corners in OpenCV order TL, TR,
BR, BL of the printed code (the order of ``cv2.aruco`` and of the layout file).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from drovisio import _numba
from drovisio.camera import Camera
from drovisio.detect import corners_kernels as _ck

__all__ = ["RefinedCode", "cell_verdict", "cell_verdicts", "normalized_grid", "refine_codes"]

#: samples (pixels) per code in the fit; bigger codes are subsampled on a regular grid
MAX_SAMPLES = 280
_RANDOM = np.random.default_rng(12345).random(1 << 16) * 0.999


@dataclass
class RefinedCode:
    """One code after refinement.

    Args:
        corners_px: (4, 2) outer-border corners TL, TR, BR, BL in distorted pixels.
        corners_norm: (4, 2) the same in undistorted normalised coordinates (x/z, y/z).
        cov_px: (8, 8) covariance of ``corners_px.ravel()`` in px².
        sigma_px: RMS standard deviation of one corner coordinate, px (sqrt of mean diag).
        residual: RMS photometric residual of the fit, grey levels.
        contrast: fitted white − black, grey levels.
        blur_px: fitted blur (Gaussian sigma incl. pixel area), px.
        ok: the fit converged to a plausible code (contrast, residual, shape, step sizes).
        reason: why not ``ok`` (empty when ok).
        cell_margin: see the attribute.
    """

    corners_px: np.ndarray
    corners_norm: np.ndarray
    cov_px: np.ndarray
    sigma_px: float
    residual: float
    contrast: float
    blur_px: float
    ok: bool
    reason: str = ""
    cell_margin: float = 0.0
    """How clearly the code's inner cells read as its bits, from a deblurred least-squares
    estimate of each cell's whiteness a (0 black .. 1 white) at the fitted geometry and blur:
    min over cells of (a - 0.5) for white cells and (0.5 - a) for black ones. Below 0 some
    cell reads wrong: a decoy or another code."""


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


def _grid_lookup(grid: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Normalised coordinates at sub-pixel positions (N, 2), bilinear in the grid; positions
    up to 3 px outside the image take the border's values (only a start for the fit), NaN
    beyond."""
    H, W = grid.shape[:2]
    x, y = px[:, 0], px[:, 1]
    inside = (x >= -3) & (y >= -3) & (x <= W + 2) & (y <= H + 2)
    x = np.minimum(np.maximum(x, 0.0), W - 1.000001)
    y = np.minimum(np.maximum(y, 0.0), H - 1.000001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    g = grid.reshape(-1, 2)
    i = y0 * W + x0
    out = ((g[i] * (1 - fx) + g[i + 1] * fx) * (1 - fy)
           + (g[i + W] * (1 - fx) + g[i + W + 1] * fx) * fy)
    out[~inside] = np.nan
    return out


def _phi_cdf(z: np.ndarray) -> np.ndarray:
    """Standard normal CDF, tanh approximation (|error| < 2e-4; one transcendental call)."""
    h = z.dtype.type(0.5)
    return h + h * np.tanh(z * (z.dtype.type(0.7978845608028654)
                                + z.dtype.type(0.035677408136300125) * z * z))


def _g_to_mat(g: np.ndarray) -> np.ndarray:
    C = g.shape[0]
    H = np.ones((C, 3, 3))
    H[:, 0] = g[:, 0:3]
    H[:, 1] = g[:, 3:6]
    H[:, 2, :2] = g[:, 6:8]
    return H


def _inv3(H: np.ndarray) -> np.ndarray:
    """Inverses of (C, 3, 3) matrices by the adjugate (no LAPACK call: it is the overhead of
    a call, not the arithmetic, that costs here)."""
    a, b, c = H[:, 0, 0], H[:, 0, 1], H[:, 0, 2]
    d, e, f = H[:, 1, 0], H[:, 1, 1], H[:, 1, 2]
    g, h, i = H[:, 2, 0], H[:, 2, 1], H[:, 2, 2]
    A, B, C_ = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * A + b * B + c * C_
    adj = np.empty_like(H)
    adj[:, 0, 0], adj[:, 1, 0], adj[:, 2, 0] = A, B, C_
    adj[:, 0, 1], adj[:, 1, 1], adj[:, 2, 1] = c * h - b * i, a * i - c * g, b * g - a * h
    adj[:, 0, 2], adj[:, 1, 2], adj[:, 2, 2] = b * f - c * e, c * d - a * f, a * e - b * d
    return adj / det[:, None, None]


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    try:
        dp = np.linalg.solve(A, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        dp = np.zeros_like(b)
        for c in range(A.shape[0]):
            try:
                dp[c] = np.linalg.solve(A[c], b[c])
            except np.linalg.LinAlgError:
                pass
    dp[~np.isfinite(dp).all(axis=1)] = 0.0
    return dp


def _model(g, lev, s, x, y, bits, bits_t, n_max, jacobian=True, blur_jacobian=True):
    """Model intensity (C, M) and, with ``jacobian``, its transposed Jacobian (C, 12, M).

    bits: (C, n_max - 2, n_max - 2) the *inner* cells (row, column), zero-padded, bits_t
    their transpose: the border is black (0), so only the inner cells and the boundaries
    1 .. n_max - 1 between them contribute. The heavy arrays are laid out
    (C, 2, boundaries, M) (u/v, cell boundary, sample) in float32 so that every reduction
    runs over a middle axis with contiguous samples.
    """
    D = g[:, 6, None] * x + g[:, 7, None] * y + 1.0
    invD = 1.0 / D
    uv = np.empty((x.shape[0], 2, x.shape[1]))
    uv[:, 0] = (g[:, 0, None] * x + g[:, 1, None] * y + g[:, 2, None]) * invD
    uv[:, 1] = (g[:, 3, None] * x + g[:, 4, None] * y + g[:, 5, None]) * invD
    k = np.arange(1, n_max, dtype=np.float32)[:, None]
    inv_s = (1.0 / s).astype(np.float32)[:, :, None, None]  # (C, 2, 1, 1)
    z = (uv.astype(np.float32)[:, :, None, :] - k) * inv_s  # (C, 2, n - 1, M)
    th = np.tanh(z * (np.float32(0.7978845608028654) + np.float32(0.035677408136300125) * z * z))
    A = np.float32(0.5) + np.float32(0.5) * th  # Phi(z), as _phi_cdf
    w = A[:, :, :-1] - A[:, :, 1:]  # (C, 2, n - 2, M): inner column j (u) / row r (v)
    col, row = w[:, 0], w[:, 1]
    T = np.matmul(bits_t, row)  # (C, n, M): T[j] = sum_r bits[r, j] row_r
    S = (T * col).sum(axis=1, dtype=np.float64)
    B, W = lev[:, 0, None], lev[:, 1, None]
    amp = W - B
    I = B + amp * S
    if not jacobian:
        return I, None
    Tv = np.matmul(bits, col)  # (C, n, M): Tv[r] = sum_j bits[r, j] col_j
    # the exact derivative of the tanh form of Phi (consistent with the model, no exp):
    # d/dz [0.5 + 0.5 tanh(z (c1 + c3 z^2))] = 0.5 (1 - tanh^2) (c1 + 3 c3 z^2)
    pz = np.float32(0.5) * (np.float32(1.0) - th * th) * (
        np.float32(0.7978845608028654) + np.float32(3 * 0.035677408136300125) * z * z)
    dw = (pz[:, :, :-1] - pz[:, :, 1:]) * inv_s  # d w / d (u or v)
    dS = np.empty((x.shape[0], 2, x.shape[1]))  # dS/du, dS/dv
    dS[:, 0] = (T * dw[:, 0]).sum(axis=1, dtype=np.float64)
    dS[:, 1] = (Tv * dw[:, 1]).sum(axis=1, dtype=np.float64)
    if blur_jacobian:
        qz = pz * z
        dws = (qz[:, :, 1:] - qz[:, :, :-1]) * inv_s  # d/ds Phi((u-k)/s) = -phi z / s
        dSs = np.empty_like(dS)  # dS/dsu, dS/dsv
        dSs[:, 0] = (T * dws[:, 0]).sum(axis=1, dtype=np.float64)
        dSs[:, 1] = (Tv * dws[:, 1]).sum(axis=1, dtype=np.float64)
    else:
        dSs = np.zeros_like(dS)
    J = np.empty((x.shape[0], 12, x.shape[1]))
    a = (amp * invD)[:, None] * dS  # (C, 2, M)
    a_u, a_v = a[:, 0], a[:, 1]
    J[:, 0] = a_u * x
    J[:, 1] = a_u * y
    J[:, 2] = a_u
    J[:, 3] = a_v * x
    J[:, 4] = a_v * y
    J[:, 5] = a_v
    wq = -(a_u * uv[:, 0] + a_v * uv[:, 1])
    J[:, 6] = wq * x
    J[:, 7] = wq * y
    J[:, 8] = 1.0 - S
    J[:, 9] = S
    J[:, 10:12] = amp[:, None] * dSs
    return I, J


def _cell_margins(g, lev, s, x, y, vals, wts, bits, ns
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per code, how clearly its inner cells read as its bits (see RefinedCode.cell_margin).

    At the fitted geometry and blur, each inner cell's whiteness a_k is estimated by linear
    least squares, (I - B)/(W - B) = sum_k a_k row_r(v) col_j(u), with a weak pull toward the
    expected bit (cells no sample sees keep it).

    Returns:
        (margin (C,): the least signed margin, a - 0.5 for white cells and 0.5 - a for black
        ones; a (C, cells): every cell's whiteness, NaN beyond a code's own size (codes
        padded to a larger n); the expected bits (C, cells), 1 = white).
    """
    C, n = bits.shape[0], bits.shape[1]
    D = g[:, 6, None] * x + g[:, 7, None] * y + 1.0
    u = ((g[:, 0, None] * x + g[:, 1, None] * y + g[:, 2, None]) / D).astype(np.float32)
    v = ((g[:, 3, None] * x + g[:, 4, None] * y + g[:, 5, None]) / D).astype(np.float32)
    k = np.arange(1, n, dtype=np.float32)[:, None]  # the boundaries of the inner cells
    inv_s = (1.0 / s).astype(np.float32)
    Au = _phi_cdf((u[:, None, :] - k) * inv_s[:, 0, None, None])
    Av = _phi_cdf((v[:, None, :] - k) * inv_s[:, 1, None, None])
    col = Au[:, :-1] - Au[:, 1:]  # (C, n-2, M) inner columns
    row = (Av[:, :-1] - Av[:, 1:]) * wts[:, None, :].astype(np.float32)  # weights 0/1
    m = n - 2
    basis = (row[:, :, None, :] * col[:, None, :, :]).reshape(C, m * m, -1)  # (C, cells, M)
    amp = lev[:, 1] - lev[:, 0]
    yv = ((vals - lev[:, 0, None]) / np.where(np.abs(amp) > 1e-9, amp, 1.0)[:, None]
          ).astype(np.float32)
    A = np.matmul(basis, basis.transpose(0, 2, 1)).astype(np.float64)
    expected = bits[:, 1:-1, 1:-1].reshape(C, m * m).astype(np.float64)
    mu = 0.05 * (A.trace(axis1=1, axis2=2) / (m * m))[:, None] + 1e-9
    rhs = np.matmul(basis, yv[..., None])[..., 0].astype(np.float64) + mu * expected
    A = A + mu[:, :, None] * np.eye(m * m)
    a = _solve(A, rhs)
    # codes padded to a larger n carry zero cells beyond their own size: not theirs
    for c in np.nonzero(ns < n)[0]:
        own = np.zeros((m, m), bool)
        own[:ns[c] - 2, :ns[c] - 2] = True
        a[c, ~own.ravel()] = np.nan
    margins = np.where(expected > 0.5, a - 0.5, 0.5 - a)
    return np.nanmin(margins, axis=1), a, expected


def cell_verdict(a: np.ndarray, expected: np.ndarray, tolerable: int,
                 false_rate: float = 0.01) -> tuple[bool, int, int, float]:
    """Whether a code's cells read as its bits, judged by the cells' own statistics.

    The cells a code's bits call white and those they call black form two brightness classes
    (whiteness ``a`` from the deblurred fit, :func:`_cell_margins`); their centres (medians)
    and common spread (the pooled median absolute deviation) are measured in the code itself,
    so JPEG blocks, gamma and residual blur widen the classes instead of failing the code. A
    cell *reads wrong* when it lies nearer the other class's centre; it is *undecided* when
    the odds that it belongs to its own class rather than the other (normal classes of the
    measured spread) are below ``2 · cells / false_rate`` (a cell that far from both classes
    is decided by neither: on exact renders the spread is tiny and a cell a few spreads off
    its class still reads right). The code is accepted when no cell
    reads wrong, at most ``tolerable`` are undecided (with that many unknown, the decided
    cells still tell the code from every other by the dictionary's distance: the rescue's bit
    tolerance), and the classes lie at least ``2 z`` spreads apart (``z``: the normal quantile
    beyond which a right cell falls with chance ``false_rate`` over all the code's cells, so
    that a right cell almost never crosses the midpoint).

    Args:
        a: (cells,) whiteness of each inner cell (NaN: not a cell of this code).
        expected: (cells,) the code's bits, 1 = white.
        tolerable: Undecided cells the dictionary's distance allows.
        false_rate: Chance that a right code is refused for one of its cells.

    Returns:
        (accepted, cells read wrong, cells undecided, class separation in spreads).
    """
    ok, wrong, undecided, sep = cell_verdicts(np.asarray(a, np.float64)[None],
                                              np.asarray(expected, np.float64)[None],
                                              np.array([tolerable]), false_rate)
    return bool(ok[0]), int(wrong[0]), int(undecided[0]), float(sep[0])


def _row_median(x: np.ndarray) -> np.ndarray:
    """Median of each row's finite values (NaN: none), by one sort (np.nanmedian is ~10×
    slower on small rows)."""
    srt = np.sort(x, axis=1)   # NaN last
    k = np.isfinite(x).sum(axis=1)
    r = np.arange(len(x))
    lo, hi = np.maximum((k - 1) // 2, 0), np.maximum(k // 2, 0)
    hi = np.minimum(hi, x.shape[1] - 1)
    return np.where(k > 0, 0.5 * (srt[r, lo] + srt[r, hi]), np.nan)


@functools.lru_cache(maxsize=64)
def _z_quantile(cells: int, false_rate: float) -> float:
    from statistics import NormalDist

    return NormalDist().inv_cdf(1.0 - false_rate / (2.0 * max(cells, 1)))


def cell_verdicts(a: np.ndarray, expected: np.ndarray, tolerable: np.ndarray,
                  false_rate: float = 0.01
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cell_verdict` for C codes at once: ``a`` and ``expected`` (C, cells), NaN
    where a cell is not the code's; ``tolerable`` (C,). Returns (accepted, wrong, undecided,
    separation), each (C,)."""
    own = np.isfinite(a)
    white = (expected > 0.5) & own
    black = ~white & own
    n = own.sum(axis=1)
    both = white.any(axis=1) & black.any(axis=1)
    with np.errstate(all="ignore"):   # a code without one class: NaN, refused below
        cw = _row_median(np.where(white, a, np.nan))
        cb = _row_median(np.where(black, a, np.nan))
        dev = np.where(white, a - cw[:, None], np.where(black, a - cb[:, None], np.nan))
        # 1.4826 MAD: the normal's sigma; floored at a hundredth of the contrast (renders)
        spread = np.maximum(1.4826 * _row_median(np.abs(dev)), 0.01)
        mid = 0.5 * (cw + cb)
        d = np.where(white, a - mid[:, None], mid[:, None] - a) / spread[:, None]
        sep = (cw - cb) / spread
    z = np.array([_z_quantile(int(k), false_rate) for k in n])
    wrong = (own & ~(d > 0)).sum(axis=1)
    # log odds of the own class against the other at d spreads from the midpoint: sep · d
    odds = np.log(2.0 * np.maximum(n, 1) / false_rate)
    undecided = (own & (d > 0) & (sep[:, None] * d < odds[:, None])).sum(axis=1)
    sep = np.where(both & np.isfinite(sep), sep, 0.0)
    ok = both & (wrong == 0) & (undecided <= np.asarray(tolerable)) & (sep >= 2.0 * z)
    return ok, wrong, undecided, sep


def _homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Batched exact 4-point homographies (C, 8) mapping src (C, 4, 2) to dst (C, 4, 2)."""
    C = src.shape[0]
    A = np.zeros((C, 8, 8))
    b = np.zeros((C, 8))
    x, y = src[..., 0], src[..., 1]
    u, v = dst[..., 0], dst[..., 1]
    A[:, 0::2, 0] = x
    A[:, 0::2, 1] = y
    A[:, 0::2, 2] = 1.0
    A[:, 0::2, 6] = -x * u
    A[:, 0::2, 7] = -y * u
    A[:, 1::2, 3] = x
    A[:, 1::2, 4] = y
    A[:, 1::2, 5] = 1.0
    A[:, 1::2, 6] = -x * v
    A[:, 1::2, 7] = -y * v
    b[:, 0::2] = u
    b[:, 1::2] = v
    return _solve(A, b)


def _select_samples(grid, gray, x0, y0, bw, P, P_box, K, centre, scale, g, lo, hi, band,
                    ns, bits_pad, M):
    """The fit's samples (numpy reference of :func:`.corners_kernels.select_samples`)."""
    C = P.shape[0]
    W_img = grid.shape[1]
    code = np.repeat(np.arange(C), P)
    start = np.cumsum(P) - P
    k = np.arange(code.size) - np.repeat(start, P)
    big = np.repeat(P_box > K, P)
    if big.any():
        rnd = _RANDOM[(np.arange(code.size) * 7919) % _RANDOM.size]
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
        order = np.argsort(sc + _RANDOM[np.arange(sel.size) % _RANDOM.size], kind="stable")
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


def _move_limits(moved: np.ndarray, use: np.ndarray, floor_px: float, cell_px: np.ndarray
                 ) -> np.ndarray:
    """How far (px) a corner of each code may move from its start, from the start noise
    measured in this frame.

    The starts' errors (OpenCV's corners, rescued quads) are taken as isotropic normal with
    a standard deviation ``sigma`` per axis, estimated robustly over every corner of the frame
    (the median distance moved is ``1.1774 sigma`` for a 2-D normal), but never below
    ``floor_px``. A right corner moves farther than ``sigma · sqrt(2 ln(N / 0.001))`` (N: the
    frame's corners) with a chance of 0.1 % a frame: a corner beyond that went elsewhere (the fit
    slid along an edge, onto the paper around the code). The limit never exceeds the
    previous bound of one and a half cells (at least 2 px).
    """
    C = len(moved)
    cap = np.maximum(1.5 * cell_px, 2.0)
    if not use.any():
        return cap
    d = moved[use].ravel()
    sigma = max(float(np.median(d)) / 1.1774, floor_px)
    limit = sigma * np.sqrt(2.0 * np.log(max(d.size, 1) / 0.001))
    return np.minimum(cap, np.full(C, limit))


def refine_codes(gray: np.ndarray, camera: Camera, corners: list[np.ndarray] | np.ndarray,
                 bits: list[np.ndarray], iterations: int = 3, coarse_iterations: int = 1,
                 chord_from: int | None = None, max_samples: int = MAX_SAMPLES,
                 band_px: float = 3.0, coarse_min_cell_px: float = 0.0,
                 lm_lambda: float = 0.1, tolerable_cells: int | np.ndarray = 0,
                 blur_iterations: int = 99, start_sigma_px: float = 0.85
                 ) -> list[RefinedCode]:
    """Refine the outer corners of decoded codes by a photometric fit of their interior.

    All codes of a frame are fitted together (batched arrays), so the cost grows slowly with
    their number.

    Args:
        gray: (H, W) uint8 (or float) image.
        camera: The calibrated camera the image comes from (its size must match).
        corners: Per code, (4, 2) rough corners in pixels, TL, TR, BR, BL (e.g. from
            ``cv2.aruco``), good to about a third of a cell; a list or a (C, 4, 2) array.
        bits: Per code, (n, n) cells with border, 1 = white
            (:func:`drovisio.layout.aruco_code_bits`).
        iterations: Levenberg–Marquardt iterations (the first ``coarse_iterations`` with a
            wide blur for a wide basin of convergence).
        chord_from: From this iteration on, reuse the last Jacobian (chord steps, a fifth
            of the cost of a full one); None: a fresh Jacobian every iteration.
        max_samples: Pixels per code used in the fit (a random subset when more are near
            edges; a regular subset would alias with the edges).
        band_px: Pixels farther than this from every modelled edge are not used.
        coarse_min_cell_px: The coarse iterations are skipped when no code has cells this
            big (0: never skipped; skipping lost accuracy on small codes).
        lm_lambda: Initial Levenberg–Marquardt damping (relative to the diagonal); 0.1
            measured best with three iterations.
        tolerable_cells: Per code (or one number for all), how many inner cells may read
            undecided at the fit's noise (:func:`cell_verdict`); a code with a cell that
            reads wrong, or with more undecided cells, is not ``ok``.
        blur_iterations: The blur is fitted in the first this many fine iterations only
            (default: all; fitting it in every iteration measured best).
        start_sigma_px: Least standard deviation (px, per axis) of the starts' errors: a
            corner that moves farther than the frame's start noise allows is refused
            (:func:`_move_limits`). 0.85: OpenCV's corners at the detector's settings,
            1.21 px RMS (both axes) on the rendered bench.

    Returns:
        One :class:`RefinedCode` per input code, in order.
    """
    C = len(corners)
    if C == 0:
        return []
    H_img, W_img = gray.shape[:2]
    grid = normalized_grid(camera)
    if grid.shape[:2] != (H_img, W_img):
        raise ValueError(f"image is {W_img}×{H_img} but the camera is {camera.width}×"
                         f"{camera.height}; give the camera file of this image size")
    M = int(max_samples)
    ns = np.array([b.shape[0] for b in bits], np.int64)
    n_max = int(ns.max())
    bits_pad = np.zeros((C, n_max, n_max))
    for c in range(C):
        bits_pad[c, :ns[c], :ns[c]] = bits[c]
    q = np.asarray(corners, np.float64).reshape(C, 4, 2)
    qn = _grid_lookup(grid, q.reshape(-1, 2)).reshape(C, 4, 2)
    valid = np.isfinite(qn).all(axis=(1, 2))
    reasons = ["" if ok else "corners outside the calibrated field" for ok in valid]
    qn = np.where(valid[:, None, None], qn, 0.0)
    nf = ns.astype(np.float64)
    prev = [3, 0, 1, 2]  # each corner's predecessor (np.roll is slow on small arrays)
    dq = q - q[:, prev]
    side_px = np.sqrt((dq * dq).sum(axis=2))
    cell_px = side_px.sum(axis=1) / (4.0 * nf)
    centre = qn.sum(axis=1) * 0.25
    dqn = qn - qn[:, prev]
    scale = np.sqrt((dqn * dqn).sum(axis=2)).sum(axis=1) / (4.0 * nf)
    scale = np.where(scale > 0, scale, 1.0)
    loc = (qn - centre[:, None]) / scale[:, None, None]
    uv_c = np.zeros((C, 4, 2))
    uv_c[:, 1, 0] = nf
    uv_c[:, 2, 0] = nf
    uv_c[:, 2, 1] = nf
    uv_c[:, 3, 1] = nf
    g = _homographies(loc, uv_c)
    # fit region: inside the border's outer side by >= 3 px, never beyond the inner bits
    a = np.minimum(np.maximum((cell_px - 3.0) / np.maximum(cell_px, 1e-9), 0.0), 0.6)
    lo, hi = 1.0 - a, nf - 1.0 + a
    band = np.minimum(band_px / np.maximum(cell_px, 1e-9), 0.5)
    # every pixel of the bounding box of each code's fit region (its quad shrunk about the
    # centre to the region, plus 2 px for perspective and the start's error), flattened
    # with its code index
    qc = q.sum(axis=1, keepdims=True) * 0.25
    shrink = ((hi - lo) / nf)[:, None, None]
    qr = qc + (q - qc) * shrink
    lo_xy = np.maximum(np.floor(qr.min(axis=1) - 2.0), 0.0).astype(np.int64)
    hi_xy = np.ceil(qr.max(axis=1) + 2.0).astype(np.int64)
    x0, y0 = lo_xy[:, 0], lo_xy[:, 1]
    x1 = np.minimum(hi_xy[:, 0], W_img - 1)
    y1 = np.minimum(hi_xy[:, 1], H_img - 1)
    bw, bh = x1 - x0 + 1, y1 - y0 + 1
    small = (bw < 4) | (bh < 4)
    for c in np.nonzero(small & valid)[0]:
        reasons[c] = "too small"
    valid &= ~small
    P_box = np.where(valid, bw * bh, 0)
    # big codes: a random subset of their box (random: a regular stride would alias with the
    # edges), about 4 candidates per sample kept
    K = 8 * M
    P = np.minimum(P_box, K)
    if _numba.enabled():   # one compiled pass, the same samples
        c_ = np.ascontiguousarray   # one compiled signature whatever the views
        xs, ys, vals, wts, cnt = _ck.select_samples(
            grid, c_(gray), c_(x0), c_(y0), c_(bw), c_(P), c_(P_box), K, c_(centre), c_(scale),
            c_(g), c_(lo, np.float64), c_(hi, np.float64), c_(band, np.float64), c_(ns),
            c_(bits_pad), _RANDOM, M)
    else:
        xs, ys, vals, wts, cnt = _select_samples(grid, gray, x0, y0, bw, P, P_box, K, centre,
                                                 scale, g, lo, hi, band, ns, bits_pad, M)
    cnt = cnt.astype(np.float64)
    few = valid & (cnt < 24)
    for c in np.nonzero(few)[0]:
        reasons[c] = "too few pixels"
    valid &= ~few
    wts[~valid] = 0.0
    # start: levels from the sample distribution, blur ~0.9 px
    srt = np.sort(np.where(wts > 0, vals, np.inf), axis=1)
    m_i = np.maximum(cnt.astype(np.int64), 1)
    lev = np.stack([srt[np.arange(C), (0.05 * (m_i - 1)).astype(np.int64)],
                    srt[np.arange(C), (0.95 * (m_i - 1)).astype(np.int64)]], axis=1)
    lev[~np.isfinite(lev)] = 0.0
    s = np.repeat((0.9 / np.maximum(cell_px, 1e-9))[:, None], 2, axis=1)
    bits_in = np.ascontiguousarray(bits_pad[:, 1:-1, 1:-1], np.float32)
    bits_t = np.ascontiguousarray(bits_in.transpose(0, 2, 1))
    s_floor = np.minimum(1.5 / np.maximum(cell_px, 1e-9), 0.25)  # coarse start: wide basin
    lam = np.full(C, lm_lambda)
    eye12 = np.eye(12)
    cost = r = Jw = A = None
    if not np.any(valid & (cell_px >= coarse_min_cell_px)):
        coarse_iterations = 0  # small codes only: their blur is wide enough already
    for it in range(iterations):
        coarse = it < coarse_iterations
        if coarse:
            s = np.maximum(s, s_floor[:, None])
        fresh = chord_from is None or it <= max(coarse_iterations, chord_from - 1)
        if fresh:  # new Jacobian; in between, its last value is reused (chord steps)
            fit_blur = not coarse and it < blur_iterations
            I, J = _model(g, lev, s, xs, ys, bits_in, bits_t, n_max, blur_jacobian=fit_blur)
            r = (vals - I) * wts
            cost = (r * r).sum(axis=1)
            Jw = J * wts[:, None]
            if not fit_blur:
                Jw[:, 10:] = 0.0
                J[:, 10:] = 0.0
            A = np.matmul(Jw, J.transpose(0, 2, 1))
        b = np.matmul(Jw, r[..., None])[..., 0]
        diag = np.einsum("cii->ci", A)
        A_d = A + lam[:, None, None] * diag[:, :, None] * eye12 + 1e-9 * eye12
        A_d[~valid] = eye12
        b[~valid] = 0.0
        dp = _solve(A_d, b)
        g_n, lev_n = g + dp[:, :8], lev + dp[:, 8:10]
        s_n = s if not fit_blur else np.minimum(np.maximum(s + dp[:, 10:12], 0.03), 0.8)
        I_n, _ = _model(g_n, lev_n, s_n, xs, ys, bits_in, bits_t, n_max, jacobian=False)
        r_n = (vals - I_n) * wts
        cost_n = (r_n * r_n).sum(axis=1)
        better = (cost_n <= cost) & np.isfinite(cost_n)
        g[better], lev[better], s[better] = g_n[better], lev_n[better], s_n[better]
        r[better], cost[better] = r_n[better], cost_n[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-6), lam * 5.0)
    # covariance of the parameters from the last Jacobian and the final residuals
    sig2 = cost / np.maximum(cnt - 12.0, 1.0)
    margin, cell_a, cell_bits = _cell_margins(g, lev, s, xs, ys, vals, wts, bits_pad, ns)
    tol_cells = np.broadcast_to(np.asarray(tolerable_cells, np.int64), (C,))
    cells_ok, cells_wrong, cells_undecided, cells_sep = cell_verdicts(cell_a, cell_bits,
                                                                      tol_cells)
    A = A + 1e-9 * eye12
    A[~valid] = eye12
    try:
        cov_p = np.linalg.inv(A) * sig2[:, None, None]
    except np.linalg.LinAlgError:
        cov_p = np.zeros((C, 12, 12))
        for c in range(C):
            try:
                cov_p[c] = np.linalg.inv(A[c]) * sig2[c]
            except np.linalg.LinAlgError:
                cov_p[c] = np.eye(12) * 1e6
    # corners p = G⁻¹(cell corners) in local coordinates and, analytically, d p / d g:
    # d p~ / d g_j = -G⁻¹ (dG/dg_j) p~ with dG/dg_j the single entry (a_j, b_j)
    Hinv = _inv3(_g_to_mat(g))
    uvh = np.zeros((C, 4, 3))
    uvh[:, :, 2] = 1.0
    uvh[:, 1, 0] = uvh[:, 2, 0] = uvh[:, 2, 1] = uvh[:, 3, 1] = nf
    ph = np.einsum("cij,ckj->cki", Hinv, uvh)  # (C, 4, 3) homogeneous local corners
    loc = ph[..., :2] / ph[..., 2:3]
    a_idx = np.array([0, 0, 0, 1, 1, 1, 2, 2])
    b_idx = np.array([0, 1, 2, 0, 1, 2, 0, 1])
    dph = -Hinv[:, None, :, a_idx] * ph[:, :, None, b_idx]  # (C, 4, 3, 8)
    dloc = (dph[:, :, :2] - loc[:, :, :, None] * dph[:, :, 2:3]) / ph[:, :, 2, None, None]
    xn_c = centre[:, None] + scale[:, None, None] * loc  # (C, 4, 2) normalised corners
    h = 1e-7
    pts = np.concatenate([xn_c, xn_c + [h, 0], xn_c + [0, h]], axis=1).reshape(-1, 2)
    pj = camera.project(np.concatenate([pts, np.ones((len(pts), 1))], axis=1)).reshape(C, 3,
                                                                                     4, 2)
    px_c = pj[:, 0]
    Jc = np.stack([(pj[:, 1] - px_c) / h, (pj[:, 2] - px_c) / h], axis=3)  # (C, 4, 2, 2)
    dpx = (Jc @ dloc * scale[:, None, None, None]).reshape(C, 8, 8)  # d px / d g
    cov_px = dpx @ cov_p[:, :8, :8] @ dpx.transpose(0, 2, 1)
    contrast = lev[:, 1] - lev[:, 0]
    resid = np.sqrt(sig2)
    blur = np.sqrt(s[:, 0] * s[:, 1]) * cell_px
    moved = np.sqrt(((px_c - q) ** 2).sum(axis=2))  # (C, 4) how far each corner moved, px
    move_limit = _move_limits(moved, valid & np.isfinite(moved).all(axis=1), start_sigma_px,
                              cell_px)
    out: list[RefinedCode] = []
    for c in range(C):
        if not valid[c]:
            out.append(RefinedCode(q[c], np.full((4, 2), np.nan), np.eye(8), float("inf"),
                                   float("inf"), 0.0, 0.0, False, reasons[c]))
            continue
        ok, why = True, ""
        if not np.all(np.isfinite(px_c[c])):
            ok, why = False, "diverged"
        elif contrast[c] < 20:
            ok, why = False, f"low contrast ({contrast[c]:.0f})"
        elif resid[c] > 0.2 * contrast[c]:
            ok, why = False, f"poor fit (residual {resid[c]:.1f} for contrast {contrast[c]:.0f})"
        elif moved[c].max() > move_limit[c]:
            ok, why = False, (f"a corner moved {moved[c].max():.1f} px from its start (limit "
                              f"{move_limit[c]:.1f} px at the start noise of this frame)")
        elif blur[c] > 2.5 * cell_px[c]:
            ok, why = False, "too blurred"
        else:
            if not cells_ok[c]:
                ok, why = False, (f"cells do not read as the code ({cells_wrong[c]} wrong, "
                                  f"{cells_undecided[c]} undecided, classes {cells_sep[c]:.1f} "
                                  "spreads apart)")
        sig = float(np.sqrt(max(np.trace(cov_px[c]), 0.0) / 8))
        out.append(RefinedCode(px_c[c], xn_c[c], cov_px[c], sig, float(resid[c]),
                               float(contrast[c]), float(blur[c]), ok, why,
                               float(margin[c])))
    return out
