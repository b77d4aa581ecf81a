"""Stage 1, OpenCV's pass: quads from the thresholded image and the bits read in them.

OpenCV's ``ArucoDetector`` with the parameters of :class:`ArucoParams`' first group (one
small adaptive-threshold window, a stricter threshold constant, 8 samples per cell, no
candidate under 11 px), over a dictionary of exactly our ids (:mod:`.families`). Its corners
are not refined here (the corner fit does it); the quads it found but could not read go to
the rescue.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drovisio.detect.aruco.codes import CodeDetection
from drovisio.detect.aruco.families import CodeFamily

__all__ = ["opencv_codes"]


def opencv_codes(gray: np.ndarray, family: CodeFamily
                 ) -> tuple[list[CodeDetection], Sequence[np.ndarray] | None]:
    """The codes of one family OpenCV reads in a grey frame, and the quads it rejected.

    Args:
        gray: (H, W) uint8 frame.
        family: The family's detector and owners.

    Returns:
        (codes with their (4, 2) corners in px, OpenCV's rejected candidates: each (1, 4, 2)
        px, or None).
    """
    corners, idx, rejected = family.detector.detectMarkers(gray)
    codes: list[CodeDetection] = []
    if idx is not None:
        for c, i in zip(corners, np.ravel(idx)):
            mid = int(family.ids[int(i)])
            lay, k, slot = family.owners[mid]
            codes.append(CodeDetection(mid, lay, k, slot, np.asarray(c, np.float64).reshape(4, 2)))
    return codes, rejected
