"""One decoded code in one frame, as it passes through the detector's stages."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drovisio.detect.corners import RefinedCode
from drovisio.layout import MarkerLayout

__all__ = ["BrickKey", "CodeDetection", "CodeOwner"]

CodeOwner = tuple[MarkerLayout, int, int]
"""Who owns a code id: (layout, instance, code slot of the layout)."""

BrickKey = tuple[str, int, int]
"""A brick of one frame: (layout name, instance, copy); copy 0 is the brick itself, 1, 2, ...
the copies of a code id read more than once (each posed on its own)."""


@dataclass
class CodeDetection:
    """One decoded code in one frame."""

    marker_id: int
    layout: MarkerLayout
    instance: int
    slot: int
    raw_corners: np.ndarray
    """(4, 2) OpenCV's corners, px."""
    refined: RefinedCode | None = None
    info: np.ndarray | None = None
    """(8, 8) inverse covariance of the refined corners (x0, y0, ... x3, y3), px⁻²."""
    guided: bool = False
    """Not read: fitted where its brick's pose put it (:mod:`.guided`), its bits known from
    the id. Not counted as read (duplicates, codes found)."""
