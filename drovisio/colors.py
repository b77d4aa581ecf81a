"""Colour tuning for non-programmers: propose a palette entry (an HSV range) from pixels the
user points at.

The web tool lets an engineer click a few dots of one colour in a camera frame (or paint over
them); :func:`propose_color` turns those pixels into a :class:`~drovisio.layout.ColorSpec`
that the dot detector uses as is (``"colors": {"red": {"hsv": [[h, s, v], [h, s, v]]}}`` in a
layout file). :func:`propose_color_report` also says how well the range separates the
selection from the rest of the frame and from the other colours of a palette, so the tool can
warn ("this range also catches 3 % of the frame", "overlaps blue").

Conventions: OpenCV HSV units (H 0–179, S and V 0–255); a range whose low hue exceeds its
high hue wraps through 0 (red). Like the detector (:mod:`drovisio.detect.dots`), V is measured
after CLAHE on V by default, because that is where the detector judges a colour's V range.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

from drovisio.detect.dots.color import clahe_value
from drovisio.layout import ColorSpec

__all__ = ["ColorProposal", "propose_color", "propose_color_report", "selection_mask"]


@dataclass
class ColorProposal:
    """A proposed palette entry and how well it works on the frame it came from.

    Attributes:
        spec: The proposed colour range (and paint colour: the selection's median BGR).
        pixels: Selected pixels that were used (colourful enough).
        ignored: Selected pixels left out (too grey or too dark: edges, glare, shadow).
        hue_center: Circular median hue of the selection (OpenCV units).
        inside_selection: Share of the used pixels inside the range.
        inside_rest: Share of the other pixels of the frame inside the range (false alarms).
        overlaps: Palette colours whose range shares pixels of the selection with this one.
        warnings: Plain-language remarks for the user.
    """

    spec: ColorSpec
    pixels: int
    ignored: int
    hue_center: float
    inside_selection: float
    inside_rest: float
    overlaps: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def selection_mask(shape: tuple[int, int], points_or_mask: ArrayLike, radius: float = 3.0
                   ) -> np.ndarray:
    """The pixels a user selected, as a bool mask.

    Args:
        shape: (H, W) of the frame.
        points_or_mask: An (H, W) mask (bool or 0/non-zero), or (x, y) pixel positions the user
            clicked (a sequence of pairs or an (N, 2) array).
        radius: With points: the disc of pixels taken around each point.

    Raises:
        ValueError: a mask of another size, or points that are not (x, y) pairs.
    """
    H, W = shape
    arr = np.asarray(points_or_mask)
    if arr.ndim == 2 and arr.shape == (H, W) and (arr.dtype == bool or W != 2):
        return arr.astype(bool)
    if arr.ndim == 2 and arr.shape[1] == 2:
        pts = arr.astype(np.float64)
    elif arr.ndim == 1 and arr.size == 2:
        pts = arr.astype(np.float64)[None]
    else:
        raise ValueError(f"points_or_mask: expected an {H}×{W} mask or (x, y) points, got an "
                         f"array of shape {arr.shape}")
    mask = np.zeros((H, W), np.uint8)
    r = max(0, round(radius))
    for x, y in pts:
        if np.isfinite(x) and np.isfinite(y):
            cv2.circle(mask, (round(x), round(y)), r, 1, -1)
    return mask.astype(bool)


def _circular_hue(h: np.ndarray) -> tuple[float, np.ndarray]:
    """Circular centre of OpenCV hues and each hue's signed offset from it (−90..90]."""
    ang = h.astype(np.float64) * (2 * np.pi / 180.0)
    c = float(np.degrees(np.arctan2(np.sin(ang).mean(), np.cos(ang).mean())) / 2.0) % 180.0
    off = (h.astype(np.float64) - c + 90.0) % 180.0 - 90.0
    med = float(np.median(off))            # robust: recentre on the median offset
    c = (c + med) % 180.0
    off = (h.astype(np.float64) - c + 90.0) % 180.0 - 90.0
    return c, off


def _inside(hsv: np.ndarray, spec: ColorSpec) -> np.ndarray:
    masks = [cv2.inRange(hsv, lo, hi) for lo, hi in spec.cv_ranges()]
    m = masks[0]
    for r in masks[1:]:
        m = cv2.bitwise_or(m, r)
    return np.asarray(m > 0)


def _frame_hsv(image_bgr: np.ndarray, clahe: bool) -> tuple[np.ndarray, np.ndarray]:
    """The frame as (H, W, 3) uint8 BGR and its HSV (V after CLAHE when ``clahe``)."""
    img = np.asarray(image_bgr)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError("propose_color: needs an (H, W, 3) uint8 BGR colour image (the "
                         "camera's frame), got " + f"{img.dtype} {img.shape}")
    if img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    if clahe:
        hsv = clahe_value(hsv)
    return img, hsv


def _hue_range(h: np.ndarray, hue_margin: int, min_hue_width: int) -> tuple[float, int, int]:
    """Circular centre of the hues ``h`` and the proposed range's low and high hue (OpenCV
    units; low > high wraps through 0)."""
    center, off = _circular_hue(h)
    lo_off, hi_off = np.percentile(off, [2, 98])
    lo_h = center + lo_off - hue_margin
    hi_h = center + hi_off + hue_margin
    if hi_h - lo_h < min_hue_width:
        mid = (hi_h + lo_h) / 2
        lo_h, hi_h = mid - min_hue_width / 2, mid + min_hue_width / 2
    if hi_h - lo_h >= 179:
        raise ValueError("propose_color: the selected pixels have every hue; select pixels of "
                         "one dot colour only")
    return center, int(np.floor(lo_h)) % 180, int(np.ceil(hi_h)) % 180


def _overlaps(use: np.ndarray, palette: Mapping[str, ColorSpec], exclude: Sequence[str]
              ) -> tuple[list[str], list[str]]:
    """Palette colours catching over 2 % of the used pixels ((N, 3) HSV), with a warning
    for each."""
    overlaps, warnings = [], []
    for name, other in palette.items():
        if name in exclude:
            continue
        share = float(_inside(use[None, :, :], other).mean())
        if share > 0.02:
            overlaps.append(name)
            warnings.append(f"{100 * share:.0f} % of the selected pixels are also in the "
                            f"'{name}' range: the two colours would be confused")
    return overlaps, warnings


def _range_warnings(in_rest: float, in_sel: float) -> list[str]:
    """Warnings on the shares of the rest of the frame and of the selection in the range."""
    warnings = []
    if in_rest > 0.01:
        warnings.append(f"the range also covers {100 * in_rest:.1f} % of the rest of the frame: "
                        "expect many candidate blobs (a more distinct paint helps)")
    if in_sel < 0.9:
        warnings.append(f"only {100 * in_sel:.0f} % of the selected pixels fall in the range: "
                        "the selection mixes colours")
    return warnings


def propose_color_report(image_bgr: np.ndarray, points_or_mask: ArrayLike, radius: float = 3.0,
                         hue_margin: int = 4, min_hue_width: int = 8,
                         sat_floor: int = 40, val_floor: int = 40, clahe: bool = True,
                         palette: Mapping[str, ColorSpec] | None = None,
                         exclude: Sequence[str] = ()) -> ColorProposal:
    """Propose an HSV range for the pixels a user pointed at, and judge it on the frame.

    The hue range is the central 96 % of the selection's hues around their circular median,
    widened by ``hue_margin`` (it may wrap through 0); the lower S and V bounds are set well
    below the selection's 5th percentiles (so that the same paint in shade still passes),
    never below ``sat_floor`` / ``val_floor``; the upper bounds are 255.

    Args:
        image_bgr: The frame, (H, W, 3) uint8 BGR.
        points_or_mask: Where the user pointed (see :func:`selection_mask`).
        radius: Disc radius around each point, pixels.
        hue_margin: Hue levels added on each side of the observed spread.
        min_hue_width: Narrowest hue range proposed.
        sat_floor: Lowest S bound proposed (greys have low saturation).
        val_floor: Lowest V bound proposed.
        clahe: Measure V after CLAHE on V, as the dot detector judges it.
        palette: Other colours, to report overlaps with (e.g. ``layout.palette()``).
        exclude: Names in ``palette`` not to compare with (the colour being re-tuned).

    Returns:
        The proposal and its diagnostics.

    Raises:
        ValueError: not a colour image, nothing selected, or the selection is not colourful
            (greys, white, black cannot be told apart by hue); the message says what to do.
    """
    img, hsv = _frame_hsv(image_bgr, clahe)
    sel = selection_mask(img.shape[:2], points_or_mask, radius)
    n_sel = int(sel.sum())
    if n_sel == 0:
        raise ValueError("propose_color: no pixel selected (are the points inside the "
                         f"{img.shape[1]}×{img.shape[0]} image?); click on the dots")
    px = hsv[sel]
    colourful = (px[:, 1] >= sat_floor) & (px[:, 2] >= val_floor)
    if colourful.sum() < max(3, 0.2 * n_sel):
        med_s = int(np.median(px[:, 1]))
        raise ValueError(f"propose_color: the selected pixels are not colourful (median "
                         f"saturation {med_s}/255): grey, white or black cannot be told apart "
                         "from the ground by colour; choose a saturated paint for dots")
    use = px[colourful]
    center, lo_h, hi_h = _hue_range(use[:, 0], hue_margin, min_hue_width)
    s5, v5 = np.percentile(use[:, 1], 5), np.percentile(use[:, 2], 5)
    lo_s = int(max(sat_floor, np.floor(0.6 * s5)))
    lo_v = int(max(val_floor, np.floor(0.5 * v5)))
    bgr = tuple(int(c) for c in np.median(img[sel][colourful], axis=0))
    spec = ColorSpec(hsv=((lo_h, lo_s, lo_v), (hi_h, 255, 255)), bgr=bgr)
    inside = _inside(hsv, spec)
    in_sel = float(inside[sel][colourful].mean())
    rest = ~sel
    in_rest = float(inside[rest].mean()) if rest.any() else 0.0
    overlaps, warnings = _overlaps(use, palette or {}, exclude)
    warnings += _range_warnings(in_rest, in_sel)
    ignored = n_sel - int(colourful.sum())
    if ignored > 0.5 * n_sel:
        warnings.append(f"{ignored} of {n_sel} selected pixels were too grey or dark and were "
                        "left out (click the dots' centres)")
    return ColorProposal(spec=spec, pixels=int(colourful.sum()), ignored=ignored,
                         hue_center=center, inside_selection=in_sel, inside_rest=in_rest,
                         overlaps=overlaps, warnings=warnings)


def propose_color(image_bgr: np.ndarray, points_or_mask: ArrayLike, radius: float = 3.0,
                  **options: Any) -> ColorSpec:
    """Propose a palette entry (HSV range and paint colour) from pixels the user points at.

    Args:
        image_bgr: The frame, (H, W, 3) uint8 BGR.
        points_or_mask: (x, y) clicks on dots of one colour, or an (H, W) mask of them.
        radius: Disc radius around each click, pixels.
        **options: See :func:`propose_color_report`.

    Returns:
        The :class:`~drovisio.layout.ColorSpec` to put in a layout's ``colors``.

    Raises:
        ValueError: see :func:`propose_color_report`.
    """
    return propose_color_report(image_bgr, points_or_mask, radius, **options).spec
