"""Whether a fitted code's cells read back as its bits: the check that refuses decoys.

At the fitted geometry and blur, every inner cell's whiteness is estimated by linear least
squares (a deblurred read-back, :func:`cell_margins`); the cells are then judged by the code's
own two brightness classes (:func:`cell_verdicts`: real JPEGs read cells at 0.7 / 0.3 that
still lie 15+ spreads apart).
"""

from __future__ import annotations

import functools
from statistics import NormalDist

import numpy as np

from drovisio.detect.corners.model import (
    code_coords,
    correlation_terms,
    phi_and_density,
    solve_batched,
)

__all__ = ["cell_margins", "cell_verdict", "cell_verdicts"]


def cell_margins(g: np.ndarray, lev: np.ndarray, s: np.ndarray, x: np.ndarray, y: np.ndarray,
                 vals: np.ndarray, wts: np.ndarray, bits: np.ndarray, ns: np.ndarray,
                 rho: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per code, how clearly its inner cells read as its bits (see RefinedCode.cell_margin).

    At the fitted geometry and blur, each inner cell's whiteness a_k is estimated by linear
    least squares, (I - B)/(W - B) = sum_k a_k box_k(u, v), with a weak pull toward the
    expected bit (cells no sample sees keep it). ``box_k`` is cell k blurred as the fit
    blurs it: ``row_r(v) col_j(u)``, plus the terms in the blur's correlation ``rho`` (C,)
    when given (:func:`.model.model`), so that an oblique code's cells are read with the
    blur that was fitted to them.

    Returns:
        (margin (C,): the least signed margin, a - 0.5 for white cells and 0.5 - a for black
        ones; a (C, cells): every cell's whiteness, NaN beyond a code's own size (codes
        padded to a larger n); the expected bits (C, cells), 1 = white).
    """
    C, n = bits.shape[0], bits.shape[1]
    u64, v64, _ = code_coords(g, x, y)
    u, v = u64.astype(np.float32), v64.astype(np.float32)
    k = np.arange(1, n, dtype=np.float32)[:, None]  # the boundaries of the inner cells
    inv_s = (1.0 / s).astype(np.float32)
    zu = (u[:, None, :] - k) * inv_s[:, 0, None, None]
    zv = (v[:, None, :] - k) * inv_s[:, 1, None, None]
    (Au, pu), (Av, pv) = phi_and_density(zu), phi_and_density(zv)
    w32 = wts[:, None, :].astype(np.float32)
    col = Au[:, :-1] - Au[:, 1:]  # (C, n-2, M) inner columns
    row = (Av[:, :-1] - Av[:, 1:]) * w32  # weights 0/1
    m = n - 2
    basis = (row[:, :, None, :] * col[:, None, :, :]).reshape(C, m * m, -1)  # (C, cells, M)
    if rho is not None and np.any(rho != 0):
        r = rho.astype(np.float32)[:, None, None, None]
        d1u, d2u = correlation_terms(zu, pu)
        d1v, d2v = correlation_terms(zv, pv)
        basis += (r * (d1v * w32)[:, :, None, :] * d1u[:, None, :, :]).reshape(C, m * m, -1)
        basis += (0.5 * r * r * (d2v * w32)[:, :, None, :] * d2u[:, None, :, :]
                  ).reshape(C, m * m, -1)
    amp = lev[:, 1] - lev[:, 0]
    yv = ((vals - lev[:, 0, None]) / np.where(np.abs(amp) > 1e-9, amp, 1.0)[:, None]
          ).astype(np.float32)
    A = np.matmul(basis, basis.transpose(0, 2, 1)).astype(np.float64)
    expected = bits[:, 1:-1, 1:-1].reshape(C, m * m).astype(np.float64)
    mu = 0.05 * (A.trace(axis1=1, axis2=2) / (m * m))[:, None] + 1e-9
    rhs = np.matmul(basis, yv[..., None])[..., 0].astype(np.float64) + mu * expected
    A = A + mu[:, :, None] * np.eye(m * m)
    a = solve_batched(A, rhs)
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
    (whiteness ``a`` from the deblurred fit, :func:`cell_margins`); their centres (medians)
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
    ok, wrong, undecided, sep, _ = cell_verdicts(np.asarray(a, np.float64)[None],
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
    return NormalDist().inv_cdf(1.0 - false_rate / (2.0 * max(cells, 1)))


def cell_verdicts(a: np.ndarray, expected: np.ndarray, tolerable: np.ndarray,
                  false_rate: float = 0.01
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cell_verdict` for C codes at once: ``a`` and ``expected`` (C, cells), NaN
    where a cell is not the code's; ``tolerable`` (C,). Returns (accepted, wrong, undecided,
    separation, spread), each (C,); spread: the classes' common spread of whiteness."""
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
    return ok, wrong, undecided, sep, spread
