"""Stage 4, the corner fit: every decoded code's corners, unbiased, with their covariance.

All codes of the frame are refined in one batch by :func:`drovisio.detect.corners.refine_codes`
(a photometric fit of the code's interior, unbiased by the outer edge's surroundings),
starting from OpenCV's corners moved outward by their measured bias. A code the model does
not fit, or whose cells do not read back as its bits (a decoy, a partly hidden code), is
marked not ``ok`` there; one whose interior is no flat square of its border but whose cells
read right at its outer edge lines is kept there (``RefinedCode.edge_lines``). The corners'
information matrices (inverse covariances) go to the
pose.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from drovisio.camera import Camera
from drovisio.detect.aruco.codes import CodeDetection
from drovisio.detect.aruco.families import CodeFamily
from drovisio.detect.aruco.params import ArucoParams
from drovisio.detect.corners import refine_codes
from drovisio.layout import aruco_code_bits

__all__ = ["CORNER_FLOOR_PX", "corner_covariance", "fit_corners", "fit_starts"]

CORNER_FLOOR_PX = 0.03
"""Least standard deviation of a fitted corner, px per axis: no fit places a corner better,
however many pixels it fits."""


def corner_covariance(cov_px: np.ndarray, params: ArucoParams) -> np.ndarray:
    """The covariance the pose uses for a fit's corners: the fit's own, scaled to the
    measured noise, with the floor.

    Args:
        cov_px: (..., 8, 8) the fit's covariance of (x0, y0, ... x3, y3), px².
        params: The detector's tuning (``corner_noise_scale``).

    Returns:
        (..., 8, 8) covariance, px².
    """
    return cov_px * params.corner_noise_scale ** 2 + np.eye(8) * CORNER_FLOOR_PX ** 2


def fit_starts(raw_corners: np.ndarray, expand_px: float) -> np.ndarray:
    """Starts of the fit: OpenCV's corners sit inside the code by a known amount, so each
    corner is moved outward along its diagonal.

    Args:
        raw_corners: (C, 4, 2) corners, px.
        expand_px: How far each corner moves, px.

    Returns:
        (C, 4, 2) starts, px.
    """
    q = raw_corners
    d = q - q.sum(axis=1, keepdims=True) * 0.25
    return q + expand_px * d / np.sqrt((d * d).sum(axis=2, keepdims=True))


def fit_corners(gray: np.ndarray, codes: list[CodeDetection], camera: Camera,
                params: ArucoParams, family_of: Mapping[int, CodeFamily]) -> None:
    """Refine the corners of a frame's codes in place (``refined`` and ``info`` of each).

    Args:
        gray: (H, W) uint8 frame.
        codes: The codes decoded in it (not empty).
        camera: The camera of the frame.
        params: The detector's tuning (the corner fit's group).
        family_of: Code id -> its family (its code bits and tolerated bit errors).
    """
    p = params
    starts = fit_starts(np.array([c.raw_corners for c in codes]), p.initial_expand_px)
    bits = [aruco_code_bits(family_of[c.marker_id].dvalue, c.marker_id).astype(np.float64)
            for c in codes]
    ref = refine_codes(gray, camera, starts, bits,
                       iterations=p.refine_iterations,
                       coarse_iterations=p.refine_coarse_iterations,
                       lm_lambda=p.refine_lambda,
                       max_samples=p.max_samples,
                       band_px=p.band_px,
                       outer_edge=p.outer_edge, edge_fallback=True,
                       tolerable_cells=np.array([family_of[c.marker_id].rescue_errors
                                                 for c in codes]))
    # the corners' information matrices (inverse covariances) for the pose
    cov = corner_covariance(np.array([r.cov_px for r in ref]), p)
    try:
        info = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        info = np.array([np.linalg.pinv(c_) for c_ in cov])
    for c, r, w in zip(codes, ref, info):
        c.refined = r
        c.info = w
