"""Per-view gates: is this view worth keeping? Each gate returns a verdict with its reason.

* **Sharpness / motion blur** — measured where it matters, on the board's own edges, as a
  camera's optics spread them: across the middle of every square side between two detected
  corners, 9 intensity profiles are sampled; each is located at its own 50 % crossing
  (sub-pixel) and shifted onto it before they are averaged (the slanted-edge method: the line
  between two corners is not exactly on the edge, and averaging misregistered profiles widens
  the edge), and the 10–90 % rise of that edge-spread function is the edge's width, pixels
  (a Gaussian blur of σ gives 2.56 σ). Edges are grouped by their direction in the image
  (quantised to 8 bins over 180°); the view's blur is the median width of the worst direction
  with at least 4 edges. A defocused view has wide edges in every direction; a motion-blurred
  one in the direction of the motion. Measured: OpenCV's ChArUco tutorial photo 1.0 px (the
  same Gaussian-blurred by σ = 1 / 1.5 px: 2.8 / 4.1 px), OpenCV's 13 webcam views 2.2–3.0 px
  (blurred by σ = 1.5 px: 4.5–5.0 px), renders 1.3 px, a 13 px motion streak ~10 px. The gate
  rejects above :data:`MAX_EDGE_WIDTH_PX` (4 px, or 0.5 % of the image diagonal on larger
  images) — or above 0.45 × the square side for boards so small that the profile cannot be
  measured. Motion blur still "detects", but it smears the corners along the motion and
  biases the focal length. On a ChArUco board the white squares hold markers, so a square
  side has only (1 − marker ratio)/2 of a square of white beside it: there the white level
  is the peak of that margin, nothing beyond the marker's border is used, and the width is
  read through the same measurement of a Gaussian-blurred bar of the margin's width (a narrow
  margin never reaches white under blur; renders: sharp 2.0–2.1 px, σ = 1.5 px 4.1–4.2 px,
  an 8 px motion streak 5.0–6.1 px).
* **Size** — squares smaller than 6 px are not refined reliably.
* **Stillness** — between two consecutive frames of a live stream, the board's corners may move
  at most :data:`MAX_MOTION_PX` (1.5 px, the largest corner displacement; at 30 fps that is at
  most ~1 px of smear in a typical exposure); a moving board is smeared and, with a rolling
  shutter, skewed.
* **Novelty** — against the views already kept: a new view must differ from every kept one by
  a mean corner displacement of at least 4 % of the image diagonal, or by a board tilt of at
  least 10°; otherwise it adds weight but no new information.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from drovisio.calibration.board import BoardSpec, Detection, to_gray

__all__ = ["GateResult", "EdgeSharpness", "edge_sharpness", "gate_sharpness", "gate_size",
           "gate_still", "gate_novel", "corner_motion_px", "MAX_EDGE_WIDTH_PX",
           "MAX_MOTION_PX", "NOVELTY_FRACTION", "NOVELTY_TILT_DEG", "MIN_SQUARE_PX"]

MAX_EDGE_WIDTH_PX = 4.0
MAX_MOTION_PX = 1.5
NOVELTY_FRACTION = 0.04
NOVELTY_TILT_DEG = 10.0
MIN_SQUARE_PX = 6.0


@dataclass
class GateResult:
    """One gate's verdict: ``ok``, the measured ``value``, the ``limit`` and a ``reason``."""

    name: str
    ok: bool
    value: float
    limit: float
    reason: str = ""

    def to_json(self) -> dict:
        return {"gate": self.name, "ok": self.ok, "value": _r(self.value),
                "limit": _r(self.limit), "reason": self.reason}


def _r(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 4)


@dataclass
class EdgeSharpness:
    """Edge widths of a view's board, by edge direction."""

    width_px: float
    """Median 10–90 % edge width of the worst edge direction, pixels."""
    direction_deg: float
    """Direction (in the image, 0 = +x) *across* which the edges are widest: the blur's."""
    best_width_px: float
    """Median width of the sharpest direction."""
    n_edges: int


def _edge_list(det: Detection, board: BoardSpec) -> list[tuple[np.ndarray, np.ndarray]]:
    pos = {int(k): c for k, c in zip(det.ids, det.corners)}
    edges = []
    for k, c in pos.items():
        i, j = k % board.cols, k // board.cols
        if i + 1 < board.cols and k + 1 in pos:
            edges.append((c, pos[k + 1]))
        if j + 1 < board.rows and k + board.cols in pos:
            edges.append((c, pos[k + board.cols]))
    return edges


