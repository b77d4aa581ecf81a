"""The code fit's model against codes drawn here: its blur's correlation (an oblique view
blurs the cells along an ellipse whose axes are not the code's), the outer edge joined
where a uniform paper surround shows, and only there (:mod:`drovisio.detect.corners.outer`),
and the covariance from the fit's own residuals (:mod:`drovisio.detect.corners.covariance`):
honest where neighbouring pixels share their errors, unchanged where they do not.

The codes are drawn by a small renderer of their own: supersampled, blurred in linear light,
then the camera's tone curve, noise and 8 bits, with paper reaching a chosen number of cells
beyond each side and a darker ground beyond that.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from drovisio import _numba
from drovisio.camera import Camera
from drovisio.detect.corners import covariance, refine_codes
from drovisio.detect.corners.cells import cell_margins
from drovisio.detect.corners.covariance import gauss_newton_covariance, parameter_covariance
from drovisio.detect.corners.model import model
from drovisio.detect.corners.outer import f_quantile, model_outer
from drovisio.layout import aruco_code_bits

CAM = Camera(K=np.array([[400.0, 0, 80], [0, 400.0, 60], [0, 0, 1]]), width=160, height=120)
BITS = aruco_code_bits("DICT_6X6_250", 7).astype(np.float64)


def _render(corners: np.ndarray, margins: tuple[float, float, float, float], gamma: float,
            seed: int, blur_px: float = 0.9, noise: float = 1.5, ss: int = 8) -> np.ndarray:
    """A 6×6 code whose outer corners (TL, TR, BR, BL, px) are ``corners``, on paper that
    reaches ``margins`` cells beyond its left, right, top and bottom sides, ground of a
    quarter of the paper's reflectance beyond; blurred in linear light, then ``x**gamma``."""
    n = BITS.shape[0]
    H = cv2.getPerspectiveTransform(np.float32(corners),
                                    np.float32([[0, 0], [n, 0], [n, n], [0, n]]))
    ys, xs = np.mgrid[0:CAM.height * ss, 0:CAM.width * ss]
    p = np.stack([(xs.ravel() + 0.5) / ss - 0.5, (ys.ravel() + 0.5) / ss - 0.5,
                  np.ones(xs.size)])
    q = H @ p
    u, v = q[0] / q[2], q[1] / q[2]
    left, right, top, bottom = margins
    paper = (u >= -left) & (u < n + right) & (v >= -top) & (v < n + bottom)
    inside = (u >= 0) & (u < n) & (v >= 0) & (v < n)
    ui = np.clip(np.floor(u).astype(int), 0, n - 1)
    vi = np.clip(np.floor(v).astype(int), 0, n - 1)
    refl = np.where(inside, np.where(BITS[vi, ui] > 0, 0.9, 0.05), np.where(paper, 0.9, 0.22))
    img = cv2.resize(refl.reshape(CAM.height * ss, CAM.width * ss), (CAM.width, CAM.height),
                     interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), blur_px)
    rng = np.random.default_rng(seed)
    out = 255.0 * np.clip(img, 0.0, 1.0) ** gamma + rng.normal(0.0, noise, img.shape)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _code(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """True corners of a ~27-px code (3.4 px cells) in slight perspective, and a start
    0.5 px off them."""
    rng = np.random.default_rng(100 + seed)
    c = (np.array([[50, 30], [104, 33], [101, 86], [47, 83]], np.float64)
         + rng.uniform(-3, 3, (4, 2))) * 0.5 + [40, 30]
    return c, c + rng.normal(0.0, 0.5, (4, 2))


def _fit(img: np.ndarray, start: np.ndarray, outer: bool):
    r = refine_codes(img, CAM, start[None], [BITS], iterations=2, lm_lambda=0.03,
                     max_samples=200, band_px=2.0, outer_edge=outer)[0]
    assert r.ok, r.reason
    return r


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).sum(axis=1).mean()))


