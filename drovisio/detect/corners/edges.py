"""A code's corners where its four outer border edges meet, each edge located on the image
gradient and fitted as a straight line: the reading of a code that needs no square model of
its interior.

Two uses. The corner fit keeps, at these corners, a code whose cells read right but whose
interior, extrapolated to the border, lands a corner far from where the border shows it (a
picture that is not a flat view of a square there: the rim of a photo undistorted with a
lens model that does not fit it, a bent print; :func:`edge_line_fallback`). And ``drovisio
bench real`` judges two readings of a code by them where the four edges are clean.

Along each side (its middle 70 %, away from the corners) the grey level is sampled on 40
normals ±3 px (bilinear, 0.1 px steps, the image smoothed by a 0.7 px Gaussian against JPEG
noise, each profile by 0.5 px along its normal); the edge is where the dark-to-light gradient
peaks (the centroid of the peak ±0.8 px: the 50 % crossing of a symmetric blur). A line is
fitted to those points by total least squares; its RMS says how clean the edge is (a
neighbour's edge or a shadow within 3 px widens it, so does a bent edge). On a rendered
square (σ 0.8 px blur, noise of 4 grey levels, any orientation) the intersections fall within
0.06 px of the truth and their covariance holds (mean χ² 7.6 for 8 coordinates). A thin
margin of paper on a darker surface pulls a gradient peak by a few tenths of a pixel (see the
package's docstring), and so does a neighbour's edge within the search; that is why the
interior fit, not this, is the detector's first reading.

Conventions: pixel (0, 0) is the centre of the top-left pixel; corners in the order given.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["EDGE_LINE_MAX_RMS_PX", "EdgeCorners", "edge_line_fallback", "outer_edge_corners",
           "read_cells"]

#: an edge line whose points scatter more than this (px RMS) is not clean enough to judge by
EDGE_LINE_MAX_RMS_PX = 0.3

#: fewest edge points (of 40 normals) for a side to count as located
_MIN_EDGE_POINTS = 20

#: how far each normal searches on either side of the given side, px
_SEARCH_PX = 3.0

#: points that scatter more than half as much as points found at random in the search window
#: (RMS ``_SEARCH_PX / sqrt(3)``) found no edge: a side covered by something dark, a shadow
_MAX_SIDE_RMS_PX = 0.5 * _SEARCH_PX / np.sqrt(3.0)

#: a Gaussian of 0.5 px along each normal (samples 0.1 px apart), and nothing across normals
_ALONG_NORMAL = cv2.getGaussianKernel(31, 5.0).astype(np.float32)
_ONE = np.ones((1, 1), np.float32)


@dataclass
class _Line:
    m: np.ndarray
    """(2,) a point on the line (the points' centroid), px."""
    d: np.ndarray
    """(2,) unit direction."""
    rms: float
    """The points' RMS off the line, px."""
    n: int
    """Points fitted."""
    spread: float
    """Sum of the points' squared positions along the line about ``m``, px²."""


@dataclass
class EdgeCorners:
    """A code's corners from its outer edge lines.

    Args:
        corners_px: (4, 2) where consecutive edge lines meet, px, in the quad's order.
        cov_px: (8, 8) their covariance from the four line fits (each line's offset and
            angle, from its points' scatter), px².
        line_rms_px: (4,) each side's points' RMS off its line, px (side i runs from corner
            i to corner i + 1).
    """

    corners_px: np.ndarray
    cov_px: np.ndarray
    line_rms_px: np.ndarray

    @property
    def worst_rms_px(self) -> float:
        """The largest of the four lines' RMS, px."""
        return float(self.line_rms_px.max())


def _edge_line(gf: np.ndarray, p0: np.ndarray, p1: np.ndarray, centre: np.ndarray
               ) -> _Line | None:
    """The outer edge between corners ``p0`` and ``p1`` (px) of a dark code around
    ``centre``, or None where fewer than :data:`_MIN_EDGE_POINTS` normals find it (a normal
    that leaves the image finds nothing: the image's own border is no edge) or its points
    scatter like noise (:data:`_MAX_SIDE_RMS_PX`)."""
    t = np.linspace(0.15, 0.85, 40)
    pts = p0[None] + t[:, None] * (p1 - p0)[None]
    length = float(np.linalg.norm(p1 - p0))
    if not np.isfinite(length) or length < 1e-6:
        return None
    along = (p1 - p0) / length
    out = np.array([-along[1], along[0]])
    if np.dot(centre - pts.mean(axis=0), out) > 0:
        out = -out
    s = np.arange(-30, 31) * (_SEARCH_PX / 30)
    X = (pts[:, 0, None] + s[None] * out[0]).astype(np.float32)
    Y = (pts[:, 1, None] + s[None] * out[1]).astype(np.float32)
    H, W = gf.shape[:2]
    seen = ((X >= 0) & (Y >= 0) & (X <= W - 1) & (Y <= H - 1)).all(axis=1)
    prof = cv2.remap(gf, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # bilinear profiles are piecewise linear between pixel centres: their gradient is flat
    # across a pixel where an edge runs along the pixel grid, and its peak wanders with the
    # noise (3.6x worse corners on an axis-aligned code); smoothed along the normal it is not
    grad = np.gradient(cv2.sepFilter2D(prof, -1, _ALONG_NORMAL, _ONE), axis=1)
    found = []
    for i in range(len(t)):
        if not seen[i]:
            continue
        k = int(np.argmax(grad[i]))
        if k < 2 or k > len(s) - 3 or grad[i, k] <= 0:
            continue
        w = slice(max(k - 8, 0), k + 9)
        g = np.clip(grad[i, w], 0.0, None)
        found.append(pts[i] + float((g * s[w]).sum() / g.sum()) * out)
    if len(found) < _MIN_EDGE_POINTS:
        return None
    e = np.array(found)
    m = e.mean(axis=0)
    _, _, vt = np.linalg.svd(e - m)
    along_e = (e - m) @ vt[0]
    rms = float(np.sqrt(np.mean(((e - m) @ vt[1]) ** 2)))
    if rms > _MAX_SIDE_RMS_PX:
        return None
    return _Line(m, vt[0], rms, len(e), float((along_e ** 2).sum()))


def _meet(a: _Line, b: _Line) -> np.ndarray | None:
    """Where lines ``a`` and ``b`` meet, px, or None when they are (nearly) parallel."""
    A = np.array([a.d, -b.d]).T
    if abs(np.linalg.det(A)) < 1e-6:
        return None
    return a.m + np.linalg.solve(A, b.m - a.m)[0] * a.d


def _moved(ln: _Line, offset: float, angle: float) -> _Line:
    """``ln`` shifted along its normal by ``offset`` px and turned by ``angle`` rad."""
    c, s = np.cos(angle), np.sin(angle)
    d = np.array([c * ln.d[0] - s * ln.d[1], s * ln.d[0] + c * ln.d[1]])
    nrm = np.array([-ln.d[1], ln.d[0]])
    return _Line(ln.m + offset * nrm, d, ln.rms, ln.n, ln.spread)


def _corners_of(lines: list[_Line]) -> np.ndarray | None:
    out = np.zeros((4, 2))
    for i in range(4):
        p = _meet(lines[i - 1], lines[i])
        if p is None:
            return None
        out[i] = p
    return out


def outer_edge_corners(gray: np.ndarray, quad: np.ndarray) -> EdgeCorners | None:
    """The corners where a dark code's four outer edge lines meet, with their covariance.

    Args:
        gray: (H, W) grey image.
        quad: (4, 2) the code's corners (px, OpenCV's convention: pixel centres at integers)
            from any reading, good to a pixel or two; the result keeps their order.

    Returns:
        The corners, or None where an edge cannot be located or two edges are parallel.
    """
    q = np.asarray(quad, np.float64)
    if q.size != 8 or not np.isfinite(q).all():
        return None
    q = q.reshape(4, 2)
    gf = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), 0.7)
    centre = q.mean(axis=0)
    lines = [_edge_line(gf, q[i], q[(i + 1) % 4], centre) for i in range(4)]
    if any(ln is None for ln in lines):
        return None
    ok_lines = [ln for ln in lines if ln is not None]
    corners = _corners_of(ok_lines)
    if corners is None:
        return None
    # each line's offset and angle are known to rms²/n and rms²/Σt² (its points' scatter);
    # the corners follow them through the intersections (a numerical Jacobian)
    J = np.zeros((8, 8))
    var = np.zeros(8)
    for i, ln in enumerate(ok_lines):
        s2 = max(ln.rms, 0.05) ** 2
        for j, (step, v) in enumerate(((1e-4, s2 / ln.n), (1e-6, s2 / max(ln.spread, 1e-9)))):
            moved = list(ok_lines)
            moved[i] = _moved(ln, step if j == 0 else 0.0, step if j == 1 else 0.0)
            c2 = _corners_of(moved)
            if c2 is None:
                return None
            J[:, 2 * i + j] = (c2 - corners).ravel() / step
            var[2 * i + j] = v
    cov = (J * var) @ J.T
    return EdgeCorners(corners, cov, np.array([ln.rms for ln in ok_lines]))


