"""The code fit itself: :func:`refine_codes`, its stages in order on a batch of codes.

1. the codes' bits padded to one size, and the starts' local frame and homography,
2. each code's fit region and the box of pixels around it,
3. the samples (:mod:`.samples`),
4. the start levels,
5. the Levenberg–Marquardt fit of (G, B, W, s_u, s_v, rho) (:mod:`.model`),
6. the parameters' covariance, from the fit's own residuals (:mod:`.covariance`),
7. the outer corners and their covariance in pixels,
8. the checks that keep or refuse each code (fit, contrast, blur, how far a corner moved,
   the cells read back: :mod:`.cells`),
9. the kept codes refitted with their outer edges where uniform paper surrounds them
   (:mod:`.outer`), their covariance holding the two fits' disagreement,
10. codes refused only because a corner moved far kept at their outer edge lines
   (:mod:`.edges`) where their cells read right there (optional).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drovisio.camera import Camera
from drovisio.detect.corners.cells import cell_margins, cell_verdicts
from drovisio.detect.corners.covariance import parameter_covariance
from drovisio.detect.corners.edges import edge_line_fallback
from drovisio.detect.corners.model import (
    g_to_matrix,
    homographies,
    inverse_3x3,
    model,
    solve_batched,
)
from drovisio.detect.corners.outer import Interior, fit_outer
from drovisio.detect.corners.samples import (
    grid_lookup,
    normalized_grid,
    pixel_boxes,
    select_samples,
)

__all__ = ["MAX_SAMPLES", "RefinedCode", "refine_codes"]

#: samples (pixels) per code in the fit; bigger codes are subsampled on a regular grid
MAX_SAMPLES = 280

#: the largest blur correlation fitted (the series of the bivariate normal is kept to rho²)
RHO_MAX = 0.6


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
    surround: bool = False
    """The corners come from the refit with the code's outer edges against a uniform paper
    surround (:mod:`.outer`), not from the interior alone."""
    edge_lines: bool = False
    """The corners are where the code's outer edge lines meet (:mod:`.edges`): its interior,
    extrapolated, placed a corner far from its border, and its cells read right at the
    edges' corners. Their covariance holds the two readings' disagreement."""


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


@dataclass
class _Batch:
    """The codes of one frame as the fit sees them (C codes, the largest n_max cells wide).

    ``valid`` and ``reasons`` change as the stages refuse codes; ``g`` is the homography the
    fit moves.
    """

    q: np.ndarray
    """(C, 4, 2) start corners, px."""
    valid: np.ndarray
    """(C,) bool: still fitted."""
    reasons: list[str]
    """Per code, why it is no longer fitted (empty while valid)."""
    ns: np.ndarray
    """(C,) int64 cells per side, border included."""
    nf: np.ndarray
    """(C,) the same as float64."""
    n_max: int
    bits_pad: np.ndarray
    """(C, n_max, n_max) float64 cells with border, 1 = white, zero-padded."""
    cell_px: np.ndarray
    """(C,) mean cell width at the start, px."""
    centre: np.ndarray
    """(C, 2) centre of the start corners, normalised coordinates: the local frame's origin."""
    scale: np.ndarray
    """(C,) the local frame's unit (a cell at the start), normalised coordinates."""
    g: np.ndarray
    """(C, 8) homography from the local frame to the code plane in cells."""


@dataclass
class _Region:
    """The pixels each code's fit may use: the fit region in cells and its box in the image."""

    lo: np.ndarray
    hi: np.ndarray
    """(C,) the fit region [lo, hi]², cells."""
    band: np.ndarray
    """(C,) how far from a modelled edge a sample may lie, cells."""
    x0: np.ndarray
    y0: np.ndarray
    bw: np.ndarray
    """(C,) int64 the box's top-left pixel and width."""
    P_box: np.ndarray
    """(C,) pixels of each box (0 for codes not fitted)."""
    P: np.ndarray
    """(C,) candidates drawn per box (min(P_box, K))."""
    K: int
    """Candidates per big box."""


@dataclass
class _Samples:
    xs: np.ndarray
    ys: np.ndarray
    """(C, M) the samples' local coordinates."""
    vals: np.ndarray
    """(C, M) their grey levels."""
    wts: np.ndarray
    """(C, M) 1 where a sample is (0: padding or a code no longer fitted)."""
    cnt: np.ndarray
    """(C,) float64 samples per code."""


