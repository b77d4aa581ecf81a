"""Blob stage of the dot detector: connected blobs of a colour mask, their shape measures and
filters, and sub-pixel centres.

* :func:`find_blobs` finds the blobs of a cleaned mask with ``cv2.findContours`` and measures
  all of them at once (area, centroid, second moments → ellipse axes, perimeter,
  circularity); :func:`find_blobs_cc` is the thesis's formulation with
  ``cv2.connectedComponentsWithStats`` plus per-blob contour measures (same blobs and
  measures; it is 20–50× slower in OpenCV 5 on a 640×480 frame, hence the default).
* :func:`filter_blobs` applies the size, aspect, circularity, convexity and fill filters.
* :func:`refine_centers` measures sub-pixel centres: the centroid of each blob's
  *colour coverage* (a linear colour contrast between the dot's and the background's colour,
  estimated per blob) over a support slightly larger than the blob. A projected circle is an
  ellipse (centrally symmetric), blur kernels are symmetric, so this centroid estimates the
  ellipse's centre without the ±0.5 px quantisation of a binary mask. (The ellipse centre is
  not the projected circle centre under perspective; :mod:`drovisio.pose.batch` corrects that.)

Pixel (0, 0) is the centre of the top-left pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np

from drovisio import _numba
from drovisio.detect.dots import blobs_kernels as _k

__all__ = [
    "BlobFilter",
    "Blobs",
    "concat_blobs",
    "filter_blobs",
    "find_blobs",
    "find_blobs_cc",
    "find_blobs_multi",
    "refine_centers",
]


@dataclass
class Blobs:
    """Blobs as parallel arrays (one entry per blob).

    Attributes:
        x, y: Centroid of the blob region, pixels.
        area: Pixel count (estimated from the contour: polygon area + half the boundary).
        a, b: Semi-axes of the region's moment ellipse (a ≥ b), pixels.
        angle: Direction of the major axis, radians (image x toward image y).
        cov: (n, 2, 2) second-moment matrix of the region (= a²/4, b²/4 along the axes).
        perimeter: Length of the region's outline, pixels.
        circularity: 4π·area / perimeter² (1 for a disc).
        fill: Contour area / its moment ellipse's area (1 for an ellipse, ≈0.95 for a
            rectangle, lower for crescents, rings and branched shapes).
        convexity: Contour area / its convex hull's area (NaN until measured).
        ellipse_err: RMS relative deviation of the outline from the blob's moment ellipse (0
            for an ellipse; ≈0.12 for a square, more for half discs and branched shapes).
        holes: Share of the outline's area that is holes (a ring is mostly hole).
        color: Index of the palette colour.
        bbox: (n, 4) int x0, y0, x1, y1 (inclusive) of the region.
        border: True where the blob touches the image border (a cut dot).
        contour: Index of the blob's contour in the mask's contour list (-1 if none).
    """

    x: np.ndarray
    y: np.ndarray
    area: np.ndarray
    a: np.ndarray
    b: np.ndarray
    angle: np.ndarray
    cov: np.ndarray
    perimeter: np.ndarray
    circularity: np.ndarray
    fill: np.ndarray
    convexity: np.ndarray
    ellipse_err: np.ndarray
    holes: np.ndarray
    color: np.ndarray
    bbox: np.ndarray
    border: np.ndarray
    contour: np.ndarray

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def take(self, idx) -> Blobs:
        """The blobs selected by an index array or boolean mask."""
        return Blobs(*[getattr(self, name)[idx] for name in _FIELDS])

    @property
    def xy(self) -> np.ndarray:
        return np.stack([self.x, self.y], axis=1)

    @staticmethod
    def empty() -> Blobs:
        z = np.zeros(0)
        return Blobs(x=z, y=z, area=z, a=z, b=z, angle=z, cov=np.zeros((0, 2, 2)),
                     perimeter=z, circularity=z, fill=z, convexity=z, ellipse_err=z, holes=z,
                     color=np.zeros(0, np.int64), bbox=np.zeros((0, 4), np.int64),
                     border=np.zeros(0, bool), contour=np.zeros(0, np.int64))


_FIELDS = tuple(f.name for f in fields(Blobs))


def concat_blobs(parts: list[Blobs]) -> Blobs:
    """Blobs of several masks as one set."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return Blobs.empty()
    if len(parts) == 1:
        return parts[0]
    return Blobs(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                    for f in fields(Blobs)})


