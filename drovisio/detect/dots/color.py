"""Colour stages of the dot detector: input check, BGR→HSV, CLAHE on V, palette thresholds,
morphology.

The thesis's stages are here as small functions (:func:`to_hsv`, :func:`clahe_value`,
:func:`threshold_color`, :func:`clean_mask`), and two faster equivalents the detector runs:

* :class:`ColorClassifier` thresholds every palette colour at once with three table look-ups
  (hue, saturation, value → one bit per colour). With ``v_floor=None`` its masks are exactly
  those of :func:`threshold_color` (``cv2.inRange`` per range, red's hue wrap included).
* :class:`ClaheMap` is CLAHE on V (OpenCV's algorithm: tiles, clip limit, redistribution,
  bilinear blending of the tile tables) evaluated only where it is needed. The detector judges
  the palette's V range on the CLAHE-equalised V of each blob, not on every pixel: the pixel
  masks only require a low V floor. This keeps the thesis's lighting normalisation for a small
  fraction of a full-frame CLAHE's cost.

HSV is in OpenCV units: H 0–179, S and V 0–255.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import cv2
import numpy as np

from drovisio.layout import ColorSpec

__all__ = [
    "ClaheMap",
    "ColorClassifier",
    "DotsInputError",
    "check_image",
    "clahe_value",
    "clean_mask",
    "threshold_color",
    "to_hsv",
]


class DotsInputError(ValueError):
    """An image the dot detector cannot use at all (the message says why and what to pass)."""


def check_image(image) -> tuple[np.ndarray | None, str | None]:
    """Validate a frame and bring it to 8-bit BGR.

    Args:
        image: An (H, W, 3) BGR or (H, W, 4) BGRA uint8 array; (H, W) / (H, W, 1) greyscale and
            uint16 are accepted too.

    Returns:
        ``(bgr, None)`` for a usable colour image, or ``(None, reason)`` for an image in which
        colour dots cannot be seen at all (greyscale, smaller than 4×4 pixels).

    Raises:
        DotsInputError: not an image (None, not an array, wrong shape, float or other dtype).
    """
    if image is None:
        raise DotsInputError("no image given (None); pass an (H, W, 3) uint8 BGR array, e.g. "
                             "cv2.imread(path)")
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.dtype != np.uint8:
        raise DotsInputError(f"image dtype is {img.dtype}; the dot detector needs 8-bit BGR "
                             "(uint8): convert floats with np.clip(img * 255, 0, 255)"
                             ".astype(np.uint8)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return None, ("greyscale image: colour dots cannot be told apart without colour; "
                      "give the camera's colour (BGR) frames")
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise DotsInputError(f"image has shape {img.shape}; expected (H, W, 3) BGR or "
                             "(H, W, 4) BGRA")
    if img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if img.shape[0] < 4 or img.shape[1] < 4:
        return None, f"image of {img.shape[1]}×{img.shape[0]} pixels is too small for dots"
    if not img.flags.c_contiguous:
        img = np.ascontiguousarray(img)
    return img, None


def to_hsv(image_bgr: np.ndarray) -> np.ndarray:
    """Stage 1: BGR → HSV (OpenCV units). Greyscale input gives S = 0 everywhere."""
    img = np.asarray(image_bgr)
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 1):
        img = cv2.cvtColor(img.reshape(img.shape[:2]), cv2.COLOR_GRAY2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return cv2.cvtColor(img, cv2.COLOR_BGR2HSV)


def clahe_value(hsv: np.ndarray, clip_limit: float = 2.0,
                tile_grid: tuple[int, int] = (8, 8)) -> np.ndarray:
    """Stage 2: CLAHE on the V channel (a new HSV image; H and S unchanged).

    Args:
        hsv: (H, W, 3) uint8 HSV image.
        clip_limit: CLAHE's contrast limit (OpenCV's ``clipLimit``).
        tile_grid: Tiles across and down (OpenCV's ``tileGridSize``).
    """
    out = hsv.copy()
    clahe = cv2.createCLAHE(clipLimit=float(clip_limit), tileGridSize=tuple(tile_grid))
    out[:, :, 2] = clahe.apply(np.ascontiguousarray(hsv[:, :, 2]))
    return out


def threshold_color(hsv: np.ndarray, spec: ColorSpec) -> np.ndarray:
    """Stage 3: the pixels inside a palette colour's HSV range (255) as a uint8 mask.

    A range whose low hue exceeds its high hue wraps through 0 (red: 170 → 10): the two
    ``cv2.inRange`` masks are OR-ed.
    """
    mask = None
    for lo, hi in spec.cv_ranges():
        m = cv2.inRange(hsv, lo, hi)
        mask = m if mask is None else cv2.bitwise_or(mask, m)
    assert mask is not None, "a palette colour has at least one range"
    return mask


def clean_mask(mask: np.ndarray, kernel_px: int = 3) -> np.ndarray:
    """Stage 4: morphological opening (drops isolated pixels) then closing (fills pin-holes).

    Args:
        mask: uint8 binary mask.
        kernel_px: Diameter of the elliptic structuring element (3 = a cross); 1 or less
            returns the mask unchanged.
    """
    if kernel_px <= 1:
        return mask
    k = _kernel(int(kernel_px))
    # opening then closing = erode(k), dilate(k), dilate(k), erode(k); the two dilations are
    # one dilation by k ⊕ k (three passes instead of four, same result)
    out = cv2.erode(mask, k)
    out = cv2.dilate(out, _kernel2(int(kernel_px)))
    return cv2.erode(out, k)


_KERNELS: dict[int, np.ndarray] = {}
_KERNELS2: dict[int, np.ndarray] = {}


def _kernel2(size: int) -> np.ndarray:
    """The Minkowski sum of the elliptic kernel with itself."""
    k2 = _KERNELS2.get(size)
    if k2 is None:
        k = _kernel(size)
        k2 = cv2.dilate(np.pad(k, size // 2), k)
        k2 = _KERNELS2[size] = (k2 > 0).astype(np.uint8)
    return k2


def _kernel(size: int) -> np.ndarray:
    k = _KERNELS.get(size)
    if k is None:
        k = _KERNELS[size] = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return k


class ColorClassifier:
    """All palette colours thresholded on the split H, S, V planes.

    Per colour: hue band(s) with ``cv2.inRange`` on H (two bands for a range that wraps),
    thresholds on S and V, AND-ed — the same pixels as ``cv2.inRange`` on the HSV image
    (:func:`threshold_color`), for about half the cost.

    Args:
        specs: Colour ranges.
        v_floor: Pixel-level lower bound on V: ``min(v_floor, spec V low)``; the spec's own V
            range is then judged on CLAHE-equalised V per blob (:class:`ClaheMap`). ``None``
            applies each spec's V range per pixel, which makes :meth:`masks` identical to
            :func:`threshold_color`.
    """

    def __init__(self, specs: Sequence[ColorSpec], v_floor: int | None = 25):
        self.specs = list(specs)
        if not self.specs:
            raise ValueError("ColorClassifier needs at least one colour")
        self._bufs: list[np.ndarray] = []
        self.v_floor = v_floor
        self._plans = []
        for spec in self.specs:
            (h0, s0, v0), (h1, s1, v1) = spec.hsv
            hue = [(h0, 179), (0, h1)] if spec.wraps else [(h0, h1)]
            if v_floor is None:
                vr = (v0, v1)
            else:
                vr = (min(int(v_floor), v0), 255)
            self._plans.append((hue, (s0, s1), vr))

    @staticmethod
    def _band(plane: np.ndarray, lo: int, hi: int, dst: np.ndarray) -> np.ndarray | None:
        if lo <= 0 and hi >= 255:
            return None
        if hi >= 255:
            return cv2.threshold(plane, lo - 1, 255, cv2.THRESH_BINARY, dst)[1]
        return cv2.inRange(plane, lo, hi, dst)

    def _buffers(self, shape: tuple[int, int], n: int) -> list[np.ndarray]:
        bufs = self._bufs
        if len(bufs) < n or bufs[0].shape != shape:
            bufs = self._bufs = [np.empty(shape, np.uint8) for _ in range(n)]
        return bufs

    def masks(self, hsv: np.ndarray, reuse: bool = False) -> list[np.ndarray]:
        """One 0/255 mask per colour, in the order of ``specs``.

        Args:
            hsv: (H, W, 3) HSV image.
            reuse: Write into buffers kept by the classifier (no allocation per frame; the
                masks are overwritten by the next call).
        """
        shape = hsv.shape[:2]
        nb = 3 + 3 * len(self._plans) + 4
        bufs = self._buffers(shape, nb) if reuse else [np.empty(shape, np.uint8)
                                                       for _ in range(nb)]
        # cv2.split into given planes: without them OpenCV 5's binding is ~50× slower
        h, s, v = cv2.split(hsv, bufs[:3])
        free = iter(bufs[3:])
        out = []
        cache: dict = {}
        for hue, (s0, s1), (v0, v1) in self._plans:
            m = cv2.inRange(h, hue[0][0], hue[0][1], next(free))
            for lo, hi in hue[1:]:
                cv2.bitwise_or(m, cv2.inRange(h, lo, hi, next(free)), dst=m)
            for plane, key, lo, hi in ((s, "s", s0, s1), (v, "v", v0, v1)):
                ck = (key, lo, hi)
                if ck not in cache:
                    cache[ck] = self._band(plane, lo, hi, next(free))
                b = cache[ck]
                if b is not None:
                    cv2.bitwise_and(m, b, dst=m)
            out.append(m)
        return out


class ClaheMap:
    """CLAHE's mapping of V, as OpenCV computes it, evaluated at chosen pixels.

    OpenCV's CLAHE splits the image into ``tile_grid`` tiles (padding it by reflection when the
    size is not a multiple), builds a clipped, redistributed cumulative histogram per tile, and
    maps a pixel by blending the tables of the four nearest tiles bilinearly. This class builds
    the tiles' histograms (from every ``stride``-th pixel in each direction; ``stride=1``
    reproduces ``cv2.createCLAHE(...).apply`` to within one level) and evaluates the tables
    only where asked.

    Args:
        v: (H, W) uint8 value channel.
        clip_limit: OpenCV's ``clipLimit``.
        tile_grid: OpenCV's ``tileGridSize`` (tiles across, tiles down).
        stride: Histogram subsampling step.
    """

    _INDEX: ClassVar[dict] = {}

    def __init__(self, v: np.ndarray, clip_limit: float = 2.0,
                 tile_grid: tuple[int, int] = (8, 8), stride: int = 4):
        tx, ty = int(tile_grid[0]), int(tile_grid[1])
        H, W = v.shape
        if W % tx or H % ty:
            v = cv2.copyMakeBorder(v, 0, (ty - H % ty) % ty, 0, (tx - W % tx) % tx,
                                   cv2.BORDER_REFLECT_101)
        Hp, Wp = v.shape
        tw, th = Wp // tx, Hp // ty
        self.area = tw * th
        self.tiles = (tx, ty)
        self.tile_size = (tw, th)
        st = max(1, int(stride))
        key = (Hp, Wp, tx, ty, st)
        idx = self._INDEX.get(key)
        if idx is None:
            ys = (np.arange(0, Hp, st) // th)[:, None]
            xs = (np.arange(0, Wp, st) // tw)[None, :]
            idx = ((ys * tx + xs) * 256).astype(np.int32)
            if len(self._INDEX) > 8:
                self._INDEX.clear()
            self._INDEX[key] = idx
        sub = v[::st, ::st] if st > 1 else v
        self.hist = np.bincount((idx + sub).ravel(), minlength=tx * ty * 256).reshape(
            tx * ty, 256)
        self.scale = self.area / max(1, sub.size // (tx * ty)) if st > 1 else 1.0
        self.clip = max(int(clip_limit * self.area / 256), 1) if clip_limit > 0 else None

    def lut(self, tiles: np.ndarray) -> np.ndarray:
        """The (k, 256) tables of the given tile indices (row-major), as OpenCV builds them."""
        hist = self.hist[tiles]
        if self.scale != 1.0:
            hist = np.rint(hist * self.scale).astype(np.int64)
        if self.clip is not None:
            clip = self.clip
            excess = np.maximum(hist - clip, 0).sum(axis=1)
            hist = np.minimum(hist, clip)
            batch = excess // 256
            residual = excess - batch * 256
            hist = hist + batch[:, None]
            step = np.maximum(256 // np.maximum(residual, 1), 1)
            b = np.arange(256)[None, :]
            hist = hist + ((residual[:, None] > 0) & (b % step[:, None] == 0)
                           & (b // step[:, None] < residual[:, None]))
        return np.minimum(np.rint(np.cumsum(hist, axis=1) * (255.0 / self.area)), 255)

    def __call__(self, x: np.ndarray, y: np.ndarray, v: np.ndarray) -> np.ndarray:
        """CLAHE output (float, 0–255) of raw values ``v`` at pixel positions (x, y)."""
        x = np.asarray(x, np.float64).ravel()
        y = np.asarray(y, np.float64).ravel()
        v = np.minimum(np.maximum(np.rint(np.asarray(v, np.float64).ravel()), 0), 255).astype(
            np.int64)
        tx, ty = self.tiles
        tw, th = self.tile_size
        txf = x / tw - 0.5
        tyf = y / th - 0.5
        tx1 = np.floor(txf)
        ty1 = np.floor(tyf)
        xa, ya = txf - tx1, tyf - ty1
        tx1 = tx1.astype(np.int64)
        ty1 = ty1.astype(np.int64)
        tx2 = np.minimum(np.maximum(tx1 + 1, 0), tx - 1)
        ty2 = np.minimum(np.maximum(ty1 + 1, 0), ty - 1)
        tx1 = np.minimum(np.maximum(tx1, 0), tx - 1)
        ty1 = np.minimum(np.maximum(ty1, 0), ty - 1)
        corners = np.concatenate([ty1 * tx + tx1, ty1 * tx + tx2, ty2 * tx + tx1,
                                  ty2 * tx + tx2])                          # (4n,)
        vv = np.concatenate([v, v, v, v])
        if corners.size >= tx * ty:     # many points: build every tile's table once
            L = self.lut(np.arange(tx * ty))[corners, vv]
        else:
            L = self.lut(corners)[np.arange(corners.size), vv]
        L = L.reshape(4, -1)
        top = L[0] * (1 - xa) + L[1] * xa
        bot = L[2] * (1 - xa) + L[3] * xa
        return top * (1 - ya) + bot * ya
