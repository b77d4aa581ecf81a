"""The outer edge: where paper surrounds a code, its four outer edges join the fit.

The interior fit (:mod:`.fit`) places the outer corners by extrapolating the homography of the
code's inner edges out to the border's outer side, and that extrapolation carries the model's
error. A camera's tone curve applied after the optics' blur moves every edge toward its dark
side: the interior sees its white cells grown and places the outer corners outward (0.33 px
on a rendered 27-px code at gamma 1/2.2; 0.4 px measured on OpenCV's ChArUco photo). The outer
edges move the other way, inward, so a fit that holds both sides of the black border balances
the two; and the outer edges, long straight steps, pin the corners that the interior holds
loosely (AprilTag's detector, which reads only those edges, agrees with the edge lines within
0.13 px on real photos).

The outer edge may only be used where its surroundings are known: a uniform quiet zone. A
thin margin of paper on a darker, textured brick (every rendered drick) is not one. So each
kept code is refitted with one more level, the surround ``O``,

    I(p) = B + (W − B) · S(u, v) + (O − B) · (1 − P(u) P(v)),
    P(t) = Φ(t / s) − Φ((t − n) / s),

(the code's square blurred by the same separable Gaussian as its cells), from the interior
fit's samples plus those within the edge band on both sides of the outer edges, and the refit
is kept only where the data say the surround is uniform paper:

* on each side, the residuals beyond the edge are no larger than inside it, on the black
  border (a one-sided F test; the blur model's misfit acts on both halves alike, a card's edge
  or a shadow within the band on the outer half only) and centred on the fitted level;
* the surround is as bright as the code's white cells, within the spread of those cells' own
  whiteness and the fit's noise (the same paper under the same light: a thin margin against a
  darker ground blurs into a grey "surround" that is not).

A first look at a few dozen pixels along the outer side skips the refit where the surround is
far from paper (most codes on a brick), so that such frames pay little for it.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from drovisio.detect.corners.covariance import parameter_covariance
from drovisio.detect.corners.model import code_coords, model, phi_and_density, solve_batched
from drovisio.detect.corners.samples import pixel_boxes, select_samples

__all__ = ["Interior", "OuterFit", "f_quantile", "fit_outer", "model_outer"]

PROBE_SAMPLES = 48
"""Pixels along a code's outer side that judge, before the refit, whether its surround can
be paper (a level from 48 pixels is good to a seventh of the noise)."""


def model_outer(g: np.ndarray, lev: np.ndarray, s: np.ndarray, x: np.ndarray, y: np.ndarray,
                bits: np.ndarray, bits_t: np.ndarray, n_max: int, nf: np.ndarray,
                jacobian: bool = True, rho: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray | None]:
    """The interior model (:func:`.model.model`) plus the surround outside the code.

    Args:
        g: (C, 8) homographies, local normalised frame -> cells.
        lev: (C, 3) black, white and surround levels, grey levels.
        s: (C, 2) blur along u and v, cells.
        x, y: (C, M) the samples' local normalised coordinates.
        bits, bits_t, n_max: As :func:`.model.model`.
        nf: (C,) cells per side, border included (the outer edges lie at 0 and n).
        jacobian: Also return the transposed Jacobian (C, 13, M) (g, B, W, s_u, s_v, O).
        rho: (C,) the blur's correlation, held (the interior fit's; :func:`.model.model`).

    Returns:
        (intensity (C, M), Jacobian or None).
    """
    I, J = model(g, lev[:, :2], s, x, y, bits, bits_t, n_max, jacobian=jacobian, rho=rho)
    u, v, invD = code_coords(g, x, y)
    Pu, du_u, ds_u = _blurred_side(u, s[:, 0], nf)
    Pv, dv_v, ds_v = _blurred_side(v, s[:, 1], nf)
    out = 1.0 - Pu * Pv
    amp_o = (lev[:, 2] - lev[:, 0])[:, None]
    I = I + amp_o * out
    if not jacobian:
        return I, None
    assert J is not None  # asked for
    a_u = -amp_o * invD * Pv * du_u
    a_v = -amp_o * invD * Pu * dv_v
    wq = -(a_u * u + a_v * v)
    J13 = np.empty((J.shape[0], 13, J.shape[2]))
    J13[:, :12] = J[:, :12]
    J13[:, 0] += a_u * x
    J13[:, 1] += a_u * y
    J13[:, 2] += a_u
    J13[:, 3] += a_v * x
    J13[:, 4] += a_v * y
    J13[:, 5] += a_v
    J13[:, 6] += wq * x
    J13[:, 7] += wq * y
    J13[:, 8] -= out
    J13[:, 10] -= amp_o * Pv * ds_u
    J13[:, 11] -= amp_o * Pu * ds_v
    J13[:, 12] = out
    return I, J13


def _blurred_side(t: np.ndarray, s: np.ndarray, nf: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The code's extent [0, n] along one of its axes, blurred: ``P(t) = Φ(t / s) −
    Φ((t − n) / s)`` and its derivatives in ``t`` and in ``s``.

    Args:
        t: (C, M) the samples' coordinate along the axis, cells.
        s: (C,) the blur along it, cells.
        nf: (C,) cells per side, border included.

    Returns:
        (P, dP/dt, dP/ds), each (C, M).
    """
    s_, n = s[:, None], nf[:, None]
    z0, z1 = t / s_, (t - n) / s_
    F0, f0 = phi_and_density(z0)
    F1, f1 = phi_and_density(z1)
    return F0 - F1, (f0 - f1) / s_, (f1 * z1 - f0 * z0) / s_