@dataclass(frozen=True)
class BlobFilter:
    """Which blobs may be dots.

    Args:
        min_area: Fewest pixels (a 6 px-across dot has ~28; its mask a little less).
        max_area: Most pixels.
        min_aspect: Smallest minor/major axis ratio (a circle seen 75° off its normal: 0.26).
        min_circularity: Smallest 4π·area/perimeter² (digital discs: 0.75–0.95; squares 0.7).
        min_fill: Smallest area / moment-ellipse area.
        min_convexity: Smallest area / hull area (measured only on blobs passing the rest).
        max_ellipse_err: Largest outline deviation from the moment ellipse, plus
            ``ellipse_err_px`` divided by the minor semi-axis (small blobs are coarse).
        max_holes: Largest share of holes.
    """

    min_area: float = 7.0
    max_area: float = 6000.0
    min_aspect: float = 0.25
    min_circularity: float = 0.55
    min_fill: float = 0.88
    min_convexity: float = 0.85
    max_ellipse_err: float = 0.05
    ellipse_err_px: float = 0.35
    max_holes: float = 0.15


def _segment_sums(x0, y0, x1, y1, starts):
    """Per-contour sums of the polygon moment terms (Green's theorem)."""
    cr = x0 * y1 - x1 * y0
    terms = np.stack([
        cr,                                               # 2A
        (x0 + x1) * cr,                                   # 6A·cx
        (y0 + y1) * cr,                                   # 6A·cy
        (x0 * x0 + x0 * x1 + x1 * x1) * cr,               # 12·Ixx
        (y0 * y0 + y0 * y1 + y1 * y1) * cr,               # 12·Iyy
        (x0 * y1 + 2 * x0 * y0 + 2 * x1 * y1 + x1 * y0) * cr,  # 24·Ixy
        np.hypot(x1 - x0, y1 - y0),                       # perimeter
    ])
    return np.add.reduceat(terms, starts, axis=1)


