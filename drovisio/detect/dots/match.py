"""Matching stage of the dot detector: which blobs are which dots of which brick.

The thesis tried every combination of n blobs (lines of equidistant dots, then pairs of
lines): 60 blobs and n = 3 already make 34 220 triples per colour set. Here every hypothesis
starts from *two nearby blobs* and uses what a single blob already says:

* a dot is a circle of known diameter, so its blob's ellipse gives the local scale and
  foreshortening of the brick's plane (the image of a circle under a local affine map A is an
  ellipse with covariance (r²/4)·A·Aᵀ; A is known up to an in-plane turn);
* the pair (blob i → dot a, blob j → dot b) fixes that turn; the distance between the blobs,
  measured in the ellipse's metric, must equal the distance between the dots (the ratio test),
  and the colours must agree;
* the local affine map then predicts where every other dot of the layout should be; the
  hypothesis scores the dots found there (right colour, within a tolerance).

Seeds are each blob's few nearest neighbours, candidates each blob's k nearest blobs, so the
work grows with the number of blobs (linearly with bricks in view), and it is done for all
hypotheses at once with numpy. Any planar layout of four or more dots works (not only two
lines); the layout's symmetry (``rot180_z``) is used to skip hypotheses that only relabel
another one. :func:`assign_greedy` then gives blobs to the best hypotheses first; poses are
checked later (:mod:`drovisio.pose.batch`, :mod:`.dots`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drovisio import _numba
from drovisio.detect.dots import match_kernels as _k
from drovisio.detect.dots.model import DotModel

__all__ = [
    "BlobGeometry",
    "Candidate",
    "Hypotheses",
    "assign_greedy",
    "generate_hypotheses",
]


@dataclass
class Hypotheses:
    """Scored hypotheses of one model (arrays, one row per hypothesis).

    Attributes:
        model: The layout model.
        assign: (H, N) blob index of each dot (-1: none found).
        score: (H,) higher is better (dots found, then closeness).
        scale: (H,) image size of the layout's smallest spacing (normalised units).
        affine: (H, 2, 2) local affine map plane → image of the hypothesis.
        origin: (H, 2) image point of the plane origin under that map.
    """

    model: DotModel
    assign: np.ndarray
    score: np.ndarray
    scale: np.ndarray
    affine: np.ndarray
    origin: np.ndarray

    @staticmethod
    def empty(model: DotModel) -> Hypotheses:
        return Hypotheses(model, np.zeros((0, model.n), np.int64), np.zeros(0), np.zeros(0),
                          np.zeros((0, 2, 2)), np.zeros((0, 2)))


def _sqrt_2x2(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Square roots and inverse square roots of SPD 2×2 matrices (n, 2, 2)."""
    c00, c01, c11 = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
    s = np.sqrt(np.maximum(c00 * c11 - c01 * c01, 1e-300))
    tt = np.sqrt(np.maximum(c00 + c11 + 2 * s, 1e-300))
    S = np.empty_like(C)
    S[:, 0, 0] = (c00 + s) / tt
    S[:, 1, 1] = (c11 + s) / tt
    S[:, 0, 1] = S[:, 1, 0] = c01 / tt
    # inverse: adj(S) / det(S), det(S) = sqrt(det C)
    Si = np.empty_like(C)
    Si[:, 0, 0] = S[:, 1, 1] / s
    Si[:, 1, 1] = S[:, 0, 0] / s
    Si[:, 0, 1] = Si[:, 1, 0] = -S[:, 0, 1] / s
    return S, Si


