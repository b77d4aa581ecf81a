"""Dot colours: a colour's HSV threshold range and paint colour, and the default palette."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictInt, field_validator

__all__ = ["ColorSpec", "DEFAULT_PALETTE", "HsvTriple", "BgrTriple"]

HsvTriple = tuple[StrictInt, StrictInt, StrictInt]
BgrTriple = tuple[StrictInt, StrictInt, StrictInt]


class ColorSpec(BaseModel):
    """A named dot colour: its HSV threshold range and optionally its paint colour.

    HSV is in OpenCV units: H 0-179, S and V 0-255. A range whose low hue exceeds its high
    hue wraps through 0 (red: H 170 -> 10).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    hsv: tuple[HsvTriple, HsvTriple] = Field(
        description="[[h, s, v] low, [h, s, v] high] in OpenCV units (H 0-179, S/V 0-255); "
        "low hue > high hue wraps through 0."
    )
    bgr: BgrTriple | None = Field(
        default=None, description="Optional paint/display colour [b, g, r], 0-255."
    )

    @field_validator("hsv")
    @classmethod
    def _check_hsv(cls, v: tuple[HsvTriple, HsvTriple]) -> tuple[HsvTriple, HsvTriple]:
        for which, (h, s, val) in zip(("low", "high"), v):
            if not 0 <= h <= 179:
                raise ValueError(f"{which} hue {h} is outside 0..179 (OpenCV hue units)")
            if not (0 <= s <= 255 and 0 <= val <= 255):
                raise ValueError(f"{which} saturation/value must be within 0..255")
        if v[0][1] > v[1][1] or v[0][2] > v[1][2]:
            raise ValueError("low saturation/value must not exceed high (only hue may wrap)")
        return v

    @field_validator("bgr")
    @classmethod
    def _check_bgr(cls, v: BgrTriple | None) -> BgrTriple | None:
        if v is not None and not all(0 <= c <= 255 for c in v):
            raise ValueError("bgr components must be within 0..255")
        return v

    @property
    def wraps(self) -> bool:
        """True when the hue range wraps through 0 (low hue > high hue)."""
        return self.hsv[0][0] > self.hsv[1][0]

    def cv_ranges(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Ranges for ``cv2.inRange`` (a wrapping hue range gives two).

        Returns:
            A list of ``(low, high)`` uint8 arrays of shape (3,), to OR together.
        """
        lo, hi = np.array(self.hsv[0], np.uint8), np.array(self.hsv[1], np.uint8)
        if not self.wraps:
            return [(lo, hi)]
        lo2, hi2 = lo.copy(), hi.copy()
        hi1 = hi.copy()
        hi1[0] = 179
        lo2[0] = 0
        return [(lo, hi1), (lo2, hi2)]

    def contains(self, hsv: Sequence[int]) -> bool:
        """Whether one OpenCV HSV pixel ``(h, s, v)`` falls inside this range."""
        h, s, v = (int(c) for c in hsv)
        (h0, s0, v0), (h1, s1, v1) = self.hsv
        hue_ok = (h0 <= h <= h1) if not self.wraps else (h >= h0 or h <= h1)
        return hue_ok and s0 <= s <= s1 and v0 <= v <= v1

    def display_bgr(self) -> tuple[int, int, int]:
        """``bgr`` if given, else a colour at the middle of the HSV range (for drawing)."""
        if self.bgr is not None:
            return self.bgr
        (h0, s0, v0), (h1, s1, v1) = self.hsv
        h = ((h0 + ((h1 - h0) % 180) / 2) % 180) if self.wraps else (h0 + h1) / 2
        px = np.array([[[round(h) % 180, (s0 + s1) // 2, (v0 + v1) // 2]]], np.uint8)
        b, g, r = cv2.cvtColor(px, cv2.COLOR_HSV2BGR)[0, 0]
        return int(b), int(g), int(r)

    def display_rgb(self) -> tuple[int, int, int]:
        """:meth:`display_bgr` in RGB order (viser, PDF, glTF, the web pages)."""
        b, g, r = self.display_bgr()
        return r, g, b


#: The default dot colours (OpenCV HSV units). Layouts may override or add colours.
#: Each paint ``bgr`` falls inside its own range and outside the others (tested).
DEFAULT_PALETTE: dict[str, ColorSpec] = {
    "red": ColorSpec(hsv=((170, 80, 70), (10, 255, 255)), bgr=(40, 40, 210)),
    "yellow": ColorSpec(hsv=((20, 80, 80), (35, 255, 255)), bgr=(30, 210, 230)),
    "green": ColorSpec(hsv=((40, 80, 60), (75, 255, 255)), bgr=(50, 170, 40)),
    "blue": ColorSpec(hsv=((80, 85, 75), (115, 255, 255)), bgr=(200, 120, 20)),
}