def _measure(contours: list[np.ndarray], color, shape: tuple[int, int],
             index: np.ndarray | None = None, flt: BlobFilter | None = None) -> Blobs:
    """Vectorised measures of contours of one mask (all contours at once); the compiled path
    also measures the convexity of the contours that ``flt``'s shape filters may keep."""
    if not contours:
        return Blobs.empty()
    if _numba.enabled():
        return _measure_compiled(contours, color, shape, index, flt)
    n_pts = np.array(list(map(len, contours)), np.int64)
    pts = np.concatenate(contours).reshape(-1, 2).astype(np.float64)
    starts = np.zeros(len(contours), np.int64)
    np.cumsum(n_pts[:-1], out=starts[1:])
    nxt = np.arange(1, pts.shape[0] + 1)
    nxt[starts + n_pts - 1] = starts
    # shift by the first point of each contour for numerical conditioning
    origin = pts[starts]
    rep = np.repeat(origin, n_pts, axis=0)
    p0 = pts - rep
    p1 = pts[nxt] - rep
    s = _segment_sums(p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1], starts)
    a2 = s[0]
    sign = np.where(a2 < 0, -1.0, 1.0)
    area_poly = np.abs(a2) / 2
    safe = np.where(area_poly > 0, a2, 1.0)
    cx = s[1] / (3 * safe)
    cy = s[2] / (3 * safe)
    ixx = s[3] / (6 * safe) - cx * cx
    iyy = s[4] / (6 * safe) - cy * cy
    ixy = s[5] / (12 * safe) - cx * cy
    perim_poly = s[6]
    # single-pixel-wide contours (lines) have no area: their centroid is the points' mean
    deg = area_poly <= 0
    if np.any(deg):
        means = np.add.reduceat(p0, starts, axis=0) / n_pts[:, None]
        cx = np.where(deg, means[:, 0], cx)
        cy = np.where(deg, means[:, 1], cy)
        ixx = np.where(deg, 0.0, ixx)
        iyy = np.where(deg, 0.0, iyy)
        ixy = np.where(deg, 0.0, ixy)
    cx = cx + origin[:, 0]
    cy = cy + origin[:, 1]
    # eigen-decomposition of the polygon's second moments
    tr = ixx + iyy
    dd = np.sqrt(np.maximum((ixx - iyy) ** 2 / 4 + ixy * ixy, 0))
    l1 = np.maximum(tr / 2 + dd, 0)
    l2 = np.maximum(tr / 2 - dd, 0)
    angle = 0.5 * np.arctan2(2 * ixy, ixx - iyy)
    a_poly, b_poly = 2 * np.sqrt(l1), 2 * np.sqrt(l2)
    fill = np.where(a_poly * b_poly > 0, area_poly / (math.pi * np.maximum(a_poly * b_poly,
                                                                            1e-12)), 0.0)
    # the contour runs through the boundary pixels' centres: the region is half a pixel wider
    a_reg, b_reg = a_poly + 0.5, b_poly + 0.5
    area = area_poly + n_pts / 2.0 + 1.0
    perimeter = perim_poly + math.pi
    circularity = 4 * math.pi * area / np.maximum(perimeter, 1e-9) ** 2
    c, sn = np.cos(angle), np.sin(angle)
    A2, B2 = (a_reg / 2) ** 2, (b_reg / 2) ** 2
    cov = np.empty((len(contours), 2, 2))
    cov[:, 0, 0] = A2 * c * c + B2 * sn * sn
    cov[:, 1, 1] = A2 * sn * sn + B2 * c * c
    cov[:, 0, 1] = cov[:, 1, 0] = (A2 - B2) * c * sn
    mn = np.minimum.reduceat(pts, starts, axis=0).astype(np.int64)
    mx = np.maximum.reduceat(pts, starts, axis=0).astype(np.int64)
    bbox = np.concatenate([mn, mx], axis=1)
    H, W = shape
    border = (mn[:, 0] <= 0) | (mn[:, 1] <= 0) | (mx[:, 0] >= W - 1) | (mx[:, 1] >= H - 1)
    del sign
    # outline vs moment ellipse: Mahalanobis radius of every outline point (1 on the ellipse)
    det = np.maximum(ixx * iyy - ixy * ixy, 1e-12)
    ccx, ccy = np.repeat(cx - origin[:, 0], n_pts), np.repeat(cy - origin[:, 1], n_pts)
    dx, dy = p0[:, 0] - ccx, p0[:, 1] - ccy
    r2 = (np.repeat(iyy / det, n_pts) * dx * dx - 2 * np.repeat(ixy / det, n_pts) * dx * dy
          + np.repeat(ixx / det, n_pts) * dy * dy) / 4.0
    dev = np.sqrt(r2) - 1.0
    ellipse_err = np.sqrt(np.add.reduceat(dev * dev, starts) / n_pts)
    ellipse_err = np.where(deg, np.inf, ellipse_err)
    return Blobs(x=cx, y=cy, area=area, a=a_reg, b=b_reg, angle=angle, cov=cov,
                 perimeter=perimeter, circularity=circularity, fill=fill,
                 convexity=np.full(len(contours), np.nan), ellipse_err=ellipse_err,
                 holes=np.zeros(len(contours)),
                 color=np.broadcast_to(np.asarray(color, np.int64), (len(contours),)).copy(),
                 bbox=bbox,
                 border=border,
                 contour=np.arange(len(contours)) if index is None else index)


