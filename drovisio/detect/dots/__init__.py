"""Colour-dot bricks: find bricks by the coloured dots painted on them, and their 6-DoF poses.

The public face of the colour-dot detector: :class:`DotDetector` (kept across frames) and
:func:`detect_dots` (one frame), their settings :class:`DotsConfig` and stream memory
:class:`DotsState`. The stages live in their own modules (see :mod:`.detector` for the order).
"""

from __future__ import annotations

from drovisio.detect.dots.detector import (
    DotDetector,
    DotsConfig,
    DotsInputError,
    DotsState,
    LayoutNotSupported,
    detect_dots,
)

__all__ = [
    "DotDetector",
    "DotsConfig",
    "DotsInputError",
    "DotsState",
    "LayoutNotSupported",
    "detect_dots",
]
