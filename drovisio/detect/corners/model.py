"""The code fit's photometric model and the small batched linear algebra it needs.

A code's pixels are modelled as ``I(p) = B + (W − B) · S(u, v)`` with ``(u, v) = G(x(p))``
(see :mod:`drovisio.detect.corners`): ``G`` the 8-parameter homography from the local,
normalised image frame to the code plane in cell units, ``S`` the code's white cells blurred by
a Gaussian of widths ``s_u``, ``s_v`` and correlation ``rho`` in the code's frame. A blur round
in the image is an ellipse in the frame of an oblique code, whose axes are not the code's
(so is a motion streak): without ``rho``, codes far off-axis through a fisheye came out 1 %
small and their corners 1–2 px off. Each cell's blurred box is the bivariate normal's, by
its tetrachoric series to ``rho²``: every term is a product of a function of ``u`` and one of
``v``, so the model stays two matrix products per term. Every function works on a batch of
C codes at once.
"""

from __future__ import annotations

import numpy as np

__all__ = ["code_coords", "correlation_terms", "g_to_matrix", "homographies", "inverse_3x3",
           "model", "phi_and_density", "phi_cdf", "solve_batched"]


_C1, _C3 = 0.7978845608028654, 0.035677408136300125
"""Φ(z) ≈ 0.5 + 0.5 tanh(z (c1 + c3 z²)): |error| < 2e-4, one transcendental call."""


def _tanh(z: np.ndarray) -> np.ndarray:
    """tanh(z (c1 + c3 z²)) in ``z``'s precision."""
    t = z.dtype.type
    return np.tanh(z * (t(_C1) + t(_C3) * z * z))


def _density(z: np.ndarray, th: np.ndarray) -> np.ndarray:
    """The tanh form's exact derivative from ``th = _tanh(z)``:
    d/dz [0.5 + 0.5 tanh(z (c1 + c3 z²))] = 0.5 (1 − tanh²) (c1 + 3 c3 z²)."""
    t = z.dtype.type
    return t(0.5) * (t(1.0) - th * th) * (t(_C1) + t(3 * _C3) * z * z)


def phi_cdf(z: np.ndarray) -> np.ndarray:
    """Standard normal CDF, tanh approximation (|error| < 2e-4; one transcendental call)."""
    h = z.dtype.type(0.5)
    return h + h * _tanh(z)