def _measure_compiled(contours, color, shape, index, flt, n_pts=None) -> Blobs:
    """:func:`_measure` with the compiled kernel (same measures)."""
    n = len(contours)
    if n_pts is None:
        n_pts = np.fromiter(map(len, contours), np.int64, n)
    pts = np.concatenate(contours).reshape(-1, 2)
    starts = np.zeros(n, np.int64)
    np.cumsum(n_pts[:-1], out=starts[1:])
    gate = _NO_HULL if flt is None else np.array(
        [flt.min_area, flt.max_area, flt.min_aspect, flt.min_circularity, flt.min_fill,
         flt.max_ellipse_err, flt.ellipse_err_px])
    out, bbox, border = _k.measure_contours(pts, starts, n_pts, int(shape[0]), int(shape[1]),
                                            gate)
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0] = out[:, 10]
    cov[:, 0, 1] = cov[:, 1, 0] = out[:, 11]
    cov[:, 1, 1] = out[:, 12]
    color = np.asarray(color, np.int64)
    return Blobs(x=out[:, 0], y=out[:, 1], area=out[:, 2], a=out[:, 3], b=out[:, 4],
                 angle=out[:, 5], cov=cov, perimeter=out[:, 6], circularity=out[:, 7],
                 fill=out[:, 8], convexity=out[:, 13], ellipse_err=out[:, 9],
                 holes=np.zeros(n), color=np.broadcast_to(color, (n,)).copy(), bbox=bbox,
                 border=border, contour=np.arange(n) if index is None else index)


_NO_HULL = np.array([np.inf, -np.inf, 0.0, 0.0, 0.0, 0.0, 0.0])


def find_blobs(mask: np.ndarray, color: int = 0, flt: BlobFilter | None = None
               ) -> tuple[Blobs, list[np.ndarray]]:
    """Stage 5: the blobs of a (cleaned) mask, measured and filtered.

    Args:
        mask: uint8 mask (non-zero = colour).
        color: Palette index stored with the blobs.
        flt: Filters; :class:`BlobFilter` defaults if None.

    Returns:
        (blobs that pass the filters, the mask's contours — ``Blobs.contour`` indexes them).
    """
    blobs, contours = find_blobs_multi([mask], flt)
    blobs.color[:] = color
    return blobs, contours


def _all_contours(masks: list, shape: tuple[int, int] | None
                  ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray],
                             tuple[int, int] | None]:
    """The contours of every mask (see :func:`find_blobs_multi`) in one list, per mask the
    colour of its contours and each contour's outline index (-1 for an outline), and the
    frame's shape (given, or that of the first whole mask)."""
    allc: list[np.ndarray] = []
    colors: list[np.ndarray] = []
    parent: list[np.ndarray] = []
    shape = (shape[0], shape[1]) if shape is not None else None
    for k, entry in enumerate(masks):
        if entry is None:
            continue
        for mask in (entry if isinstance(entry, list) else [entry]):
            offset = (0, 0)
            if isinstance(mask, tuple):
                mask, offset = mask
            else:
                shape = shape or (mask.shape[0], mask.shape[1])
            cs, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE,
                                        offset=offset)
            if not cs:
                continue
            base = len(allc)
            allc.extend(cs)
            colors.append(np.full(len(cs), k, np.int64))
            par = hier[0][:, 3].astype(np.int64)
            parent.append(np.where(par >= 0, par + base, -1))
    return allc, colors, parent, shape


def find_blobs_multi(masks: list, flt: BlobFilter | None = None, extra=None,
                     shape: tuple[int, int] | None = None) -> tuple[Blobs, list[np.ndarray]]:
    """:func:`find_blobs` for one mask per colour, measured in one pass (colour k = mask k;
    None = no pixel of that colour; ``(roi_mask, (x0, y0))`` = a region of the frame's mask
    whose top-left pixel is (x0, y0), with ``shape`` the frame's (H, W); a list of such
    regions = separate regions of one colour's mask). ``extra(blobs) ->
    bool mask`` is one more filter, applied with the convexity filter (e.g. the CLAHE V gate).

    Outlines and holes come from ``cv2.findContours`` (two-level hierarchy); all outlines are
    measured at once (:func:`_measure`), holes are subtracted from their outline's area.

    Returns:
        (blobs, contours of all masks in one list — ``Blobs.contour`` indexes it).
    """
    flt = flt or BlobFilter()
    allc, colors, parent, shape = _all_contours(masks, shape)
    if not allc:
        return Blobs.empty(), []
    parent_a = np.concatenate(parent)
    n_pts = np.fromiter(map(len, allc), np.int64, len(allc))
    outer = parent_a < 0
    keep = np.nonzero(outer & (n_pts >= max(4, int(2.5 * math.sqrt(flt.min_area))))
                      & (n_pts <= 8 * math.sqrt(flt.max_area)))[0]
    if keep.size == 0:
        return Blobs.empty(), allc
    col = np.concatenate(colors)[keep]
    kept = [allc[i] for i in keep.tolist()]
    assert shape is not None, "regions of a mask need the frame's shape"
    if _numba.enabled():
        blobs = _measure_compiled(kept, col, shape, keep, flt, n_pts[keep])
    else:
        blobs = _measure(kept, col, shape, index=keep, flt=flt)
    holes = np.nonzero(~outer)[0]
    if holes.size:
        _measure_holes(blobs, allc, holes, parent_a, keep, n_pts)
    return filter_blobs(blobs, flt, allc, extra), allc