@dataclass
class _Fit:
    """The fitted parameters and what the covariance needs."""

    lev: np.ndarray
    """(C, 2) black and white levels, grey levels."""
    s: np.ndarray
    """(C, 2) blur along u and v, cells."""
    rho: np.ndarray
    """(C,) the blur's correlation of u and v."""
    cost: np.ndarray
    """(C,) sum of squared residuals."""
    A: np.ndarray
    """(C, 13, 13) the last Gauss–Newton matrix JᵀJ."""
    Jw: np.ndarray
    """(C, 13, M) its transposed Jacobian (zero where no sample is)."""
    r: np.ndarray
    """(C, M) the residuals at the solution (zero where no sample is)."""


def _batch(grid: np.ndarray, corners: list[np.ndarray] | np.ndarray, bits: list[np.ndarray]
           ) -> _Batch:
    """Stage 1: the codes' bits padded to one size, and the starts: corners, local frame and
    homography to the cells."""
    C = len(corners)
    ns = np.array([b.shape[0] for b in bits], np.int64)
    n_max = int(ns.max())
    bits_pad = np.zeros((C, n_max, n_max))
    for c in range(C):
        bits_pad[c, :ns[c], :ns[c]] = bits[c]
    q = np.asarray(corners, np.float64).reshape(C, 4, 2)
    qn = grid_lookup(grid, q.reshape(-1, 2)).reshape(C, 4, 2)
    valid = np.isfinite(qn).all(axis=(1, 2))
    reasons = ["" if ok else "corners outside the calibrated field" for ok in valid]
    qn = np.where(valid[:, None, None], qn, 0.0)
    q = np.where(valid[:, None, None], q, 0.0)   # refused: its numbers stay harmless
    nf = ns.astype(np.float64)
    prev = [3, 0, 1, 2]  # each corner's predecessor (np.roll is slow on small arrays)
    dq = q - q[:, prev]
    side_px = np.sqrt((dq * dq).sum(axis=2))
    cell_px = np.where(valid, side_px.sum(axis=1) / (4.0 * nf), 1.0)
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
    g = homographies(loc, uv_c)
    return _Batch(q, valid, reasons, ns, nf, n_max, bits_pad, cell_px, centre, scale, g)


def _region(b: _Batch, shape: tuple[int, ...], band_px: float, max_samples: int) -> _Region:
    """Stage 2: each code's fit region and the box of pixels around it; codes whose box is
    under 4 px are refused."""
    cell_px, nf = b.cell_px, b.nf
    # fit region: inside the border's outer side by >= 3 px, never beyond the inner bits
    a = np.minimum(np.maximum((cell_px - 3.0) / np.maximum(cell_px, 1e-9), 0.0), 0.6)
    lo, hi = 1.0 - a, nf - 1.0 + a
    band = np.minimum(band_px / np.maximum(cell_px, 1e-9), 0.5)
    # every pixel of the bounding box of each code's fit region (its quad shrunk about the
    # centre to the region), flattened with its code index
    x0, y0, bw, bh = pixel_boxes(b.q, (hi - lo) / nf, shape)
    small = (bw < 4) | (bh < 4)
    for c in np.nonzero(small & b.valid)[0]:
        b.reasons[c] = "too small"
    b.valid &= ~small
    P_box = np.where(b.valid, bw * bh, 0)
    # big codes: a random subset of their box (random: a regular stride would alias with the
    # edges), about 4 candidates per sample kept
    K = 8 * max_samples
    P = np.minimum(P_box, K)
    return _Region(lo, hi, band, x0, y0, bw, P_box, P, K)


def _samples(grid: np.ndarray, gray: np.ndarray, b: _Batch, r: _Region, max_samples: int
             ) -> _Samples:
    """Stage 3: the pixels each code's fit uses (:func:`.samples.select_samples`); codes with
    fewer than 24 are refused."""
    xs, ys, vals, wts, cnt = select_samples(grid, gray, r.x0, r.y0, r.bw, r.P, r.P_box, r.K,
                                            b.centre, b.scale, b.g, r.lo, r.hi, r.band, b.ns,
                                            b.bits_pad, max_samples)
    cnt = cnt.astype(np.float64)
    few = b.valid & (cnt < 24)
    for c in np.nonzero(few)[0]:
        b.reasons[c] = "too few pixels"
    b.valid &= ~few
    wts[~b.valid] = 0.0
    return _Samples(xs, ys, vals, wts, cnt)