@dataclass
class BlobGeometry:
    """Per-frame blob data the matcher needs (shared by all layouts).

    Attributes:
        q: (M, 2) centres, normalised image coordinates.
        S, Si: (M, 2, 2) square root of each blob's second-moment matrix and its inverse.
        semi_major: (M,) major semi-axis, normalised units.
        color: (M,) colour index.
        usable: (M,) may be used.
    """

    q: np.ndarray
    S: np.ndarray
    Si: np.ndarray
    semi_major: np.ndarray
    color: np.ndarray
    usable: np.ndarray

    @classmethod
    def build(cls, q: np.ndarray, cov: np.ndarray, color: np.ndarray, usable: np.ndarray
              ) -> BlobGeometry:
        S, Si = _sqrt_2x2(cov)
        tr = cov[:, 0, 0] + cov[:, 1, 1]
        det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
        lmax = tr / 2 + np.sqrt(np.maximum(tr * tr / 4 - det, 0))
        return cls(q=q, S=S, Si=Si, semi_major=2 * np.sqrt(lmax), color=color, usable=usable)


def _hypotheses_compiled(model: DotModel, geo: BlobGeometry, idx: np.ndarray,
                         seeds_per_blob: int, ratio_tol: float, match_tol: float,
                         min_dots: int, orientation: float) -> Hypotheses:
    """:func:`generate_hypotheses` by the compiled kernel, on the usable blobs ``idx``."""
    assign, score, scale, A, origin = _k.hypotheses(
        geo.q[idx], geo.color[idx], geo.S[idx], geo.Si[idx], geo.semi_major[idx],
        model.pairs, model.pair_color_match, model.pair_len, model.pair_vec,
        model.pair_mid, model.pair_ra_half, model.pair_rb_half, model.pair_ia,
        model.pair_ib, model.P, model.colors, float(model.min_spacing),
        float(model.reach_per_semi_axis), int(seeds_per_blob), float(ratio_tol),
        float(match_tol), int(min_dots), float(orientation))
    if score.size == 0:
        return Hypotheses.empty(model)
    sel = np.argsort(-score, kind="stable")
    assign = assign[sel]
    assign = np.where(assign >= 0, idx[np.maximum(assign, 0)], -1)
    return Hypotheses(model, assign, score[sel], scale[sel], A[sel], origin[sel])


def _local_affine(model: DotModel, S: np.ndarray, i: np.ndarray, j: np.ndarray,
                  hp: np.ndarray, f: np.ndarray, orientation: float) -> np.ndarray:
    """(H, 2, 2) local affine map A (plane → normalised image) of each seed: blob i on the
    first dot of layout pair ``hp``, blob j on the second, ``f`` (H, 2) = q_j − q_i; A·e = f
    with e the pair's plane vector, A = S̄·Q·s (S: (M, 2, 2) square roots of the blobs'
    second moments)."""
    e, le = model.pair_vec[hp], model.pair_len[hp]
    Sbar = S[i] * model.pair_ia[hp][:, None, None] + S[j] * model.pair_ib[hp][:, None, None]
    s00, s01, s11 = Sbar[:, 0, 0], Sbar[:, 0, 1], Sbar[:, 1, 1]
    dS = s00 * s11 - s01 * s01
    g0 = (s11 * f[:, 0] - s01 * f[:, 1]) / dS                 # g = S̄⁻¹·f
    g1 = (s00 * f[:, 1] - s01 * f[:, 0]) / dS
    lg = np.sqrt(g0 * g0 + g1 * g1)
    e0, e1 = e[:, 0] / le, e[:, 1] / le
    h0, h1 = g0 / lg, g1 / lg
    Q = np.empty_like(Sbar)
    if orientation < 0:   # reflection taking ê to ĝ
        c2 = e0 * h0 - e1 * h1
        s2 = e0 * h1 + e1 * h0
        Q[:, 0, 0], Q[:, 0, 1], Q[:, 1, 0], Q[:, 1, 1] = c2, s2, s2, -c2
    else:                 # rotation taking ê to ĝ
        c1 = e0 * h0 + e1 * h1
        s1 = e0 * h1 - e1 * h0
        Q[:, 0, 0], Q[:, 0, 1], Q[:, 1, 0], Q[:, 1, 1] = c1, -s1, s1, c1
    return (Sbar @ Q) * (lg / le)[:, None, None]