def _measure_holes(blobs: Blobs, allc: list[np.ndarray], holes: np.ndarray,
                   parent_a: np.ndarray, keep: np.ndarray, n_pts: np.ndarray) -> None:
    """Set ``blobs.holes``: the area of the holes of each kept outline (index ``keep`` into
    ``allc``) over its area. ``holes``: indices of the hole contours, ``parent_a``: each
    contour's outline (-1 for outlines), ``n_pts``: each contour's point count."""
    pos = np.full(len(allc), -1, np.int64)
    pos[keep] = np.arange(keep.size)
    owner = pos[parent_a[holes]]
    sel = owner >= 0
    if not np.any(sel):
        return
    hs = holes[sel]
    if _numba.enabled():
        hc = [allc[h] for h in hs]
        nh = n_pts[hs]
        starts = np.zeros(hs.size, np.int64)
        np.cumsum(nh[:-1], out=starts[1:])
        hole_area = np.maximum(_k.polygon_areas(np.concatenate(hc).reshape(-1, 2),
                                                starts, nh) - nh / 2.0 + 1.0, 0.0)
    else:
        hole_area = np.array([max(cv2.contourArea(allc[h]) - len(allc[h]) / 2.0 + 1.0, 0.0)
                              for h in hs])
    total = np.zeros(keep.size)
    np.add.at(total, owner[sel], hole_area)
    blobs.holes = total / np.maximum(blobs.area, 1.0)


def _shape_ok(blobs: Blobs, flt: BlobFilter) -> np.ndarray:
    b_poly = np.maximum(blobs.b - 0.5, 0.5)
    return ((blobs.area >= flt.min_area) & (blobs.area <= flt.max_area)
            & (blobs.b >= flt.min_aspect * blobs.a) & (blobs.circularity >= flt.min_circularity)
            & (blobs.fill >= flt.min_fill) & (blobs.holes <= flt.max_holes)
            & (blobs.ellipse_err <= flt.max_ellipse_err + flt.ellipse_err_px / b_poly))


def filter_blobs(blobs: Blobs, flt: BlobFilter, contours: list[np.ndarray] | None = None,
                 extra=None) -> Blobs:
    """Keep blobs that pass the size, aspect, circularity, fill, hole and ellipse filters,
    then convexity (measured here on the survivors when their contours are given) and the
    ``extra`` filter (a function of the blobs returning a bool mask)."""
    if len(blobs) == 0:
        return blobs
    blobs = blobs.take(np.flatnonzero(_shape_ok(blobs, flt)))
    if len(blobs) == 0:
        return blobs
    ok = np.ones(len(blobs), bool)
    if contours is not None and flt.min_convexity > 0:
        # convexity where the other measures leave a doubt (a clean ellipse is convex)
        b_poly = np.maximum(blobs.b - 0.5, 0.5)
        doubt = (blobs.fill < 0.97) | (blobs.ellipse_err > 0.5 * (
            flt.max_ellipse_err + flt.ellipse_err_px / b_poly))
        conv = np.ones(len(blobs))
        known = ~np.isnan(blobs.convexity)      # measured with the shape (compiled path)
        conv[doubt & known] = blobs.convexity[doubt & known]
        for k in np.flatnonzero(doubt & ~known).tolist():
            c = contours[int(blobs.contour[k])]
            hull_area = cv2.contourArea(cv2.convexHull(c))
            conv[k] = cv2.contourArea(c) / hull_area if hull_area > 0 else 0.0
        blobs.convexity = conv
        # tiny blobs: one pixel more or less changes the ratio a lot
        tol = np.minimum(0.15, 1.5 / np.sqrt(np.maximum(blobs.area, 1)))
        ok &= conv >= flt.min_convexity - tol
    if extra is not None:
        ok &= extra(blobs)
    return blobs if ok.all() else blobs.take(np.flatnonzero(ok))