@pytest.mark.parametrize("gamma", [1.0, 1 / 2.2])
def test_a_paper_surround_joins_the_fit_and_the_corners_get_closer(gamma):
    # a camera's tone curve after the optics' blur moves every edge toward the dark side:
    # the interior alone sees its white cells grown and extrapolates the outer corners
    # outward (measured 0.33 px RMS); with the outer edges, which move inward, the border's
    # two sides balance
    interior, surround = [], []
    for seed in range(4):
        truth, start = _code(seed)
        img = _render(truth, (3.0, 3.0, 3.0, 3.0), gamma, seed)
        a, b = _fit(img, start, False), _fit(img, start, True)
        assert b.surround and not a.surround
        interior.append(_rms(a.corners_px, truth))
        surround.append(_rms(b.corners_px, truth))
    if gamma == 1.0:  # measured 0.071 -> 0.021 px
        assert np.mean(surround) < 0.045 and np.mean(surround) < 0.6 * np.mean(interior)
    else:             # measured 0.328 -> 0.177 px
        assert np.mean(interior) > 0.25
        assert np.mean(surround) < 0.22 and np.mean(surround) < 0.65 * np.mean(interior)


def test_the_refit_is_known_no_better_than_its_two_readings_agree():
    """Under a tone curve, the cells (extrapolated) and the outer edges disagree: the model's
    error, which the pixel noise does not show. The refit's corners are 0.13 px per
    coordinate off the truth; their covariance from the pixel noise alone said 0.04 px
    (chi-square 40 against chi2(8)'s median 7.3, measured); with half the distance between
    the two fits' corners added it says 0.16 px (3.9). Without a tone curve the two agree
    and the covariance stays small (0.028 px)."""
    for gamma, chi2_max, sigma_max in ((1 / 2.2, 15.0, 0.3), (1.0, 15.0, 0.05)):
        d2, sig = [], []
        for seed in range(8):
            truth, start = _code(seed)
            b = _fit(_render(truth, (3.0, 3.0, 3.0, 3.0), gamma, seed), start, True)
            assert b.surround
            e = (b.corners_px - truth).ravel()
            d2.append(float(e @ np.linalg.solve(b.cov_px + np.eye(8) * 0.03 ** 2, e)))
            sig.append(b.sigma_px)
        assert np.median(d2) < chi2_max and np.median(sig) < sigma_max, (gamma, d2, sig)
    assert np.median(sig) > 0.01


@pytest.mark.parametrize("margins", [(0.2, 0.2, 0.2, 0.2),     # a thin margin on a brick
                                     (3.0, 0.25, 3.0, 3.0)])   # a card's edge on one side
def test_a_surround_that_is_not_uniform_paper_is_left_out(margins):
    for seed in range(4):
        truth, start = _code(seed)
        img = _render(truth, margins, 1.0, seed)
        a, b = _fit(img, start, False), _fit(img, start, True)
        assert not b.surround
        assert np.array_equal(a.corners_px, b.corners_px)   # the interior fit, untouched
        assert _rms(b.corners_px, truth) < 0.15


def test_the_refit_is_not_worse_where_the_paper_is_uniform_but_the_ground_near():
    # paper one cell wide all round (AprilTag's white ring): the band (half a cell here)
    # stays on the paper, so the refit is kept and exact
    errs = []
    for seed in range(4):
        truth, start = _code(seed)
        b = _fit(_render(truth, (1.0, 1.0, 1.0, 1.0), 1.0, seed), start, True)
        errs.append(_rms(b.corners_px, truth) if b.surround else np.inf)
    assert np.mean(np.isfinite(errs)) >= 0.75
    assert np.median(errs) < 0.05


