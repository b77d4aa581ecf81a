"""Stages 1–4 of the dot detector on one frame: BGR → HSV, the palette's masks, morphology,
blobs, and the palette's V range judged on the CLAHE-equalised V of each blob.

Only the regions of a mask with colour pixels are cleaned and searched: bands of rows
separated by empty rows, each cut to its columns (padded: the morphology reaches no further,
so separate bands give the blobs of the whole mask).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from drovisio import _numba
from drovisio.detect.dots import color_kernels
from drovisio.detect.dots.blobs import BlobFilter, Blobs, find_blobs_multi
from drovisio.detect.dots.color import ClaheMap, ColorClassifier, clean_mask
from drovisio.detect.dots.config import DotsConfig
from drovisio.detect.dots.model import DotModel
from drovisio.layout import ColorSpec

__all__ = ["BlobFinder"]


class BlobFinder:
    """The candidate dot blobs of a frame, for a set of palette colours (one detector's).

    Args:
        specs: The distinct palette colours (at most 8); blob colour indices refer to them.
        models: The layouts' dot models (their largest dot bounds the blob size).
        f: Focal length, pixels.
        config: Settings.
    """

    def __init__(self, specs: list[ColorSpec], models: list[DotModel], f: float,
                 config: DotsConfig):
        cfg = self.config = config
        self.classifier = ColorClassifier(specs, v_floor=cfg.v_floor if cfg.clahe else None) \
            if specs else None
        self.blob_filter = BlobFilter()
        if models:
            d_max = max(float(m.radii.max()) for m in models) * 2
            max_px = f * d_max / cfg.min_distance_m
            self.blob_filter = BlobFilter(
                min_area=max(5.0, 0.55 * math.pi / 4 * cfg.min_dot_px ** 2),
                max_area=1.3 * math.pi / 4 * max_px ** 2,
                min_aspect=cfg.min_aspect, min_circularity=cfg.min_circularity,
                min_fill=cfg.min_fill, min_convexity=cfg.min_convexity,
                max_ellipse_err=cfg.max_ellipse_err, max_holes=cfg.max_holes)
        self._v_ranges = np.array([[s.hsv[0][2], s.hsv[1][2]] for s in specs], float) \
            if specs else np.zeros((0, 2))
        self._hsv: np.ndarray | None = None    # frame buffer, reused (no allocation per frame)

    def __call__(self, image_bgr: np.ndarray) -> tuple[Blobs, np.ndarray]:
        """The candidate dot blobs of a frame (H, W, 3) uint8 BGR, and its HSV image (in a
        buffer of the finder: valid until the next frame)."""
        assert self.classifier is not None, "no palette colours: nothing to look for"
        H, W = image_bgr.shape[:2]
        if self._hsv is None or self._hsv.shape[:2] != (H, W):
            self._hsv = np.empty((H, W, 3), np.uint8)
        hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV, self._hsv)
        cfg = self.config
        masks = [self._mask_parts(m, H, W) for m in self.classifier.masks(hsv, reuse=True)]
        blobs, _ = find_blobs_multi(masks, self.blob_filter,
                                    extra=(lambda b: self._clahe_ok(b, hsv)) if cfg.clahe
                                    else None, shape=(H, W))
        return blobs, hsv

    def _mask_parts(self, m: np.ndarray, H: int, W: int
                    ) -> list[tuple[np.ndarray, tuple[int, int]]] | None:
        """The cleaned regions of one colour's mask with their (x, y) offsets, or None."""
        pad = 2 * self.config.morph_kernel_px + 2
        # (REDUCE_SUM to int32: OpenCV 5's REDUCE_MAX on uint8 is ~100× slower)
        rows = np.flatnonzero(cv2.reduce(m, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel())
        if rows.size == 0:
            return None
        cut = np.flatnonzero(np.diff(rows) > 2 * pad + 1)
        parts = []
        for r0, r1 in zip([rows[0], *rows[cut + 1].tolist()], [*rows[cut].tolist(), rows[-1]]):
            y0, y1 = max(int(r0) - pad, 0), min(int(r1) + 1 + pad, H)
            x, _, w, _ = cv2.boundingRect(m[y0:y1])
            x0, x1 = max(x - pad, 0), min(x + w + pad, W)
            parts.append((clean_mask(m[y0:y1, x0:x1], self.config.morph_kernel_px), (x0, y0)))
        return parts

    def _clahe_ok(self, blobs: Blobs, hsv: np.ndarray) -> np.ndarray:
        """Blobs whose CLAHE-equalised V lies in their colour's V range."""
        cfg = self.config
        v = hsv[:, :, 2]
        H, W = v.shape
        tx, ty = cfg.clahe_tiles
        rng = self._v_ranges[blobs.color]
        if _numba.enabled() and W % tx == 0 and H % ty == 0 and hsv.flags.c_contiguous:
            eq = color_kernels.clahe_at(hsv, np.ascontiguousarray(blobs.x, np.float64),
                                        np.ascontiguousarray(blobs.y, np.float64), int(tx),
                                        int(ty), int(cfg.clahe_stride), float(cfg.clahe_clip))
            return (eq >= rng[:, 0] - 0.5) & (eq <= rng[:, 1] + 0.5)
        xi = np.clip(np.rint(blobs.x).astype(np.int64), 1, W - 2)
        yi = np.clip(np.rint(blobs.y).astype(np.int64), 1, H - 2)
        raw = (v[yi, xi].astype(np.float64) + v[yi - 1, xi] + v[yi + 1, xi] + v[yi, xi - 1]
               + v[yi, xi + 1]) / 5.0
        eq = ClaheMap(v, cfg.clahe_clip, cfg.clahe_tiles, cfg.clahe_stride)(blobs.x, blobs.y,
                                                                            raw)
        return (eq >= rng[:, 0] - 0.5) & (eq <= rng[:, 1] + 0.5)