def _crossing(p: np.ndarray, s: np.ndarray, step: float, level: float, start: int,
              direction: int) -> float:
    """Where the rising profile ``p`` (sampled at ``s``, pixels) crosses ``level``, walking
    from index ``start`` in ``direction``; interpolated between samples, pixels."""
    i = start
    if direction < 0:
        while i > 0 and p[i] > level:
            i -= 1
        j = i + 1
    else:
        while i < p.size - 1 and p[i] < level:
            i += 1
        j, i = i, i - 1
    if i < 0 or j >= p.size:
        return math.nan
    a, b = p[i], p[j]
    return float(s[i] + (level - a) / (b - a) * step) if b != a else float(s[i])


def _edge_positions(samp: np.ndarray, s: np.ndarray, step: float,
                    levels: Callable[[np.ndarray], tuple[float, float]]
                    ) -> list[tuple[np.ndarray, float]]:
    """Each profile with contrast (8 grey levels) and its edge: the rising crossing of its
    middle level nearest to s = 0, sub-pixel (pixels)."""
    shifts = []
    for p in samp:
        lo, hi = levels(p)
        if hi - lo < 8.0:
            continue
        mid = 0.5 * (lo + hi)
        above = p >= mid
        ups = np.flatnonzero(~above[:-1] & above[1:])   # rising crossings of the middle
        if ups.size == 0:
            continue
        k = int(ups[np.argmin(np.abs(s[ups]))])
        shifts.append((p, s[k] + (mid - p[k]) / max(p[k + 1] - p[k], 1e-9) * step))
    return shifts