@pytest.mark.parametrize("shift_cells", [0.2, 2.0])
def test_a_refit_is_held_to_the_move_limit_of_its_start(monkeypatch, shift_cells):
    # the refit is only kept where the surround is paper; a corner it moved farther than the
    # frame's start noise allows would have slid onto something else, whatever the surround
    import drovisio.detect.corners.fit as fit_mod

    real = fit_mod.fit_outer

    def shifted(*args, **kwargs):
        of = real(*args, **kwargs)
        g = of.g.copy()   # u -> u + shift: the code's square slides along u
        g[:, 0:3] += shift_cells * np.c_[g[:, 6:8], np.ones(len(g))]
        return replace(of, g=g)

    monkeypatch.setattr(fit_mod, "fit_outer", shifted)
    truth, start = _code(0)
    img = _render(truth, (3.0, 3.0, 3.0, 3.0), 1.0, 0)
    a, b = _fit(img, start, False), _fit(img, start, True)
    moved = np.sqrt(((b.corners_px - start) ** 2).sum(axis=1)).max()
    if shift_cells < 1.0:   # 0.7 px: within the limit, the refit is kept as it came
        assert b.surround and 0.4 < _rms(b.corners_px, a.corners_px) < 1.0
    else:                   # 6.8 px: beyond it (3.5 px here), the interior fit stays
        assert not b.surround and np.array_equal(a.corners_px, b.corners_px)
        assert moved < 2.0


def _two_codes(seed: int, reach: float):
    """Inputs of the model for two codes near a slight perspective: their inner cells (and
    transposed), homographies, blur, and 300 samples each within ``reach`` of the centre."""
    rng = np.random.default_rng(seed)
    C, M = 2, 300
    bits = np.ascontiguousarray(np.stack([BITS[1:-1, 1:-1]] * C), np.float32)
    bits_t = np.ascontiguousarray(bits.transpose(0, 2, 1))
    g = np.array([[1.1, 0.05, 4.0, -0.03, 0.95, 4.1, 0.01, -0.02]] * C)
    g[1] += rng.normal(0, 0.01, 8)
    s = np.array([[0.3, 0.25], [0.2, 0.35]])
    x = rng.uniform(-reach, reach, (C, M))
    y = rng.uniform(-reach, reach, (C, M))
    return bits, bits_t, g, s, x, y


def test_the_model_jacobian_is_its_derivative():
    bits, bits_t, g, s, x, y = _two_codes(3, 5.5)
    n = BITS.shape[0]
    lev = np.array([[30.0, 200.0, 190.0], [20.0, 180.0, 185.0]])
    rho = np.array([0.3, -0.2])
    nf = np.full(2, float(n))
    for r, exact in ((None, range(13)), (rho, (8, 9, 12))):
        # with the blur correlated, the levels' rows are exact; the geometry's and blur's
        # leave out terms of the correlation's series (the fit's steps, not its model)
        _check_rows(g, lev, s, r, x, y, bits, bits_t, n, nf, exact)


def _check_rows(g, lev, s, rho, x, y, bits, bits_t, n, nf, exact):
    _, J = model_outer(g, lev, s, x, y, bits, bits_t, n, nf, rho=rho)
    assert J is not None

    def I_of(p):
        I, _ = model_outer(p[:, :8], p[:, [8, 9, 12]], p[:, 10:12], x, y, bits, bits_t, n, nf,
                           jacobian=False, rho=rho)
        return I
    p0 = np.concatenate([g, lev[:, :2], s, lev[:, 2:]], axis=1)
    for k in exact:
        h = 1e-4 * max(1.0, abs(p0[0, k]))
        pp, pm = p0.copy(), p0.copy()
        pp[:, k] += h
        pm[:, k] -= h
        num = (I_of(pp) - I_of(pm)) / (2 * h)
        # the interior part runs in float32: compare at its precision
        assert np.abs(num - J[:, k]).max() < 2e-3 * (np.abs(num).max() + 1.0), k


def test_the_blur_correlation_row_is_its_derivative():
    bits, bits_t, g, s, x, y = _two_codes(4, 4.5)
    n = BITS.shape[0]
    lev = np.array([[30.0, 200.0], [20.0, 180.0]])
    for r0 in (0.0, 0.4):
        rho = np.array([r0, -r0])
        _, J = model(g, lev, s, x, y, bits, bits_t, n, rho=rho)
        h = 1e-3
        Ip, _ = model(g, lev, s, x, y, bits, bits_t, n, jacobian=False, rho=rho + h)
        Im, _ = model(g, lev, s, x, y, bits, bits_t, n, jacobian=False, rho=rho - h)
        num = (Ip - Im) / (2 * h)
        assert np.abs(num).max() > 5.0   # the correlation does move the model
        assert np.abs(num - J[:, 12]).max() < 2e-3 * np.abs(num).max()


