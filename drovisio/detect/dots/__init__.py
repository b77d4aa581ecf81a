"""Colour-dot bricks: find bricks by the coloured dots painted on them, and their 6-DoF poses.

The public face of the colour-dot detector: :class:`DotDetector` (kept across frames) and
:func:`detect_dots` (one frame), their settings :class:`DotsConfig`, stream memory
:class:`DotsState` and per-stage times :class:`StageTimes`. The stages, in the order
:meth:`DotDetector.detect` runs them (:mod:`.detector`):

* :mod:`.candidates` — stages 1–4 on a frame: HSV, palette masks (:mod:`.color`), blobs
  (:mod:`.blobs`), CLAHE V per blob;
* :mod:`.match` — blobs to the layouts' dots (:mod:`.model`: a layout's dots as the
  detector sees them): pair-seeded hypotheses, greedy assignment;
* :mod:`.batch` — the matched bricks as one typed batch, sub-pixel centres on it;
* :mod:`.poses` — both planar solutions of every brick, solved again when its dots change;
* :mod:`.occlusion` — hidden dots, wrong blobs, missing dots;
* :mod:`.refine` — the perspective step (ellipse centres) and the checks;
* :mod:`.ambiguity` — the planar ambiguity and a symmetric layout's half-turn
  (:mod:`.stream`: the previous frame's bricks);
* :mod:`.bricks` — covariance and output.

Compiled kernels sit beside their stage (``*_kernels.py``; :mod:`.kernels` lists all of
them, the lens model's and the batched poses' included).
"""

from __future__ import annotations

from drovisio.detect.dots.color import DotsInputError
from drovisio.detect.dots.config import DotsConfig
from drovisio.detect.dots.detector import DotDetector, DotsState, StageTimes, detect_dots
from drovisio.detect.dots.model import LayoutNotSupported

__all__ = [
    "DotDetector",
    "DotsConfig",
    "DotsInputError",
    "DotsState",
    "LayoutNotSupported",
    "StageTimes",
    "detect_dots",
]