def _esf_width(samp: np.ndarray, s: np.ndarray, white_lim: float | None, step: float
               ) -> float:
    """10–90 % rise of the edge-spread function of one board edge, pixels; NaN when the edge
    has no measurable contrast (8 grey levels).

    Args:
        samp: (lines, n) intensity profiles across the edge, sampled at ``s``.
        s: (n,) signed distance from the corner-to-corner line, pixels (step ``step``).
        white_lim: How far the white side may be used (a ChArUco square side has only the
            margin before the marker's border); None: as far as the dark side.

    Each line's edge is located at its 50 % crossing (sub-pixel) and the lines are shifted
    onto it before they are averaged (the slanted-edge method: a line between two corners
    is not exactly on the edge, and averaging misregistered lines would widen it); the
    levels are the dark plateau and the white plateau (the white margin's peak on a ChArUco
    board), and the width is the distance between the 10 % and 90 % crossings either side of
    the 50 % one, interpolated between samples.
    """
    hw = float(-s[0])
    near = np.abs(s) <= min(2.0, hw)
    if samp[:, (s > 0) & near].mean() < samp[:, (s < 0) & near].mean():
        samp, s = samp[:, ::-1], -s[::-1]            # white side toward +s
    if white_lim is not None:
        keep = s <= white_lim
        samp, s = samp[:, keep], s[keep]
    dark = s < -0.5 * hw
    white = (s > 0.5 * hw) if white_lim is None else (s > 0)
    if not dark.any() or not white.any():
        return math.nan

    def levels(p: np.ndarray) -> tuple[float, float]:
        lo = float(np.median(p[..., dark]))
        hi = float(np.median(p[..., white])) if white_lim is None else float(p[..., white].max())
        return lo, hi

    shifts = _edge_positions(samp, s, step, levels)
    if len(shifts) < max(2, len(samp) // 2):
        return math.nan
    xs = np.array([x for _, x in shifts])
    med = float(np.median(xs))
    # each line shifted onto the median edge; a line across a defect (>1.5 px off) is out
    good = [np.interp(s, s - (x - med), p) for p, x in shifts if abs(x - med) <= 1.5]
    if not good:
        return math.nan
    esf = np.mean(good, axis=0)
    lo, hi = levels(esf)
    if hi - lo < 8.0:
        return math.nan
    q = (esf - lo) / (hi - lo)
    i50 = int(np.argmin(np.abs(s - med)))
    w = _crossing(q, s, step, 0.9, i50, +1) - _crossing(q, s, step, 0.1, i50, -1)
    if white_lim is None or not math.isfinite(w):
        return w
    # a margin narrow against the blur never reaches the white level: its peak is lower and
    # the rise measured against it shorter. Invert the measurement of a Gaussian-blurred bar
    # of the margin's width (same levels, same crossings) to the width of a free edge.
    sig, wm = _bar_table()
    rel = w / white_lim
    if rel <= wm[0]:
        return w
    return _W_PER_SIGMA * white_lim * float(np.interp(rel, wm, sig))


_W_PER_SIGMA = 2.5631  # 10–90 % rise of a Gaussian-blurred step, in σ


@functools.lru_cache(maxsize=1)
def _bar_table() -> tuple[np.ndarray, np.ndarray]:
    """(σ, measured width) for a white bar 1 px wide between two black regions, blurred by a
    Gaussian of σ and measured as :func:`_esf_width` measures (levels: the dark plateau and
    the bar's peak), up to where the width stops growing with σ. Everything scales with the
    bar's width: a bar of m px has σ·m and width·m."""
    sigmas = np.geomspace(0.02, 2.0, 160)
    s = np.linspace(-6.0 * sigmas[-1], 1.0, 8001)

    def phi(z: np.ndarray) -> np.ndarray:   # Φ by the tanh approximation (error < 2e-4)
        return 0.5 * (1.0 + np.tanh(z * (0.7978845608 + 0.0356774081 * z * z)))

    q_all = phi(s[None, :] / sigmas[:, None]) - phi((s[None, :] - 1.0) / sigmas[:, None])
    sig: list[float] = []
    out: list[float] = []
    for sg, q in zip(sigmas, q_all):
        top = int(np.argmax(q))
        r = q[: top + 1] / q[top]
        if r.size < 3 or np.any(np.diff(r) < 0):
            break
        w = float(np.interp(0.9, r, s[: top + 1]) - np.interp(0.1, r, s[: top + 1]))
        if out and w <= out[-1]:
            break
        sig.append(float(sg))
        out.append(w)
    return np.array(sig), np.array(out)


def edge_sharpness(image: np.ndarray, det: Detection, board: BoardSpec) -> EdgeSharpness:
    """Measure the board's edge widths (see the module docstring)."""
    gray = to_gray(image).astype(np.float32)
    edges = _edge_list(det, board)
    widths, angles = [], []
    step = 0.25
    for a, b in edges:
        v = b - a
        L = float(np.hypot(*v))
        if L < 4:
            continue
        d = v / L
        nrm = np.array([-d[1], d[0]])
        half = 0.45 * L
        s = np.arange(-half, half + 1e-9, step)
        ts = np.linspace(0.3, 0.7, 9)
        mids = a[None, :] + ts[:, None] * v[None, :]
        pts = mids[:, None, :] + s[None, :, None] * nrm[None, None, :]
        mx = pts[..., 0].astype(np.float32)
        my = pts[..., 1].astype(np.float32)
        samp = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # a ChArUco white square holds a marker: white only for (1 − ratio)/2 of a square
        white_lim = ((1.0 - board.marker_ratio) / 2.0 * L if board.kind == "charuco"
                     else None)
        w = _esf_width(samp.astype(np.float64), s, white_lim, step)
        if math.isfinite(w):
            widths.append(w)
            angles.append(math.degrees(math.atan2(nrm[1], nrm[0])) % 180.0)
    if not widths:
        return EdgeSharpness(math.nan, math.nan, math.nan, 0)
    widths_a = np.array(widths)
    bins = np.round(np.array(angles) / 22.5).astype(int) % 8  # bin 0 centred on 0°
    meds = []
    for bi in range(8):
        sel = widths_a[bins == bi]
        if sel.size >= 4:
            meds.append((float(np.median(sel)), bi))
    if not meds:
        m = float(np.median(widths_a))
        return EdgeSharpness(m, math.nan, m, len(widths))
    worst = max(meds)
    best = min(meds)
    return EdgeSharpness(worst[0], worst[1] * 22.5, best[0], len(widths))


def gate_sharpness(image: np.ndarray, det: Detection, board: BoardSpec,
                   max_width_px: float = MAX_EDGE_WIDTH_PX) -> tuple[GateResult, EdgeSharpness]:
    """Reject blurred or motion-blurred views (see the module docstring)."""
    es = edge_sharpness(image, det, board)
    w, h = det.image_size
    max_width_px = max(max_width_px, 0.005 * math.hypot(w, h))  # scales with the resolution
    limit = min(max_width_px, max(2.0, 0.45 * det.square_px))
    if not math.isfinite(es.width_px):
        return GateResult("sharpness", False, es.width_px, limit,
                          "no board edge has measurable contrast (too dark, washed out or "
                          "blurred)"), es
    ok = es.width_px <= limit
    reason = ""
    if not ok:
        motion = es.best_width_px < 0.6 * es.width_px
        kind = (f"motion blur ({_direction_word(es.direction_deg)})" if motion
                else "blur (out of focus or moving)")
        reason = (f"{kind}: board edges are {es.width_px:.1f} px wide (limit {limit:.1f} px); "
                  "hold the board and camera still, or add light for a shorter exposure")
    return GateResult("sharpness", ok, es.width_px, limit, reason), es


def _direction_word(deg: float) -> str:
    d = deg % 180.0
    if d < 22.5 or d >= 157.5:
        return "horizontal"
    if 67.5 <= d < 112.5:
        return "vertical"
    return "diagonal"


def gate_size(det: Detection, min_square_px: float = MIN_SQUARE_PX) -> GateResult:
    ok = det.square_px >= min_square_px
    return GateResult("size", ok, det.square_px, min_square_px,
                      "" if ok else f"board too small: squares of {det.square_px:.1f} px "
                                    f"(need {min_square_px:g}); bring it closer")


def corner_motion_px(a: Detection, b: Detection) -> float:
    """Largest displacement of the corners the two detections share, pixels (for a symmetric
    chessboard the 180°-turned labelling is tried too); inf when they share fewer than 4."""
    common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    if common.size < 4:
        return math.inf
    d1 = float(np.max(np.hypot(*(a.corners[ia] - b.corners[ib]).T)))
    if a.ids.size == b.ids.size and np.array_equal(a.ids, np.arange(a.ids.size)):
        d2 = float(np.max(np.hypot(*(a.corners[::-1] - b.corners).T)))
        return min(d1, d2)
    return d1


def gate_still(previous: Detection | None, current: Detection,
               max_motion_px: float = MAX_MOTION_PX) -> GateResult:
    """Is the board still since the previous frame? (No previous frame: not yet known.)"""
    if previous is None:
        return GateResult("still", False, math.inf, max_motion_px,
                          "waiting for a second frame to check that the board is still")
    m = corner_motion_px(previous, current)
    ok = m <= max_motion_px
    return GateResult("still", ok, m, max_motion_px,
                      "" if ok else f"board moving: corners moved {m:.1f} px since the previous "
                                    f"frame (limit {max_motion_px:g} px); hold it still")


def _mean_displacement(a: Detection, b: Detection) -> float:
    common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    if common.size < 4:
        return math.inf
    d1 = float(np.mean(np.hypot(*(a.corners[ia] - b.corners[ib]).T)))
    if a.ids.size == b.ids.size and np.array_equal(a.ids, np.arange(a.ids.size)):
        d1 = min(d1, float(np.mean(np.hypot(*(a.corners[::-1] - b.corners).T))))
    return d1


def gate_novel(current: Detection, kept: list[Detection], tilt_deg: float | None = None,
               kept_tilts_deg: list[float | None] | None = None,
               fraction: float = NOVELTY_FRACTION,
               min_tilt_change_deg: float = NOVELTY_TILT_DEG) -> GateResult:
    """Does the view differ enough from every kept view? Tilts (degrees, optional) let a view
    that only turns the board count as new."""
    w, h = current.image_size
    limit = fraction * math.hypot(w, h)
    if not kept:
        return GateResult("novel", True, math.inf, limit, "")
    kept_tilts = kept_tilts_deg or [None] * len(kept)
    nearest = math.inf
    for k, t in zip(kept, kept_tilts):
        d = _mean_displacement(current, k)
        tilt_differs = (tilt_deg is not None and t is not None
                        and abs(tilt_deg - t) >= min_tilt_change_deg)
        if d < limit and not tilt_differs:
            return GateResult("novel", False, d, limit,
                              f"too similar to a kept view (corners {d:.0f} px away on average,"
                              f" need {limit:.0f} px, or {min_tilt_change_deg:g}° more or less "
                              "tilt); move the board somewhere new")
        nearest = min(nearest, d)
    return GateResult("novel", True, nearest, limit, "")