def generate_hypotheses(model: DotModel, geo: BlobGeometry, seeds_per_blob: int = 4,
                        ratio_tol: float = 1.5, match_tol: float = 0.3, min_dots: int = 4,
                        orientation: float = -1.0) -> Hypotheses:
    """All pair-seeded hypotheses for one layout, scored (vectorised).

    Args:
        model: The layout.
        geo: The frame's blobs (:class:`BlobGeometry`).
        seeds_per_blob: Nearest usable neighbours of each blob tried as its pair.
        ratio_tol: Largest factor between the blob distance in the ellipse's metric and the
            dot distance.
        match_tol: Tolerance of a predicted dot position, in units of the hypothesis' smallest
            dot spacing.
        min_dots: Fewest dots a hypothesis must find.
        orientation: Sign of the determinant of the plane → image map for a face seen from
            its front (-1 for OpenCV's camera frame with plane axes u × v = normal).

    Returns:
        Hypotheses with at least ``min_dots`` dots found, best first.
    """
    N = model.n
    idx = np.flatnonzero(model.color_ok[geo.color] & geo.usable)
    M = idx.size
    if M < min_dots:
        return Hypotheses.empty(model)
    if _numba.enabled():
        return _hypotheses_compiled(model, geo, idx, seeds_per_blob, ratio_tol, match_tol,
                                    min_dots, orientation)
    qq, col = geo.q[idx], geo.color[idx]
    S, Si = geo.S[idx], geo.Si[idx]
    reach = geo.semi_major[idx] * model.reach_per_semi_axis
    diff = qq[:, None, :] - qq[None, :, :]
    D2 = (diff * diff).sum(axis=2)
    D2.flat[::M + 1] = np.inf
    K = min(M - 1, N + 3)
    order = np.argsort(D2, axis=1)[:, :K]                     # (M, K) nearest blobs
    near = D2[np.arange(M)[:, None], order] <= (reach * reach)[:, None]
    # ---- seed pairs: each blob with its nearest few (within reach), layout pairs by colour
    ks = min(seeds_per_blob, K)
    okp = near[:, :ks].ravel()
    si = np.repeat(np.arange(M), ks)[okp]
    sj = order[:, :ks].ravel()[okp]
    # (i, j) and (j, i) give the same hypotheses (the layout's pairs come in both orders)
    key = np.unique(np.minimum(si, sj) * M + np.maximum(si, sj))
    si, sj = key // M, key % M
    hs, hp = np.nonzero(model.pair_color_match[col[si], col[sj]])
    if hs.size == 0:
        return Hypotheses.empty(model)
    i, j = si[hs], sj[hs]
    a, b = model.pairs[hp, 0], model.pairs[hp, 1]
    le = model.pair_len[hp]
    f = qq[j] - qq[i]                                         # (H, 2) image
    # distance in each ellipse's metric: (r/2)·Σ^{-1/2}·f has the length of e
    fc = f[:, :, None]
    gi = (Si[i] @ fc)[:, :, 0]
    gj = (Si[j] @ fc)[:, :, 0]
    ri = np.sqrt((gi * gi).sum(axis=1)) * model.pair_ra_half[hp] / le
    rj = np.sqrt((gj * gj).sum(axis=1)) * model.pair_rb_half[hp] / le
    lo = 1.0 / ratio_tol
    keep = np.flatnonzero((ri < ratio_tol) & (ri > lo) & (rj < ratio_tol) & (rj > lo))
    if keep.size == 0:
        return Hypotheses.empty(model)
    i, j, a, b, hp, f = i[keep], j[keep], a[keep], b[keep], hp[keep], f[keep]
    A = _local_affine(model, S, i, j, hp, f, orientation)
    origin = 0.5 * (qq[i] + qq[j]) - (A @ model.pair_mid[hp][:, :, None])[:, :, 0]
    pred = origin[:, None, :] + model.P[None, :, :] @ A.transpose(0, 2, 1)   # (H, N, 2)
    # smallest singular value of A × smallest dot spacing → position tolerance
    ata = A.transpose(0, 2, 1) @ A
    tr = ata[:, 0, 0] + ata[:, 1, 1]
    dt = ata[:, 0, 0] * ata[:, 1, 1] - ata[:, 0, 1] ** 2
    sv_min = np.sqrt(np.maximum(tr / 2 - np.sqrt(np.maximum(tr * tr / 4 - dt, 0)), 0))
    scale = sv_min * model.min_spacing
    tol2 = (match_tol * scale) ** 2
    # ---- look for each dot among the nearest blobs of the seed (and the seed itself)
    cand = np.concatenate([i[:, None], order[i]], axis=1)    # (H, K+1)
    cand_ok = np.concatenate([np.ones((i.size, 1), bool), near[i]], axis=1)
    dq = pred[:, :, None, :] - qq[cand][:, None, :, :]        # (H, N, K+1, 2)
    dist2 = (dq * dq).sum(axis=3)
    right = (col[cand][:, None, :] == model.colors[None, :, None]) & cand_ok[:, None, :]
    dist2[~right] = np.inf
    best = dist2.argmin(axis=2)                               # (H, N)
    H = i.size
    rows = np.arange(H)[:, None]
    bd = dist2[rows, np.arange(N)[None, :], best]
    found = bd <= tol2[:, None]
    assign = np.where(found, cand[rows, best], -1)
    r1 = np.arange(H)
    assign[r1, a] = i
    assign[r1, b] = j
    found[r1, a] = True
    found[r1, b] = True
    count = found.sum(axis=1)
    close = np.where(found, np.sqrt(bd / tol2[:, None]), 0.0)
    close[r1, a] = 0.0
    close[r1, b] = 0.0
    score = count - 0.5 * close.sum(axis=1) / np.maximum(count - 2, 1)
    sel = np.flatnonzero(count >= min_dots)
    if sel.size == 0:
        return Hypotheses.empty(model)
    sel = sel[np.argsort(-score[sel], kind="stable")]
    assign = assign[sel]
    assign = np.where(assign >= 0, idx[np.maximum(assign, 0)], -1)
    return Hypotheses(model, assign, score[sel], scale[sel], A[sel], origin[sel])