def find_blobs_cc(mask: np.ndarray, color: int = 0, flt: BlobFilter | None = None) -> Blobs:
    """The thesis's blob stage: ``cv2.connectedComponentsWithStats`` (size filter on the
    component statistics), then contour measures of each remaining component."""
    flt = flt or BlobFilter()
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    parts = []
    H, W = mask.shape
    for k in range(1, n):
        x, y, w, h, area = (int(v) for v in stats[k])
        if area < flt.min_area * 0.5 or area > flt.max_area * 1.5:
            continue
        roi = (labels[y:y + h, x:x + w] == k).astype(np.uint8)
        cs, _ = cv2.findContours(roi, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(x, y))
        if not cs:
            continue
        c = max(cs, key=len)
        b = _measure([c], color, (H, W), index=np.array([k]))
        b.holes = np.array([max(0.0, 1.0 - float(area) / float(b.area[0]))])
        b.area = np.array([float(area)])
        hull_area = cv2.contourArea(cv2.convexHull(c))
        b.convexity = np.array([cv2.contourArea(c) / hull_area if hull_area > 0 else 0.0])
        parts.append(b)
    blobs = concat_blobs(parts)
    if len(blobs) == 0:
        return blobs
    ok = _shape_ok(blobs, flt)
    tol = np.minimum(0.15, 1.5 / np.maximum(blobs.area, 1) ** 0.5)
    ok &= blobs.convexity >= flt.min_convexity - tol
    return blobs.take(np.nonzero(ok)[0])


_WINDOW_SIZES = (9, 13, 17, 23, 31, 41, 55, 73, 97, 129)