def test_the_cells_read_back_with_the_blur_the_fit_found():
    # samples drawn by the model itself with a strongly correlated blur: read back with that
    # correlation, every cell's whiteness is its bit; read back as if the blur were along the
    # code's axes, the cells near the black-white corners are misread
    bits, bits_t, g, s, x, y = _two_codes(5, 4.5)
    n = BITS.shape[0]
    lev = np.array([[30.0, 200.0], [20.0, 180.0]])
    rho = np.array([0.55, -0.55])
    vals, _ = model(g, lev, s, x, y, bits, bits_t, n, jacobian=False, rho=rho)
    wts = np.ones_like(vals)
    pad = np.stack([BITS.astype(np.float64)] * 2)
    ns = np.full(2, n)
    _, a, expected = cell_margins(g, lev, s, x, y, vals, wts, pad, ns, rho)
    seen = np.isfinite(a)
    assert np.abs(a - expected)[seen].max() < 1e-4
    _, a0, _ = cell_margins(g, lev, s, x, y, vals, wts, pad, ns)
    assert np.abs(a0 - expected)[seen].max() > 0.05


def test_an_oblique_code_blurred_round_in_the_image_is_fitted_true():
    # a round blur in the image is an ellipse across an oblique code's cells, its axes not
    # the code's (axes 41° apart here): the blur's correlation is fitted with it (measured
    # 0.10 px RMS; with a blur along the code's own axes only, 0.28 px)
    errs = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        o = np.array([48.0, 35.0]) + rng.uniform(-2, 2, 2)
        eu = np.array([30.0, 9.0]) * rng.uniform(0.9, 1.1)
        ev = np.array([16.0, 26.0]) * rng.uniform(0.9, 1.1)
        if seed % 2:  # leaning the other way
            ev, o = np.array([-16.0, 26.0]) * rng.uniform(0.9, 1.1), o + [16.0, 0.0]
        truth = np.array([o, o + eu, o + eu + ev, o + ev])
        img = _render(truth, (3.0, 3.0, 3.0, 3.0), 1.0, seed, blur_px=1.0)
        a = _fit(img, truth + rng.normal(0.0, 0.5, (4, 2)), False)
        errs.append(_rms(a.corners_px, truth))
    assert np.mean(errs) < 0.15 and max(errs) < 0.3


def test_f_quantile_matches_the_exact_quantiles():
    # exact values: scipy.stats.f.ppf(0.999, d1, d2)
    exact = {(20, 200): 2.4243, (50, 100): 2.0756, (100, 300): 1.6205, (400, 400): 1.3632,
             (30, 30): 3.2171, (8, 200): 3.4343, (4, 200): 4.8116}
    for (d1, d2), f in exact.items():
        got = float(f_quantile(0.001, np.array([float(d1)]), np.array([float(d2)]))[0])
        assert abs(got / f - 1.0) < 0.02, (d1, d2, got)


# ------------------------------------------------------------------ the covariance
def _noisy(truth: np.ndarray, seed: int, correlated: bool) -> np.ndarray:
    """A code drawn without noise, then 3 levels of noise: white, or white blurred over
    1.5 px (what demosaicing and compression do to a sensor's noise), of the same spread."""
    clean = _render(truth, (3.0, 3.0, 3.0, 3.0), 1.0, seed, noise=0.0).astype(np.float64)
    n = np.random.default_rng(seed).normal(0.0, 1.0, clean.shape)
    if correlated:
        n = cv2.GaussianBlur(n, (0, 0), 1.5)
    n *= 3.0 / n.std()
    return np.clip(np.round(clean + n), 0, 255).astype(np.uint8)