def phi_and_density(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tanh form of the normal CDF (:func:`phi_cdf`) and its exact derivative (the
    normal density in the same form, so that a model built from both is consistent)."""
    th = _tanh(z)
    h = z.dtype.type(0.5)
    return h + h * th, _density(z, th)


def correlation_terms(z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's first- and second-order terms in the blur's correlation along one axis.

    With ``h1 = φ`` and ``h2(α) = α φ(α)`` (α = −z) differenced across each cell, a cell's
    box blurred by a bivariate normal of correlation rho is the product of its two marginal
    boxes plus ``rho · D1(u) D1(v) + rho² / 2 · D2(u) D2(v)`` (the tetrachoric series).

    Args:
        z: (..., boundaries, M) the standardised distances to the cell boundaries.
        p: φ at ``z`` (:func:`phi_and_density`).

    Returns:
        (D1, D2), each (..., boundaries - 1, M): per cell, far side minus near side.
    """
    q = z * p
    return p[..., 1:, :] - p[..., :-1, :], q[..., :-1, :] - q[..., 1:, :]


def code_coords(g: np.ndarray, x: np.ndarray, y: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where samples lie in each code's cells.

    Args:
        g: (C, 8) homographies, local normalised frame -> cells.
        x, y: (C, M) the samples' local normalised coordinates.

    Returns:
        (u, v: (C, M) cells; 1 / D: (C, M) the inverse of the homography's denominator).
    """
    invD = 1.0 / (g[:, 6, None] * x + g[:, 7, None] * y + 1.0)
    return ((g[:, 0, None] * x + g[:, 1, None] * y + g[:, 2, None]) * invD,
            (g[:, 3, None] * x + g[:, 4, None] * y + g[:, 5, None]) * invD, invD)


def g_to_matrix(g: np.ndarray) -> np.ndarray:
    """(C, 3, 3) matrices of (C, 8) homography parameters (the last entry 1)."""
    C = g.shape[0]
    H = np.ones((C, 3, 3))
    H[:, 0] = g[:, 0:3]
    H[:, 1] = g[:, 3:6]
    H[:, 2, :2] = g[:, 6:8]
    return H


def inverse_3x3(H: np.ndarray) -> np.ndarray:
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


def solve_batched(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solutions (C, k) of C linear systems A (C, k, k) x = b (C, k); a singular system (or a
    non-finite solution) gives zeros."""
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


def model(g: np.ndarray, lev: np.ndarray, s: np.ndarray, x: np.ndarray, y: np.ndarray,
          bits: np.ndarray, bits_t: np.ndarray, n_max: int, jacobian: bool = True,
          blur_jacobian: bool = True, rho: np.ndarray | None = None
          ) -> tuple[np.ndarray, np.ndarray | None]:
    """Model intensity (C, M) and, with ``jacobian``, its transposed Jacobian (C, 13, M)
    (the last row: d/d rho, zero without ``rho``).

    Args:
        g: (C, 8) homographies, local normalised frame -> cells.
        lev: (C, 2) black and white levels, grey levels.
        s: (C, 2) blur along u and v, cells.
        x, y: (C, M) the samples' local normalised coordinates.
        bits: (C, n_max - 2, n_max - 2) the *inner* cells (row, column), zero-padded, float32;
            the border is black (0), so only the inner cells and the boundaries
            1 .. n_max - 1 between them contribute.
        bits_t: Their transpose (column, row).
        n_max: Cells per side (border included) of the largest code.
        jacobian: Also return the Jacobian (parameters g, B, W, s_u, s_v, rho).
        blur_jacobian: Fill the blur's rows of the Jacobian (zeros otherwise).
        rho: (C,) correlation of the blur's u and v (an oblique view or a motion streak
            makes the blur an ellipse whose axes are not the code's): each cell's blurred
            box is the bivariate normal's, by its tetrachoric series to the second order in
            rho (separable terms; 0.3 % of the contrast at rho 0.5).

    The heavy arrays are laid out (C, 2, boundaries, M) (u/v, cell boundary, sample) in
    float32 so that every reduction runs over a middle axis with contiguous samples.
    """
    u, v, invD = code_coords(g, x, y)
    uv = np.stack([u, v], axis=1)
    k = np.arange(1, n_max, dtype=np.float32)[:, None]
    inv_s = (1.0 / s).astype(np.float32)[:, :, None, None]  # (C, 2, 1, 1)
    z = (uv.astype(np.float32)[:, :, None, :] - k) * inv_s  # (C, 2, n - 1, M)
    th = _tanh(z)
    A = np.float32(0.5) + np.float32(0.5) * th  # Phi(z), as phi_cdf
    w = A[:, :, :-1] - A[:, :, 1:]  # (C, 2, n - 2, M): inner column j (u) / row r (v)
    col, row = w[:, 0], w[:, 1]
    T = np.matmul(bits_t, row)  # (C, n, M): T[j] = sum_r bits[r, j] row_r
    S = (T * col).sum(axis=1, dtype=np.float64)
    # the exact derivative of the tanh form of Phi (consistent with the model, no exp)
    pz = _density(z, th) if jacobian or rho is not None else None
    corr = None if rho is None or pz is None else _correlated(z, pz, bits_t, rho)
    if corr is not None:
        S = S + corr[0]
    B, W = lev[:, 0, None], lev[:, 1, None]
    amp = W - B
    I = B + amp * S
    if not jacobian:
        return I, None
    assert pz is not None  # computed for the Jacobian
    Tv = np.matmul(bits, col)  # (C, n, M): Tv[r] = sum_j bits[r, j] col_j
    dw = (pz[:, :, :-1] - pz[:, :, 1:]) * inv_s  # d w / d (u or v)
    dS = np.empty((x.shape[0], 2, x.shape[1]))  # dS/du, dS/dv
    dS[:, 0] = (T * dw[:, 0]).sum(axis=1, dtype=np.float64)
    dS[:, 1] = (Tv * dw[:, 1]).sum(axis=1, dtype=np.float64)
    if corr is not None:
        dS += corr[1] * (1.0 / s)[:, :, None]
    if blur_jacobian:
        qz = pz * z
        dws = (qz[:, :, 1:] - qz[:, :, :-1]) * inv_s  # d/ds Phi((u-k)/s) = -phi z / s
        dSs = np.empty_like(dS)  # dS/dsu, dS/dsv
        dSs[:, 0] = (T * dws[:, 0]).sum(axis=1, dtype=np.float64)
        dSs[:, 1] = (Tv * dws[:, 1]).sum(axis=1, dtype=np.float64)
    else:
        dSs = np.zeros_like(dS)
    J = np.empty((x.shape[0], 13, x.shape[1]))
    J[:, 12] = 0.0 if corr is None else amp * corr[2]
    a = (amp * invD)[:, None] * dS  # (C, 2, M)
    a_u, a_v = a[:, 0], a[:, 1]
    J[:, 0] = a_u * x
    J[:, 1] = a_u * y
    J[:, 2] = a_u
    J[:, 3] = a_v * x
    J[:, 4] = a_v * y
    J[:, 5] = a_v
    wq = -(a_u * u + a_v * v)
    J[:, 6] = wq * x
    J[:, 7] = wq * y
    J[:, 8] = 1.0 - S
    J[:, 9] = S
    J[:, 10:12] = amp[:, None] * dSs
    return I, J


def _correlated(z: np.ndarray, p: np.ndarray, bits_t: np.ndarray, rho: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cells' blurred boxes' terms in the blur's correlation ``rho``
    (:func:`correlation_terms`), summed over the code's white cells.

    Args:
        z: (C, 2, n - 1, M) the standardised distances to the cell boundaries (model's).
        p: φ at ``z`` in the model's tanh form (its Φ's derivative, so that rho = 0 is the
            model exactly).
        bits_t: (C, n - 2, n - 2) the inner cells, transposed (column, row).
        rho: (C,) the correlation.

    Returns:
        (the terms' sum (C, M); their derivative along u and v times the blur, (C, 2, M),
        to the first order in rho; their derivative in rho (C, M)).
    """
    d1, d2 = correlation_terms(z, p)  # (C, 2, n - 2, M)
    T1 = np.matmul(bits_t, d1[:, 1])  # (C, n - 2, M): sum_r bits[r, j] D1_r(v)
    T2 = np.matmul(bits_t, d2[:, 1])
    s11 = (T1 * d1[:, 0]).sum(axis=1, dtype=np.float64)
    s22 = (T2 * d2[:, 0]).sum(axis=1, dtype=np.float64)
    r = rho[:, None]
    # d D1 / d(u or v) = D2 / s: the first-order term's derivative
    du = (T1 * d2[:, 0]).sum(axis=1, dtype=np.float64)
    dv = (T2 * d1[:, 0]).sum(axis=1, dtype=np.float64)
    return r * s11 + 0.5 * r * r * s22, np.stack([r * du, r * dv], axis=1), s11 + r * s22


def homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
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
    return solve_batched(A, b)