def refine_centers(image_bgr: np.ndarray, blobs: Blobs, index: np.ndarray | None = None,
                   margin_px: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel centres of blobs: the centroid of their colour coverage.

    For each blob, in a window around it: the background colour is the mean outside the
    support (the blob's moment ellipse grown by ``margin_px``), the dot colour the mean of
    the inner half of the ellipse; each pixel's coverage is its colour's projection on the
    line from background to dot colour, with the grey direction (1, 1, 1) projected out so
    that shading and grey edges next to the dot do not count (a linear measure, so blur and
    anti-aliasing keep the centroid where it is), and the centre is the coverage-weighted
    centroid over the support.
    Blobs are processed at once, in at most a few groups of similar window sizes.

    Args:
        image_bgr: The frame (H, W, 3) uint8.
        blobs: Blobs found in it.
        index: Which blobs to refine (all if None).
        margin_px: How far beyond the blob's ellipse the support reaches (covers blur).

    Returns:
        ((n, 2) refined centres in pixels, (n,) contrast: |dot − background| colour distance;
        where a blob cannot be refined its centroid is returned and its contrast is 0), for
        the blobs of ``index``.
    """
    idx = np.arange(len(blobs)) if index is None else np.asarray(index, np.int64)
    n = idx.size
    if _numba.enabled() and n:
        return _k.refine_centers(np.ascontiguousarray(image_bgr), blobs.x[idx], blobs.y[idx],
                                 blobs.a[idx], blobs.b[idx], blobs.cov[idx], float(margin_px),
                                 _WINDOW_SIZES[-1])
    bx, by = blobs.x[idx], blobs.y[idx]
    ba, bb, bcov = blobs.a[idx], blobs.b[idx], blobs.cov[idx]
    out = np.stack([bx, by], axis=1)
    contrast = np.zeros(n)
    if n == 0:
        return out, contrast
    H, W = image_bgr.shape[:2]
    need = 2 * (np.ceil(ba + margin_px) + 2) + 1
    # groups: windows within a factor 2 of each other share a size (the largest)
    lo = float(need.min())
    groups = [np.flatnonzero(need <= 2 * lo)]
    rest = np.flatnonzero(need > 2 * lo)
    while rest.size:
        lo = float(need[rest].min())
        groups.append(rest[need[rest] <= 2 * lo])
        rest = rest[need[rest] > 2 * lo]
    for sel in groups:
        w = int(need[sel].max())
        if w > _WINDOW_SIZES[-1]:   # too big to be a dot worth refining: keep the centroid
            continue
        half = w // 2
        cx = np.rint(bx[sel]).astype(np.int64)
        cy = np.rint(by[sel]).astype(np.int64)
        offs = np.arange(-half, half + 1)
        xs = cx[:, None] + offs[None, :]
        ys = cy[:, None] + offs[None, :]
        vx = (xs >= 0) & (xs < W)
        vy = (ys >= 0) & (ys < H)
        m = sel.size
        # np.take on the flattened frame: several times faster than 2-D fancy indexing
        flat_idx = (np.minimum(np.maximum(ys, 0), H - 1)[:, :, None] * W
                    + np.minimum(np.maximum(xs, 0), W - 1)[:, None, :]).ravel()
        win = np.take(image_bgr.reshape(-1, image_bgr.shape[2]), flat_idx, axis=0)
        win = win.reshape(m, w * w, -1)[:, :, :3].astype(np.float32)   # (m, w², 3)
        valid = (vy[:, :, None] & vx[:, None, :]).reshape(m, w * w)
        # Mahalanobis radius in the blob's ellipse (boundary at 1)
        dx = (xs - bx[sel][:, None]).astype(np.float32)          # (m, w)
        dy = (ys - by[sel][:, None]).astype(np.float32)
        cov = bcov[sel]
        det = np.maximum(cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2, 1e-9)
        k00 = (cov[:, 1, 1] / (4 * det)).astype(np.float32)[:, None, None]
        k01 = (-cov[:, 0, 1] / (2 * det)).astype(np.float32)[:, None, None]
        k11 = (cov[:, 0, 0] / (4 * det)).astype(np.float32)[:, None, None]
        q = (k00 * (dx * dx)[:, None, :] + k01 * (dy[:, :, None] * dx[:, None, :])
             + k11 * (dy * dy)[:, :, None]).reshape(m, w * w)
        # q = 1 on the ellipse; the support grows by margin_px along the minor axis
        grow2 = ((1.0 + margin_px / np.maximum(bb[sel], 0.5)) ** 2).astype(np.float32)
        support = (q <= grow2[:, None]) & valid
        fo = (valid & ~support).astype(np.float32)[:, None, :]   # ring outside the support
        fi = ((q <= 0.25) & valid).astype(np.float32)[:, None, :]  # inner half of the blob
        no = fo.sum(axis=2)                                       # (m, 1)
        ni = fi.sum(axis=2)
        bg = (fo @ win)[:, 0, :] / np.maximum(no, 1)              # (m, 3)
        fg = (fi @ win)[:, 0, :] / np.maximum(ni, 1)
        d = fg - bg
        # chroma only: brightness changes of a grey background (shading, the pyramids'
        # edges) lie along (1, 1, 1) and must not count as coverage
        d = d - d.mean(axis=1, keepdims=True)
        dn = (d * d).sum(axis=1)
        good = (no[:, 0] > 0) & (ni[:, 0] > 0) & (dn > 100.0)    # ≥ 10 levels of contrast
        dd = (d / np.where(good, dn, 1.0)[:, None]).astype(np.float32)
        # coverage = (pixel − background)·d / |d|², over the support
        cw = ((win @ dd[:, :, None])[:, :, 0] - (bg * dd).sum(axis=1)[:, None]) * support
        cw = cw.reshape(m, w, w)
        s = cw.sum(axis=(1, 2))
        sx = (cw.sum(axis=1) * xs).sum(axis=1)
        sy = (cw.sum(axis=2) * ys).sum(axis=1)
        ok = good & (s > 1.0)
        out[sel[ok], 0] = sx[ok] / s[ok]
        out[sel[ok], 1] = sy[ok] / s[ok]
        contrast[sel[ok]] = np.sqrt(dn[ok])
    return out, contrast