def _start_levels(smp: _Samples) -> np.ndarray:
    """Stage 4: the black and white levels (C, 2) to start from, from the samples'
    distribution (5 % and 95 % quantiles)."""
    C = len(smp.cnt)
    srt = np.sort(np.where(smp.wts > 0, smp.vals, np.inf), axis=1)
    m_i = np.maximum(smp.cnt.astype(np.int64), 1)
    lev = np.stack([srt[np.arange(C), (0.05 * (m_i - 1)).astype(np.int64)],
                    srt[np.arange(C), (0.95 * (m_i - 1)).astype(np.int64)]], axis=1)
    lev[~np.isfinite(lev)] = 0.0
    return lev


@dataclass
class _Step:
    """A Gauss–Newton linearisation, kept for the chord steps that reuse it."""

    r: np.ndarray
    """(C, M) weighted residuals at the current parameters."""
    cost: np.ndarray
    """(C,) their sum of squares."""
    Jw: np.ndarray
    """(C, 13, M) the weighted transposed Jacobian."""
    A: np.ndarray
    """(C, 13, 13) JᵀJ."""


def _linearise(b: _Batch, smp: _Samples, lev: np.ndarray, s: np.ndarray, rho: np.ndarray,
               bits_in: np.ndarray, bits_t: np.ndarray, fit_blur: bool) -> _Step:
    """The model's residuals and Jacobian at the current parameters (the blur's columns zero
    unless ``fit_blur``)."""
    I, J = model(b.g, lev, s, smp.xs, smp.ys, bits_in, bits_t, b.n_max, blur_jacobian=fit_blur,
                 rho=rho)
    assert J is not None  # asked for
    r = (smp.vals - I) * smp.wts
    cost = (r * r).sum(axis=1)
    Jw = J * smp.wts[:, None]
    if not fit_blur:
        Jw[:, 10:] = 0.0
        J[:, 10:] = 0.0
    return _Step(r, cost, Jw, np.matmul(Jw, J.transpose(0, 2, 1)))


def _levenberg_marquardt(b: _Batch, smp: _Samples, lev: np.ndarray, iterations: int,
                         coarse_iterations: int, chord_from: int | None, lm_lambda: float,
                         blur_iterations: int, coarse_min_cell_px: float) -> _Fit:
    """Stage 5: the fit of (G, B, W, s_u, s_v, rho), every code at once; ``b.g`` and ``lev`` are
    updated in place. Blur starts at ~0.9 px; the first ``coarse_iterations`` keep it wide
    (a wide basin of convergence)."""
    C, cell_px, valid = len(b.q), b.cell_px, b.valid
    g = b.g
    s = np.repeat((0.9 / np.maximum(cell_px, 1e-9))[:, None], 2, axis=1)
    rho = np.zeros(C)
    bits_in = np.ascontiguousarray(b.bits_pad[:, 1:-1, 1:-1], np.float32)
    bits_t = np.ascontiguousarray(bits_in.transpose(0, 2, 1))
    s_floor = np.minimum(1.5 / np.maximum(cell_px, 1e-9), 0.25)  # coarse start: wide basin
    lam = np.full(C, lm_lambda)
    eye = np.eye(13)
    step: _Step | None = None
    if not np.any(valid & (cell_px >= coarse_min_cell_px)):
        coarse_iterations = 0  # small codes only: their blur is wide enough already
    for it in range(iterations):
        coarse = it < coarse_iterations
        if coarse:
            s = np.maximum(s, s_floor[:, None])
        fresh = chord_from is None or it <= max(coarse_iterations, chord_from - 1)
        if fresh or step is None:  # new Jacobian; in between, its last value (chord steps)
            fit_blur = not coarse and it < blur_iterations
            step = _linearise(b, smp, lev, s, rho, bits_in, bits_t, fit_blur)
        r, cost, A = step.r, step.cost, step.A
        rhs = np.matmul(step.Jw, r[..., None])[..., 0]
        diag = np.einsum("cii->ci", A)
        A_d = A + lam[:, None, None] * diag[:, :, None] * eye + 1e-9 * eye
        A_d[~valid] = eye
        rhs[~valid] = 0.0
        dp = solve_batched(A_d, rhs)
        g_n, lev_n = g + dp[:, :8], lev + dp[:, 8:10]
        s_n = s if not fit_blur else np.minimum(np.maximum(s + dp[:, 10:12], 0.03), 0.8)
        rho_n = rho if not fit_blur else np.clip(rho + dp[:, 12], -RHO_MAX, RHO_MAX)
        I_n, _ = model(g_n, lev_n, s_n, smp.xs, smp.ys, bits_in, bits_t, b.n_max,
                       jacobian=False, rho=rho_n)
        r_n = (smp.vals - I_n) * smp.wts
        cost_n = (r_n * r_n).sum(axis=1)
        better = (cost_n <= cost) & np.isfinite(cost_n)
        g[better], lev[better], s[better] = g_n[better], lev_n[better], s_n[better]
        rho[better] = rho_n[better]
        r[better], cost[better] = r_n[better], cost_n[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-6), lam * 5.0)
    assert step is not None, "refine_codes needs at least one iteration"
    return _Fit(lev, s, rho, step.cost, step.A, step.Jw, step.r)


