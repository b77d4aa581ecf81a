"""One marker of a design, in the mesh frame (metres)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["DesignMarker"]


@dataclass(frozen=True)
class DesignMarker:
    """One marker of the design, in the **mesh frame**, metres.

    Attributes:
        kind: ``"aruco"`` (a printed code) or ``"dot"`` (a colour dot).
        center: centre on the surface.
        normal: unit direction the printed face looks toward (the face's outward normal).
        up: unit in-plane direction toward the printed image's top edge (codes); for dots
            only the reference of the face's grid.
        size: code side (outer black border) or dot diameter.
        slot: the code's slot in the id block (codes only).
        color: dot colour name (dots only).
        face: index of the flat face it lies on (None: not found on the surface).
    """

    kind: Literal["aruco", "dot"]
    center: tuple[float, float, float]
    normal: tuple[float, float, float]
    up: tuple[float, float, float]
    size: float
    slot: int | None = None
    color: str | None = None
    face: int | None = None

    @property
    def c(self) -> np.ndarray:
        """``center`` as a (3,) float64 array."""
        return np.array(self.center, np.float64)

    @property
    def n(self) -> np.ndarray:
        """``normal`` as a (3,) float64 array."""
        return np.array(self.normal, np.float64)

    @property
    def u(self) -> np.ndarray:
        """``up`` as a (3,) float64 array."""
        return np.array(self.up, np.float64)

    @property
    def code_slot(self) -> int:
        """``slot`` of a code (every code has one; a dot has none)."""
        if self.slot is None:
            raise ValueError(f"this {self.kind} marker has no slot")
        return self.slot

    @property
    def dot_color(self) -> str:
        """``color`` of a dot (every dot has one; a code has none)."""
        if self.color is None:
            raise ValueError(f"this {self.kind} marker has no colour")
        return self.color

    @property
    def r(self) -> np.ndarray:
        """Unit direction toward the printed image's right edge (``up x normal``)."""
        return np.cross(self.u, self.n)

    def label(self, index: int) -> str:
        """Short name used in the panel and in warnings, e.g. ``"code 0"``, ``"dot 3 (red)"``
        (``index`` counts dots from 1 among all markers)."""
        if self.kind == "aruco":
            return f"code {self.slot}"
        return f"dot {index} ({self.color})"

    def outline(self, samples: int = 8) -> np.ndarray:
        """Points on and inside the marker's printed shape (mesh frame), for face tests."""
        c, r, u = self.c, self.r, self.u
        h = self.size / 2.0
        if self.kind == "aruco":
            t = np.linspace(-1.0, 1.0, samples + 1)
            gx, gy = np.meshgrid(t, t)
            pts = np.stack([gx.ravel(), gy.ravel()], axis=1) * h
        else:
            ang = np.linspace(0, 2 * np.pi, 4 * samples, endpoint=False)
            ring = np.stack([np.cos(ang), np.sin(ang)], axis=1) * h
            pts = np.concatenate([ring, ring * 0.5, [[0.0, 0.0]]])
        return c + pts[:, :1] * r + pts[:, 1:] * u

    def corners(self) -> np.ndarray:
        """A code's corners TL, TR, BR, BL (OpenCV order; mesh frame)."""
        c, r, u, h = self.c, self.r, self.u, self.size / 2.0
        return np.array([c - r * h + u * h, c + r * h + u * h, c + r * h - u * h,
                         c - r * h - u * h])