def read_cells(gray: np.ndarray, corners_px: np.ndarray, n: int) -> np.ndarray:
    """Each cell's grey level (the median of 9 points in its middle third) in the square code
    of ``n`` cells a side (border included) whose outer corners are ``corners_px``.

    Args:
        gray: (H, W) grey image.
        corners_px: (4, 2) TL, TR, BR, BL outer corners, px.
        n: Cells per side, border included.

    Returns:
        (n, n) grey levels, row by row.
    """
    src = np.array([[0, 0], [n, 0], [n, n], [0, n]], np.float32)
    H = cv2.getPerspectiveTransform(src, np.asarray(corners_px, np.float32).reshape(4, 2))
    off = np.array([-1.0, 0.0, 1.0]) / 6.0
    cu = (np.arange(n) + 0.5)[:, None] + off[None]  # (n, 3) per cell, along one axis
    u = np.broadcast_to(cu[None, :, None, :], (n, n, 3, 3))
    v = np.broadcast_to(cu[:, None, :, None], (n, n, 3, 3))
    uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2).astype(np.float32)
    px = cv2.perspectiveTransform(uv, H).reshape(-1, 2)
    vals = cv2.remap(np.asarray(gray, np.float32), px[:, 0].reshape(1, -1).copy(),
                     px[:, 1].reshape(1, -1).copy(), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    return np.median(vals.reshape(n, n, 9), axis=2)


def edge_line_fallback(gray: np.ndarray, start: np.ndarray, bits: np.ndarray
                       ) -> tuple[EdgeCorners, np.ndarray] | None:
    """The code's corners from its outer edge lines, and its inner cells' whiteness read
    there, for a code whose interior fit placed a corner far from its border.

    Args:
        gray: (H, W) grey image.
        start: (4, 2) the fit's start corners (the decoded quad), px, TL, TR, BR, BL.
        bits: (n, n) the code's cells with border, 1 = white.

    Returns:
        (the edge corners, (n-2)² inner cells' whiteness: 0 at the border's black, 1 at the
        white cells' median), or None where an edge is not found or the code has no white
        cell.
    """
    e = outer_edge_corners(gray, start)
    if e is None:
        return None
    n = bits.shape[0]
    lv = read_cells(gray, e.corners_px, n)
    ring = np.ones((n, n), bool)
    ring[1:-1, 1:-1] = False
    inner, inner_bits = lv[1:-1, 1:-1].ravel(), bits[1:-1, 1:-1].ravel()
    if not (inner_bits > 0.5).any():
        return None
    black = float(np.median(lv[ring]))
    white = float(np.median(inner[inner_bits > 0.5]))
    if white - black <= 0:
        return None
    return e, (inner - black) / (white - black)