def _corners(b: _Batch, camera: Camera, cov_p: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 7: the outer corners ``G⁻¹((0,0), (n,0), (n,n), (0,n))`` and their covariance.

    Returns:
        (corners (C, 4, 2) px, the same (C, 4, 2) normalised, covariance (C, 8, 8) px²).
    """
    C, nf, centre, scale = len(b.q), b.nf, b.centre, b.scale
    # corners p = G⁻¹(cell corners) in local coordinates and, analytically, d p / d g:
    # d p~ / d g_j = -G⁻¹ (dG/dg_j) p~ with dG/dg_j the single entry (a_j, b_j)
    Hinv = inverse_3x3(g_to_matrix(b.g))
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
    return px_c, xn_c, cov_px


@dataclass
class _Checks:
    """What decides whether a fitted code is kept (each (C,))."""

    contrast: np.ndarray
    resid: np.ndarray
    blur: np.ndarray
    moved: np.ndarray
    """(C, 4) how far each corner moved from its start, px."""
    move_limit: np.ndarray
    cells_ok: np.ndarray
    cells_wrong: np.ndarray
    cells_undecided: np.ndarray
    cells_sep: np.ndarray
    cells_spread: np.ndarray
    """(C,) the cells' common spread of whiteness (fraction of the contrast)."""


#: a fit whose residual is this share of its contrast or more explains nothing of the code (the
#: model's black and white lie within a residual of each other). Below it the cells' verdict
#: and the corners' moves decide: a sharpened JPEG's halos, which no blurred model has, leave
#: 0.26 of the contrast on a code whose cells read 7.9 spreads apart (a limit of 0.2 refused it)
_MAX_RESIDUAL_SHARE = 0.5

#: an interior fit farther than this many cells from the code's edge lines went astray: it is
#: no bent view of the code (a rim, a bent print moves a corner about a cell)
_EDGE_MAX_DISAGREE_CELLS = 2.5


def _refusal(c: int, px_c: np.ndarray, cell_px: np.ndarray, k: _Checks,
             moved_too: bool = True) -> str:
    """Why code ``c``'s fit is refused, or ``""`` when it is kept (``moved_too``: False
    leaves out how far its corners moved, every other check still made)."""
    contrast, resid = k.contrast[c], k.resid[c]
    if not np.all(np.isfinite(px_c[c])):
        return "diverged"
    if contrast < 20:
        return f"low contrast ({contrast:.0f})"
    if resid > _MAX_RESIDUAL_SHARE * contrast:
        return f"poor fit (residual {resid:.1f} for contrast {contrast:.0f})"
    if moved_too and k.moved[c].max() > k.move_limit[c]:
        return (f"a corner moved {k.moved[c].max():.1f} px from its start (limit "
                f"{k.move_limit[c]:.1f} px at the start noise of this frame)")
    if k.blur[c] > 2.5 * cell_px[c]:
        return "too blurred"
    if not k.cells_ok[c]:
        return (f"cells do not read as the code ({k.cells_wrong[c]} wrong, "
                f"{k.cells_undecided[c]} undecided, classes {k.cells_sep[c]:.1f} "
                "spreads apart)")
    return ""


# the batch carries codes already refused (degenerate or non-finite quads) whose arithmetic is
# meaningless and never used; every kept code is checked finite ("diverged")
@np.errstate(invalid="ignore", divide="ignore", over="ignore")
def refine_codes(gray: np.ndarray, camera: Camera, corners: list[np.ndarray] | np.ndarray,
                 bits: list[np.ndarray], iterations: int = 3, coarse_iterations: int = 1,
                 chord_from: int | None = None, max_samples: int = MAX_SAMPLES,
                 band_px: float = 3.0, coarse_min_cell_px: float = 0.0,
                 lm_lambda: float = 0.1, tolerable_cells: int | np.ndarray = 0,
                 blur_iterations: int = 99, start_sigma_px: float = 0.85,
                 outer_edge: bool = True, edge_fallback: bool = False
                 ) -> list[RefinedCode]:
    """Refine the outer corners of decoded codes by a photometric fit of their interior
    (and of their outer edges, where paper surrounds them).

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
        outer_edge: Refit the kept codes with their outer edges where a uniform paper
            surround shows (:mod:`.outer`; ``RefinedCode.surround``).
        edge_fallback: Keep a code refused only because a corner moved too far at its
            outer edge lines, where its cells read right there (``RefinedCode.edge_lines``;
            :func:`_at_edge_lines`). For starts that are decoded quads: around a guessed
            start, a corner that moved far is the expected refusal.

    Returns:
        One :class:`RefinedCode` per input code, in order.
    """
    C = len(corners)
    if C == 0:
        return []
    grid = normalized_grid(camera)
    if grid.shape[:2] != gray.shape[:2]:
        raise ValueError(f"image is {gray.shape[1]}×{gray.shape[0]} but the camera is "
                         f"{camera.width}×{camera.height}; give the camera file of this "
                         "image size")
    M = int(max_samples)
    b = _batch(grid, corners, bits)
    region = _region(b, gray.shape, band_px, M)
    smp = _samples(grid, gray, b, region, M)
    fit = _levenberg_marquardt(b, smp, _start_levels(smp), iterations, coarse_iterations,
                               chord_from, lm_lambda, blur_iterations, coarse_min_cell_px)
    lev, s, valid, cell_px = fit.lev, fit.s, b.valid, b.cell_px
    sig2 = fit.cost / np.maximum(smp.cnt - 13.0, 1.0)
    margin, cell_a, cell_bits = cell_margins(b.g, lev, s, smp.xs, smp.ys, smp.vals, smp.wts,
                                             b.bits_pad, b.ns, fit.rho)
    tol_cells = np.broadcast_to(np.asarray(tolerable_cells, np.int64), (C,))
    cells = cell_verdicts(cell_a, cell_bits, tol_cells)
    blur_px = np.sqrt(s[:, 0] * s[:, 1]) * cell_px
    px_c, xn_c, cov_px = _corners(b, camera, parameter_covariance(
        fit.A, sig2, fit.Jw, fit.r, smp.xs, smp.ys, smp.wts, cell_px, blur_px, valid))
    moved = np.sqrt(((px_c - b.q) ** 2).sum(axis=2))  # (C, 4) how far each corner moved, px
    checks = _Checks(lev[:, 1] - lev[:, 0], np.sqrt(sig2), blur_px,
                     moved, _move_limits(moved, valid & np.isfinite(moved).all(axis=1),
                                         start_sigma_px, cell_px), *cells)
    whys = ["" if not valid[c] else _refusal(c, px_c, cell_px, checks) for c in range(C)]
    kept = valid & np.array([not w for w in whys])
    surround = np.zeros(C, bool)
    if outer_edge and kept.any():
        surround = _with_surround(grid, gray, camera, b, region, fit, smp, sig2, M, kept,
                                  np.nan_to_num(checks.cells_spread, nan=1.0),
                                  checks.move_limit, px_c, xn_c, cov_px)
    at_edges = np.zeros(C, bool)
    if edge_fallback:
        for c in range(C):
            # refused, but for the move alone: every other check (the cells read back at
            # the fit, the blur) passes, as it must for any code kept
            if (valid[c] and whys[c]
                    and not _refusal(c, px_c, cell_px, checks, moved_too=False)):
                got = _at_edge_lines(gray, camera, b, c, px_c[c], tol_cells[c])
                if got is not None:
                    px_c[c], xn_c[c], cov_px[c], margin[c] = got
                    whys[c], at_edges[c] = "", True
    out: list[RefinedCode] = []
    for c in range(C):
        if not valid[c]:
            given = np.asarray(corners[c], np.float64).reshape(4, 2)
            out.append(RefinedCode(given, np.full((4, 2), np.nan), np.eye(8), float("inf"),
                                   float("inf"), 0.0, 0.0, False, b.reasons[c]))
            continue
        why = whys[c]
        sig = float(np.sqrt(max(np.trace(cov_px[c]), 0.0) / 8))
        out.append(RefinedCode(px_c[c], xn_c[c], cov_px[c], sig, float(checks.resid[c]),
                               float(checks.contrast[c]), float(checks.blur[c]), not why, why,
                               float(margin[c]), bool(surround[c]), bool(at_edges[c])))
    return out


def _at_edge_lines(gray: np.ndarray, camera: Camera, b: _Batch, c: int,
                   interior_px: np.ndarray, tolerable: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """Stage 10: code ``c``, whose interior fit moved a corner far from its start, read at
    its outer edge lines (:func:`.edges.edge_line_fallback`) when its cells read right there
    (:func:`.cells.cell_verdicts`, with the code's own two classes).

    The interior and the border then disagree: the picture is not a flat view of a square
    there (the rim of a photo undistorted with a lens model that does not fit it, a bent
    print). Neither reading is the corner; the edges are the one the decoder saw, and their
    covariance gets a quarter of the mean squared distance to the interior's corners on every
    coordinate, as the surround refit's does (two readings, the truth between them).

    Returns:
        (corners (4, 2) px, the same normalised, covariance (8, 8) px², the cells' least
        margin), or None when an edge is not found (:func:`.edges.outer_edge_corners`),
        the interior fit lies more than :data:`_EDGE_MAX_DISAGREE_CELLS` cells from the edges'
        corners (it went astray), a corner leaves the calibrated field, or the cells do not
        read as the code there.
    """
    n = int(b.ns[c])
    got = edge_line_fallback(gray, b.q[c], b.bits_pad[c, :n, :n])
    if got is None:
        return None
    e, a = got
    far = np.linalg.norm(e.corners_px - interior_px, axis=1).max()
    if far > _EDGE_MAX_DISAGREE_CELLS * b.cell_px[c]:
        return None
    expected = b.bits_pad[c, 1:n - 1, 1:n - 1].ravel()
    ok = cell_verdicts(a[None], expected[None], np.array([tolerable]))[0]
    xn = camera.normalize(e.corners_px)
    if not ok[0] or not np.isfinite(xn).all():
        return None
    d2 = float(((e.corners_px - interior_px) ** 2).mean()) / 4.0
    margin = float(np.min(np.where(expected > 0.5, a - 0.5, 0.5 - a)))
    return e.corners_px, xn, e.cov_px + d2 * np.eye(8), margin


def _with_surround(grid: np.ndarray, gray: np.ndarray, camera: Camera, b: _Batch,
                   region: _Region, fit: _Fit, smp: _Samples, sig2: np.ndarray, M: int,
                   kept: np.ndarray, white_spread: np.ndarray, move_limit: np.ndarray,
                   px_c: np.ndarray, xn_c: np.ndarray, cov_px: np.ndarray) -> np.ndarray:
    """Stage 9: the kept codes refitted with their surround (:mod:`.outer`); where the
    surround is uniform paper, their corners and covariance are replaced in place.

    A refit is held to the interior fit's limit on how far a corner may move from its start
    (``move_limit``, (C,) px): one that went farther slid onto something else, and the
    interior fit, which passed every check, stays. A refit's covariance is its own plus,
    on every coordinate, a quarter of the mean squared distance between its corners and the
    interior fit's (see the comment where it is added).

    Returns:
        (C,) bool, the codes whose corners now come from the refit.
    """
    interior = Interior(b.g, fit.lev, fit.s, fit.rho, smp.xs, smp.ys, smp.vals, smp.wts, sig2,
                        white_spread)
    of = fit_outer(grid, gray, b.q, b.centre, b.scale, b.ns, b.bits_pad, region.band, kept,
                   interior, M, b.cell_px)
    used = of.used
    if used.any():
        b_o = replace(b, g=of.g)
        px_o, xn_o, cov_o = _corners(b_o, camera, of.cov_p)
        with np.errstate(invalid="ignore"):
            moved = np.sqrt(((px_o - b.q) ** 2).sum(axis=2))
            used &= np.isfinite(px_o).all(axis=(1, 2)) & (moved <= move_limit[:, None]).all(1)
        # the two fits read different evidence (the cells, extrapolated; the outer edges
        # against the paper): their disagreement is the model's error on this code, which
        # the pixel noise alone does not show; the refit, between them, is known to half of
        # it (two estimates of equal error, combined) on every coordinate
        d2 = ((px_o[used] - px_c[used]) ** 2).reshape(-1, 8).mean(axis=1) / 4.0
        px_c[used], xn_c[used] = px_o[used], xn_o[used]
        cov_px[used] = cov_o[used] + d2[:, None, None] * np.eye(8)
    return used