@dataclass
class Candidate:
    """A brick candidate: one layout, the blob of each of its dots (-1 = not found)."""

    model: DotModel
    assign: np.ndarray
    score: float
    scale: float


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """A well-mixed 64-bit hash of each element (sums of these identify sets of blobs)."""
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def assign_greedy(hyps: list[Hypotheses], n_blobs: int, min_dots: int = 4,
                  taken: np.ndarray | None = None) -> list[Candidate]:
    """Give blobs to hypotheses, best first; a blob belongs to at most one brick.

    Hypotheses of all layouts compete on their score. Many hypotheses describe the same brick
    (every seed pair of its dots): rows with the same (layout, set of blobs) are merged first
    (by a sum of well-mixed 64-bit hashes of its blobs; the best scored is kept). Then, in
    rounds, every row that no better row still in play competes with for a blob is accepted
    (the same result as taking rows one by one, best first), and rows left with fewer than
    ``min_dots`` free blobs drop out. A hypothesis keeps the dots whose blobs are still free
    (a blob met twice in one hypothesis goes to its first dot).

    Args:
        hyps: Hypotheses of each layout (best first within each).
        n_blobs: Number of blobs (indices in ``assign`` are below it).
        min_dots: Fewest dots per brick.
        taken: Blobs already used (updated in place).
    """
    taken = np.zeros(n_blobs, bool) if taken is None else taken
    hyps = [h for h in hyps if h.assign.shape[0]]
    if not hyps:
        return []
    W = max(h.model.n for h in hyps)
    A, scores, which, row = _stacked(hyps, W)
    order = np.argsort(-scores, kind="stable")

    def candidate(o: int, r: np.ndarray) -> Candidate:
        h = hyps[int(which[o])]
        return Candidate(h.model, r[:h.model.n], float(scores[o]), float(h.scale[int(row[o])]))

    if _numba.enabled():
        A = np.ascontiguousarray(A[order])
        acc, rows_a = _k.assign_greedy(A, int(min_dots), taken)
        return [candidate(int(order[k]), r) for k, r in zip(acc.tolist(), rows_a)]
    if order.size > 64:     # many rows: merge duplicates first (few rows: the rounds do it)
        order = _unique_rows(A, order, which, n_blobs)
    A = A[order].copy()
    _first_dot_keeps(A, W)
    out: list[Candidate] = []
    # rounds of "locally best" rows: a row is accepted when no better row still in play uses
    # any of its free blobs; rows left with too few free blobs drop out
    while A.shape[0]:
        free = (A >= 0) & ~taken[np.maximum(A, 0)]
        ok = free.sum(axis=1) >= min_dots
        if not ok.all():
            A, order, free = A[ok], order[ok], free[ok]
            if A.shape[0] == 0:
                break
        owner = np.full(n_blobs, A.shape[0], np.int64)
        rows_of = np.broadcast_to(np.arange(A.shape[0])[:, None], A.shape)
        np.minimum.at(owner, A[free], rows_of[free])
        best = np.where(free, owner[np.maximum(A, 0)], np.arange(A.shape[0])[:, None])
        win = (best == np.arange(A.shape[0])[:, None]).all(axis=1)
        for k in np.flatnonzero(win).tolist():
            r = np.where(free[k], A[k], -1)
            taken[r[r >= 0]] = True
            out.append(candidate(int(order[k]), r))
        keep = ~win
        A, order = A[keep], order[keep]
    return out


