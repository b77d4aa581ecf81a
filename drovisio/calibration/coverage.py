"""Coverage of a calibration session: where the corners fell on the image, at which distances
and tilts.

* ``counts``: a grid heatmap (default 8 × 6 cells) of detected corners per cell.
* ``covered``: per cell, the fraction of its area that lies inside at least one board's
  outline (the convex hull of its corners) — a board sweeps area, not just its corners.
* ``regions``: the same fraction for the nine named regions of the image (a 3 × 3 split:
  ``top-left``, ``top``, ``top-right``, ``left``, ``centre``, ``right``, ``bottom-left``,
  ``bottom``, ``bottom-right``), so that messages can name them. A region counts as covered
  from :data:`REGION_COVERED` (30 %) of its area.
* ``distances_m`` / ``tilts_deg``: per view, the distance from the camera to the board's centre
  and the angle between the board's normal and the line of sight, from the board poses
  (solved, or estimated with a guessed camera before the first solve). Spreads: the ratio of
  the farthest to the nearest distance, and the range of tilts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio.calibration.board import Detection

__all__ = ["Coverage", "compute_coverage", "REGION_NAMES", "REGION_COVERED", "region_boxes",
           "region_of_point"]

REGION_NAMES = (("top-left", "top", "top-right"), ("left", "centre", "right"),
                ("bottom-left", "bottom", "bottom-right"))
REGION_COVERED = 0.3
_MASK_SCALE = 4  # hull mask at 1/4 resolution


def region_boxes(width: int, height: int) -> dict[str, tuple[float, float, float, float]]:
    """The nine named regions as (x0, y0, x1, y1) pixel boxes."""
    xs = np.linspace(0, width, 4)
    ys = np.linspace(0, height, 4)
    return {REGION_NAMES[r][c]: (float(xs[c]), float(ys[r]), float(xs[c + 1]), float(ys[r + 1]))
            for r in range(3) for c in range(3)}


def region_of_point(x: float, y: float, width: int, height: int) -> str:
    c = min(2, max(0, int(3 * x / width)))
    r = min(2, max(0, int(3 * y / height)))
    return REGION_NAMES[r][c]


@dataclass
class Coverage:
    """See the module docstring."""

    image_size: tuple[int, int]
    counts: np.ndarray
    covered: np.ndarray
    regions: dict[str, float]
    distances_m: list[float] = field(default_factory=list)
    tilts_deg: list[float] = field(default_factory=list)
    n_views: int = 0

    @property
    def grid_shape(self) -> tuple[int, int]:
        return self.counts.shape

    def uncovered_regions(self, threshold: float = REGION_COVERED) -> list[str]:
        """Named regions with less than ``threshold`` of their area covered, corners first."""
        order = ["top-left", "top-right", "bottom-left", "bottom-right", "top", "bottom", "left",
                 "right", "centre"]
        return [r for r in order if self.regions.get(r, 0.0) < threshold]

    @property
    def covered_fraction(self) -> float:
        return float(self.covered.mean()) if self.covered.size else 0.0

    def distance_spread(self) -> dict:
        d = [x for x in self.distances_m if math.isfinite(x)]
        if not d:
            return {"min_m": None, "max_m": None, "ratio": None}
        return {"min_m": min(d), "max_m": max(d), "ratio": max(d) / min(d)}

    def tilt_spread(self) -> dict:
        t = [x for x in self.tilts_deg if math.isfinite(x)]
        if not t:
            return {"min_deg": None, "max_deg": None, "range_deg": None}
        return {"min_deg": min(t), "max_deg": max(t), "range_deg": max(t) - min(t)}

    def to_json(self) -> dict:
        return {
            "views": self.n_views,
            "grid": {"cols": int(self.counts.shape[1]), "rows": int(self.counts.shape[0]),
                     "corner_counts": self.counts.astype(int).tolist(),
                     "covered_fraction": np.round(self.covered, 3).tolist()},
            "image_covered_fraction": round(self.covered_fraction, 4),
            "regions_covered_fraction": {k: round(v, 3) for k, v in self.regions.items()},
            "uncovered_regions": self.uncovered_regions(),
            "distances_m": [round(x, 4) for x in self.distances_m],
            "distance_spread": _round_dict(self.distance_spread()),
            "tilts_deg": [round(x, 2) for x in self.tilts_deg],
            "tilt_spread": _round_dict(self.tilt_spread()),
        }


def _round_dict(d: dict) -> dict:
    return {k: (None if v is None else round(float(v), 4)) for k, v in d.items()}


def hull_mask(detections: list[Detection], image_size: tuple[int, int]) -> np.ndarray:
    """Boolean mask (H/4, W/4) of the image area inside at least one board's corner hull."""
    w, h = image_size
    mw, mh = max(1, w // _MASK_SCALE), max(1, h // _MASK_SCALE)
    mask = np.zeros((mh, mw), np.uint8)
    for d in detections:
        if d.n < 3:
            continue
        pts = (d.corners / _MASK_SCALE).astype(np.float32)
        hull = cv2.convexHull(pts)
        cv2.fillConvexPoly(mask, np.round(hull).astype(np.int32).reshape(-1, 2), 1)
    return mask.astype(bool)


def compute_coverage(detections: list[Detection], image_size: tuple[int, int],
                     poses: list[tuple[float, float]] | None = None,
                     grid: tuple[int, int] = (8, 6)) -> Coverage:
    """Coverage of ``detections`` on an image of ``image_size`` = (width, height).

    Args:
        detections: The kept views' detections.
        image_size: (width, height).
        poses: Per view (distance m, tilt deg), or None.
        grid: (cols, rows) of the heatmap.
    """
    w, h = image_size
    gw, gh = grid
    counts = np.zeros((gh, gw), int)
    for d in detections:
        cx = np.clip((d.corners[:, 0] / w * gw).astype(int), 0, gw - 1)
        cy = np.clip((d.corners[:, 1] / h * gh).astype(int), 0, gh - 1)
        np.add.at(counts, (cy, cx), 1)
    mask = hull_mask(detections, image_size).astype(np.float32)
    mh, mw = mask.shape
    covered = cv2.resize(mask, (gw, gh), interpolation=cv2.INTER_AREA) if mask.size else \
        np.zeros((gh, gw))
    regions = {}
    for name, (x0, y0, x1, y1) in region_boxes(w, h).items():
        sub = mask[int(y0 / h * mh):max(int(y0 / h * mh) + 1, int(y1 / h * mh)),
                   int(x0 / w * mw):max(int(x0 / w * mw) + 1, int(x1 / w * mw))]
        regions[name] = float(sub.mean()) if sub.size else 0.0
    dist = [p[0] for p in poses] if poses else []
    tilt = [p[1] for p in poses] if poses else []
    return Coverage((w, h), counts, np.asarray(covered, float), regions, dist, tilt,
                    len(detections))