def f_quantile(p: float, d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Upper ``p`` quantile of Fisher's F(d1, d2) by Paulson's normal approximation of
    ``F^(1/3)`` (within 5 % of the exact quantile at 0.1 % for d1 ≥ 4, d2 ≥ 10; 1 % for
    d1, d2 ≥ 20).

    Args:
        p: Upper tail probability.
        d1, d2: Degrees of freedom (broadcast together).
    """
    z2 = NormalDist().inv_cdf(1.0 - p) ** 2
    c1 = 2.0 / (9.0 * np.maximum(d1, 1.0))
    c2 = 2.0 / (9.0 * np.maximum(d2, 1.0))
    a, b = 1.0 - c2, 1.0 - c1
    den = np.maximum(a * a - z2 * c2, 1e-9)
    x = (a * b + np.sqrt(np.maximum(a * a * b * b - den * (b * b - z2 * c1), 0.0))) / den
    return x ** 3


@dataclass
class OuterFit:
    """The refit of the codes whose surround joined the fit."""

    used: np.ndarray
    """(C,) bool: the refit is kept (the surround is uniform paper)."""
    g: np.ndarray
    """(C, 8) the refit homographies (the interior's where not used)."""
    cov_p: np.ndarray
    """(C, 13, 13) the refit parameters' covariance, from its residuals
    (:func:`.covariance.parameter_covariance`; the identity where not refitted)."""


def _ring_bits(ns: np.ndarray) -> np.ndarray:
    """(C, n + 2, n + 2): a code-sized black square in a one-cell white ring, whose only
    edge is the code's outer side."""
    C, n_max = len(ns), int(ns.max())
    ring = np.zeros((C, n_max + 2, n_max + 2))
    for c in range(C):
        n = int(ns[c])
        ring[c, :n + 2, :n + 2] = 1.0
        ring[c, 1:n + 1, 1:n + 1] = 0.0
    return ring


def _shifted(g: np.ndarray) -> np.ndarray:
    """Homographies to cells counted from the ring (u + 1, v + 1)."""
    h = g.copy()
    h[:, 0] += g[:, 6]
    h[:, 1] += g[:, 7]
    h[:, 2] += 1.0
    h[:, 3] += g[:, 6]
    h[:, 4] += g[:, 7]
    h[:, 5] += 1.0
    return h


def _outer_samples(grid: np.ndarray, gray: np.ndarray, q: np.ndarray, g: np.ndarray,
                   centre: np.ndarray, scale: np.ndarray, ns: np.ndarray, band: np.ndarray,
                   fit: np.ndarray, M: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The samples within ``band`` cells of the code's outer side, on both sides of it (the
    interior fit stays clear of it: these are new samples).

    Returns:
        (xs, ys: local coordinates, vals: grey levels, wts: 1 where a sample is), (C, Mc).
    """
    nf = ns.astype(np.float64)
    x0, y0, bw, bh = pixel_boxes(q, (nf + 2.0 * band) / nf, gray.shape)
    P_box = np.where(fit & (bw > 0) & (bh > 0), bw * bh, 0)
    K = 8 * M
    P = np.minimum(P_box, K)
    xs, ys, vals, wts, _ = select_samples(grid, gray, x0, y0, bw, P, P_box, K, centre, scale,
                                          _shifted(g), 1.0 - band, nf + 1.0 + band, band,
                                          ns + 2, _ring_bits(ns), M)
    return xs, ys, vals, wts


def _sides(g: np.ndarray, xs: np.ndarray, ys: np.ndarray, nf: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Which side of the code each sample is nearest (0 left, 1 right, 2 top, 3 bottom) and
    how far beyond it (cells; negative inside the code).

    Returns:
        (side (C, M) int, beyond (C, M)).
    """
    u, v, _ = code_coords(g, xs, ys)
    n = nf[:, None]
    d = np.stack([-u, u - n, -v, v - n])  # (4, C, M)
    return d.argmax(axis=0), d.max(axis=0)


def _sides_uniform(g: np.ndarray, xs: np.ndarray, ys: np.ndarray, r: np.ndarray,
                   wts: np.ndarray, nf: np.ndarray, band: np.ndarray, shade: np.ndarray,
                   false_rate: float) -> np.ndarray:
    """Whether the surround is uniform along each of the four sides.

    Each side's outer edge is judged against itself: the residuals on its outer half (the
    surround) may be no larger than on its inner half (the code's black border, which is
    uniform ink) by a one-sided F test, and centred on the fitted level within the noise and
    the white cells' own spread of shade. The blur model's misfit acts on both halves alike;
    a card's edge, a shadow or a neighbour within the band acts on the outer half only. The
    tests of the four sides share ``false_rate``.

    Args:
        g: (C, 8) the refit's homographies; xs, ys: (C, M) the samples; r: (C, M) their
            weighted residuals; wts: (C, M) 1 where a sample is; nf: (C,) cells per side;
            band: (C,) the edge band, cells.
        shade: (C,) the white cells' spread of level, grey levels.
        false_rate: Chance that a uniform surround is refused.

    Returns:
        (C,) bool: uniform.
    """
    side, beyond = _sides(g, xs, ys, nf)
    near = (wts > 0) & (beyond > -band[:, None])
    on = (side[:, None, :] == np.arange(4)[None, :, None]) & near[:, None, :]  # (C, 4, M)
    out = on & (beyond > 0)[:, None, :]
    inn = on & ~out
    n_o = out.sum(axis=2).astype(np.float64)
    n_i = inn.sum(axis=2).astype(np.float64)
    r2 = (r * r)[:, None, :]
    s2_o = np.where(out, r2, 0.0).sum(axis=2) / np.maximum(n_o, 1.0)
    s2_i = np.where(inn, r2, 0.0).sum(axis=2) / np.maximum(n_i, 1.0)
    f = s2_o / np.maximum(s2_i, 1e-12)
    mean_o = np.where(out, r[:, None, :], 0.0).sum(axis=2) / np.maximum(n_o, 1.0)
    rate = false_rate / 8.0  # two tests on each of four sides
    z = NormalDist().inv_cdf(1.0 - rate / 2.0)
    f_ok = f <= f_quantile(rate, n_o, n_i)
    m_ok = np.abs(mean_o) <= z * np.sqrt(s2_i / np.maximum(n_o, 1.0) + shade[:, None] ** 2)
    seen = (n_o >= 4) & (n_i >= 4)
    return np.all((f_ok & m_ok) | ~seen, axis=1) & (seen.sum(axis=1) >= 3)


def _paper(lev3: np.ndarray, var_ow: np.ndarray, white_spread: np.ndarray, z: float
           ) -> np.ndarray:
    """(C,) bool: the surround is as bright as the code's white cells, within the spread of
    those cells' own whiteness and the fit's noise (the same paper under the same light).

    Args:
        lev3: (C, 3) black, white and surround levels; var_ow: (C,) variance of the fitted
            surround minus white, grey levels²; white_spread: (C,) the cells' spread of
            whiteness, a fraction of the contrast; z: the normal quantile of the test.
    """
    amp = np.maximum(lev3[:, 1] - lev3[:, 0], 1e-9)
    d = (lev3[:, 2] - lev3[:, 1]) / amp
    return np.abs(d) <= z * np.sqrt(white_spread ** 2 + np.maximum(var_ow, 0.0) / amp ** 2)


def _start_surround(g: np.ndarray, lev: np.ndarray, s: np.ndarray, rho: np.ndarray,
                    xs: np.ndarray,
                    ys: np.ndarray, vals: np.ndarray, wts: np.ndarray, bits_in: np.ndarray,
                    bits_t: np.ndarray, n_max: int, nf: np.ndarray) -> np.ndarray:
    """(C, 3) the interior fit's levels and the surround's, the latter by linear least
    squares with everything else held at the interior fit."""
    I0, _ = model(g, lev, s, xs, ys, bits_in, bits_t, n_max, jacobian=False, rho=rho)
    u, v, _ = code_coords(g, xs, ys)
    box = _blurred_side(u, s[:, 0], nf)[0] * _blurred_side(v, s[:, 1], nf)[0]
    out = (1.0 - box) * wts  # the surround's share of each sample
    den = (out * out).sum(axis=1)
    amp_o = ((vals - I0) * out).sum(axis=1) / np.maximum(den, 1e-9)
    return np.concatenate([lev, (lev[:, 0] + np.where(den > 0, amp_o, 0.0))[:, None]], axis=1)


def _var_o_minus_w(A: np.ndarray, sig2: np.ndarray, live: np.ndarray) -> np.ndarray:
    """(C,) variance of O − W, grey levels², from the Gauss–Newton matrix."""
    out = np.full(len(A), np.inf)
    eye = np.eye(A.shape[1])
    for c in np.nonzero(live)[0]:
        try:
            cov = np.linalg.inv(A[c] + 1e-9 * eye) * sig2[c]
        except np.linalg.LinAlgError:
            continue
        out[c] = cov[12, 12] + cov[9, 9] - 2.0 * cov[9, 12]
    return out


def _levenberg_marquardt(g: np.ndarray, lev3: np.ndarray, s: np.ndarray, rho: np.ndarray,
                         xs: np.ndarray,
                         ys: np.ndarray, vals: np.ndarray, wts: np.ndarray,
                         bits_in: np.ndarray, bits_t: np.ndarray, n_max: int, nf: np.ndarray,
                         iterations: int, lm_lambda: float
                         ) -> tuple[np.ndarray, ...]:
    """The refit of (G, B, W, s_u, s_v, O) of the codes given (copies).

    Returns:
        (g (C, 8), levels (C, 3), blur (C, 2) cells, the last Gauss–Newton matrix
        (C, 13, 13) and its transposed Jacobian (C, 13, M), the weighted residuals at the
        solution (C, M)).
    """
    g, lev3, s = g.copy(), lev3.copy(), s.copy()
    lam = np.full(len(g), lm_lambda)
    eye = np.eye(13)
    A = np.tile(eye, (len(g), 1, 1))
    Jw = np.zeros((len(g), 13, vals.shape[1]))
    r = np.zeros_like(vals)
    for _ in range(iterations):
        I, J = model_outer(g, lev3, s, xs, ys, bits_in, bits_t, n_max, nf, rho=rho)
        assert J is not None  # asked for
        r = (vals - I) * wts
        cost = (r * r).sum(axis=1)
        Jw = J * wts[:, None]
        A = np.matmul(Jw, J.transpose(0, 2, 1))
        rhs = np.matmul(Jw, r[..., None])[..., 0]
        diag = np.einsum("cii->ci", A)
        dp = solve_batched(A + lam[:, None, None] * diag[:, :, None] * eye + 1e-9 * eye, rhs)
        g_n, lev_n = g + dp[:, :8], lev3 + dp[:, [8, 9, 12]]
        s_n = np.minimum(np.maximum(s + dp[:, 10:12], 0.03), 0.8)
        I_n, _ = model_outer(g_n, lev_n, s_n, xs, ys, bits_in, bits_t, n_max, nf,
                             jacobian=False, rho=rho)
        r_n = (vals - I_n) * wts
        better = ((r_n * r_n).sum(axis=1) <= cost) & np.isfinite(r_n).all(axis=1)
        g[better], lev3[better], s[better] = g_n[better], lev_n[better], s_n[better]
        r[better] = r_n[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-6), lam * 5.0)
    return g, lev3, s, A, Jw, r


@dataclass
class Interior:
    """The interior fit a refit starts from (C codes)."""

    g: np.ndarray
    """(C, 8) homographies, local normalised frame -> cells."""
    lev: np.ndarray
    """(C, 2) black and white levels."""
    s: np.ndarray
    """(C, 2) blur, cells."""
    rho: np.ndarray
    """(C,) the blur's correlation of u and v (held in the refit)."""
    xs: np.ndarray
    ys: np.ndarray
    vals: np.ndarray
    wts: np.ndarray
    """(C, M) its samples: local coordinates, grey levels, 1 where a sample is."""
    sig2: np.ndarray
    """(C,) its residual variance, grey levels²."""
    white_spread: np.ndarray
    """(C,) the spread of its cells' whiteness, a fraction of the contrast
    (:func:`.cells.cell_verdicts`)."""


def fit_outer(grid: np.ndarray, gray: np.ndarray, q: np.ndarray, centre: np.ndarray,
              scale: np.ndarray, ns: np.ndarray, bits_pad: np.ndarray, band: np.ndarray,
              fit: np.ndarray, interior: Interior, max_samples: int, cell_px: np.ndarray,
              iterations: int = 3, lm_lambda: float = 0.01, false_rate: float = 0.001
              ) -> OuterFit:
    """Refit codes with their surround (see the module), from the interior fit.

    Args:
        grid: (H, W, 2) normalised coordinates of the pixel centres; gray: (H, W) the frame.
        q: (C, 4, 2) the codes' corners, px (their box).
        centre, scale: (C, 2), (C,) the local frame.
        ns: (C,) cells per side, border included; bits_pad: (C, n, n) the cells, 1 = white.
        band: (C,) the edge band, cells (also how far outside the code samples reach).
        fit: (C,) bool, the codes to refit (the others keep the interior fit).
        interior: The interior fit: the start, its samples (the refit adds those along the
            outer side) and its noise.
        max_samples: Most samples per code along the outer side.
        cell_px: (C,) a cell's width, px.
        iterations: Levenberg–Marquardt iterations.
        lm_lambda: Initial damping, relative to the diagonal.
        false_rate: Chance that a uniform paper surround is refused, per test.

    Returns:
        The refit, :class:`OuterFit`.
    """
    it = interior
    C = len(it.g)
    nf = ns.astype(np.float64)
    z = NormalDist().inv_cdf(1.0 - false_rate / 2.0)
    bits_in = np.ascontiguousarray(bits_pad[:, 1:-1, 1:-1], np.float32)
    bits_t = np.ascontiguousarray(bits_in.transpose(0, 2, 1))
    n_max = bits_pad.shape[1]
    # a first look, a few dozen pixels along the outer side: a surround far from paper
    # (twice the final test's reach) is not worth the refit (most codes on a brick)
    xo, yo, vo, wo = _outer_samples(grid, gray, q, it.g, centre, scale, ns, band, fit,
                                    PROBE_SAMPLES)
    live = fit & (wo.sum(axis=1) >= 8)
    lev3 = _start_surround(it.g, it.lev, it.s, it.rho, xo, yo, vo, wo, bits_in, bits_t, n_max,
                           nf)
    live &= _paper(lev3, np.zeros(C), it.white_spread, 2.0 * z)
    g = it.g.copy()
    used = np.zeros(C, bool)
    cov_p = np.tile(np.eye(13), (C, 1, 1))
    k = np.nonzero(live)[0]
    if k.size == 0:
        return OuterFit(used, g, cov_p)
    xo, yo, vo, wo = _outer_samples(grid, gray, q, it.g, centre, scale, ns, band, live,
                                    max_samples)
    xs = np.concatenate([it.xs[k], xo[k]], axis=1)
    ys = np.concatenate([it.ys[k], yo[k]], axis=1)
    vals = np.concatenate([it.vals[k], vo[k]], axis=1)
    wts = np.concatenate([it.wts[k], wo[k]], axis=1)
    g_k, lev_k, s_k, A_k, Jw_k, r_k = _levenberg_marquardt(
        g[k], lev3[k], it.s[k], it.rho[k], xs, ys, vals, wts, bits_in[k], bits_t[k], n_max,
        nf[k], iterations, lm_lambda)
    sig2_k = (r_k * r_k).sum(axis=1) / np.maximum(wts.sum(axis=1) - 13.0, 1.0)
    ok = _sides_uniform(g_k, xs, ys, r_k, wts, nf[k], band[k],
                        it.white_spread[k] * (lev_k[:, 1] - lev_k[:, 0]), false_rate)
    ok &= _paper(lev_k, _var_o_minus_w(A_k, sig2_k, ok), it.white_spread[k], z)
    g[k], used[k] = g_k, ok
    if ok.any():
        cov_p[k] = parameter_covariance(A_k, sig2_k, Jw_k, r_k, xs, ys, wts, cell_px[k],
                                        np.sqrt(s_k[:, 0] * s_k[:, 1]) * cell_px[k], ok)
    return OuterFit(used, g, cov_p)