def _chi2_to_truth(correlated: bool, monkeypatch=None) -> float:
    d2 = []
    for seed in range(12):
        truth, start = _code(seed)
        r = refine_codes(_noisy(truth, seed, correlated), CAM, start[None], [BITS],
                         iterations=2, lm_lambda=0.03, max_samples=200, band_px=2.0,
                         outer_edge=False)[0]
        assert r.ok, r.reason
        e = (r.corners_px - truth).ravel()
        d2.append(float(e @ np.linalg.solve(r.cov_px, e)))
    return float(np.median(d2))


def _gauss_newton_only(A, sig2, Jw, r, xs, ys, wts, cell_px, blur_px, valid):
    return gauss_newton_covariance(A, sig2, valid)


def test_correlated_noise_widens_the_covariance_white_noise_does_not(monkeypatch):
    """Chi-square of the corners against the truth, median of 12 drawn codes (chi2(8)'s
    median is 7.3). With the same noise blurred over 1.5 px, the Gauss-Newton covariance
    alone is far too small (17.7, measured) and the sandwich from the residuals honest
    (9.6); with white noise the residuals show nothing more (the two within 1.3x)."""
    import drovisio.detect.corners.fit as fit_mod

    white, corr = _chi2_to_truth(False), _chi2_to_truth(True)
    monkeypatch.setattr(fit_mod, "parameter_covariance", _gauss_newton_only)
    white_gn, corr_gn = _chi2_to_truth(False), _chi2_to_truth(True)
    assert corr_gn > 14.0 and corr < 12.0 and corr < 0.7 * corr_gn, (corr, corr_gn)
    assert 4.0 < white <= white_gn < 1.3 * white + 1.0, (white, white_gn)


@pytest.mark.skipif(not _numba.AVAILABLE, reason="numba is not installed on this platform")
def test_the_compiled_kernel_is_its_numpy_reference():
    rng = np.random.default_rng(3)
    C, M, k = 5, 120, 13
    p = rng.uniform(0, 12, (C, M, 2)).astype(np.float32)
    score = rng.normal(size=(C, M, k)).astype(np.float32)
    score[:, 100:] = 0.0                     # samples that are not there
    a = covariance._ck.kernel_scores(p, score, np.float32(covariance.CUT2))
    b = covariance._kernel_scores(p, score, covariance.CUT2)
    # the samples that are there (the others' rows are multiplied by their zero score)
    assert np.allclose(a[:, :100], b[:, :100], rtol=1e-4, atol=1e-4)
    B_a = np.matmul(score.transpose(0, 2, 1), a)
    assert np.allclose(B_a, np.matmul(score.transpose(0, 2, 1), b), rtol=1e-4, atol=1e-3)


def test_never_narrower_than_gauss_newton():
    """Residuals that alternate in sign from one sample to the next (neighbours whose errors
    cancel) make the sandwich smaller than the Gauss-Newton covariance: the residuals only
    ever widen it, so the Gauss-Newton one is kept."""
    C, M = 2, 64
    t = np.arange(M, dtype=np.float64)
    # smooth, independent columns (a sample's neighbours have nearly its Jacobian)
    Jw = np.stack([np.cos(np.pi * a * (t + 0.5) / M) for a in range(13)])[None].repeat(C, 0)
    A = np.matmul(Jw, Jw.transpose(0, 2, 1))
    xs = np.tile(t * 0.25, (C, 1))            # a sample a pixel (cells of 4 px)
    ys = np.zeros((C, M))
    r = np.tile(np.where(np.arange(M) % 2 == 0, 2.0, -2.0), (C, 1))
    wts = np.ones((C, M))
    sig2 = (r * r).sum(axis=1) / (M - 13)     # the same for both signs
    rest = (xs, ys, wts, np.full(C, 4.0), np.full(C, 0.8), np.ones(C, bool))
    gn = _gauss_newton_only(A, sig2, Jw, r, *rest)
    assert np.allclose(parameter_covariance(A, sig2, Jw, r, *rest), gn)
    r_same = np.abs(r)                       # neighbours sharing their error: widened
    wide = parameter_covariance(A, sig2, Jw, r_same, *rest)
    assert np.trace(wide[0, :8, :8]) > 2.0 * np.trace(gn[0, :8, :8])
