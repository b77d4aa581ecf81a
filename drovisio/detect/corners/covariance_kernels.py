"""Compiled kernel of the fit's covariance (:func:`.covariance.parameter_covariance`), numba.

The sandwich's middle sums each sample's score against its neighbours' through a Gaussian of
their distance. Densely that is every pair of a code's samples (40 000 for 200 samples, a
few passes of numpy over each); within four widths, where the kernel is not yet below
3·10⁻⁴, lie a few hundred. This kernel walks each code's samples in order along x and sums
only the pairs within the cut, the numpy reference (:func:`.covariance._kernel_scores`)
every pair with the same cut.
"""

from __future__ import annotations

import numpy as np

from drovisio._numba import jit

__all__ = ["kernel_scores"]


@jit
def kernel_scores(p, score, cut2):
    """Each sample's score smoothed over its code's samples: ``H[c, i] = Σ_j w_ij
    score[c, j]`` with ``w_ij = exp(-|p_i - p_j|² / 2)`` where ``|p_i - p_j|² < cut2``
    (else 0).

    Args:
        p: (C, M, 2) float32 samples' positions in kernel widths.
        score: (C, M, k) float32 scores, a row per sample (zero where no sample is).
        cut2: The squared distance beyond which a pair is left out.

    Returns:
        (C, M, k) float32.
    """
    C, M, k = score.shape
    out = score.copy()
    cut = np.float32(np.sqrt(cut2))
    live = np.zeros(M, np.bool_)
    for c in range(C):
        for i in range(M):
            live[i] = False
            for a in range(k):
                if score[c, i, a] != 0.0:
                    live[i] = True
                    break
        # along x in order: a pair farther apart in x than the cut ends the inner loop
        order = np.argsort(p[c, :, 0])
        for ii in range(M):
            i = order[ii]
            if not live[i]:
                continue
            xi = p[c, i, 0]
            yi = p[c, i, 1]
            for jj in range(ii + 1, M):
                j = order[jj]
                dx = p[c, j, 0] - xi
                if dx >= cut:
                    break
                if not live[j]:
                    continue
                dy = yi - p[c, j, 1]
                d2 = dx * dx + dy * dy
                if d2 < cut2:
                    w = np.float32(np.exp(np.float32(-0.5) * d2))
                    for a in range(k):
                        out[c, i, a] += w * score[c, j, a]
                        out[c, j, a] += w * score[c, i, a]
    return out