def _stacked(hyps: list[Hypotheses], W: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All hypotheses' rows as one (rows, W) assignment (padded with -1), their scores, the
    hypotheses each came from and its row there."""
    if len(hyps) == 1:
        A = hyps[0].assign
        return A, hyps[0].score, np.zeros(A.shape[0], np.int64), np.arange(A.shape[0])
    A = np.concatenate([np.pad(h.assign, ((0, 0), (0, W - h.model.n)), constant_values=-1)
                        for h in hyps])
    scores = np.concatenate([h.score for h in hyps])
    which = np.concatenate([np.full(h.score.size, k) for k, h in enumerate(hyps)])
    row = np.concatenate([np.arange(h.score.size) for h in hyps])
    return A, scores, which, row


def _unique_rows(A: np.ndarray, order: np.ndarray, which: np.ndarray, n_blobs: int
                 ) -> np.ndarray:
    """``order`` without the rows that repeat a better row's (layout, set of blobs)."""
    with np.errstate(over="ignore"):
        hv = _splitmix64(np.arange(n_blobs, dtype=np.uint64))
        key = np.where(A >= 0, hv[np.maximum(A, 0)], np.uint64(0)).sum(axis=1) \
            + _splitmix64(which.astype(np.uint64) + np.uint64(1 << 40))
    _, first = np.unique(key[order], return_index=True)
    return order[np.sort(first)]


def _first_dot_keeps(A: np.ndarray, W: int) -> None:
    """One blob for two dots of a row: the first dot keeps it (A changed in place)."""
    srt = np.sort(np.where(A >= 0, A, -np.arange(1, W + 1)[None, :]), axis=1)
    dup_rows = np.flatnonzero((srt[:, 1:] == srt[:, :-1]).any(axis=1))
    for rr in dup_rows.tolist():
        seen: set[int] = set()
        for d, bl in enumerate(A[rr].tolist()):
            if bl >= 0:
                if bl in seen:
                    A[rr, d] = -1
                seen.add(bl)
