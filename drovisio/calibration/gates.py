"""Per-view gates: is this view worth keeping? Each gate returns a verdict with its reason.

* **Sharpness / motion blur** — measured where it matters, on the board's own edges: across the
  middle of every square side between two detected corners the intensity profile is sampled
  (averaged along the side) and its 10–90 % rise width is taken, in pixels. Edges are grouped by
  their direction in the image (quantised to 8 bins over 180°); the view's blur is the median
  width of the worst direction with at least 4 edges. A defocused view has wide edges in every
  direction; a motion-blurred one in the direction of the motion. A sharp view has widths of
  1.3 px (renders) to 2.2–3.2 px (OpenCV's sample webcam views); a 13 px motion streak makes
  them ~10.5 px, a 5 px one 4.3 px, a Gaussian defocus of σ = 2 px 5.3 px. The gate rejects
  above :data:`MAX_EDGE_WIDTH_PX` (4 px, or 0.5 % of the image diagonal on larger images) — or
  above 0.45 × the square side for boards so small that the profile cannot be measured. Motion blur still "detects", but it smears the corners
  along the motion and biases the focal length. On a ChArUco board the white squares hold
  markers, so a square side has only (1 − marker ratio)/2 of a square of white beside it: there
  the profile is fitted as a blurred white bar of that width between the black square and the
  marker's border (σ on a grid, levels by least squares), width = 2.563 σ (sharp renders
  1.7–3.4 px, σ = 1.5 px defocus 4.4 px, an 8 px motion streak 6.5 px).
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

import math
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


def _rise_width(profile: np.ndarray, step: float) -> float:
    """10–90 % rise distance of a step profile (either polarity), pixels; NaN if flat."""
    n = profile.size
    k = max(2, n // 8)
    lo, hi = float(np.mean(profile[:k])), float(np.mean(profile[-k:]))
    if abs(hi - lo) < 8.0:  # no measurable step (8 grey levels)
        return math.nan
    p = (profile - lo) / (hi - lo)  # 0 → 1
    p = np.maximum.accumulate(p)  # monotone envelope against noise
    s = np.arange(n) * step

    def cross(level: float) -> float:
        idx = int(np.searchsorted(p, level))
        if idx <= 0:
            return s[0]
        if idx >= n:
            return s[-1]
        a, b = p[idx - 1], p[idx]
        return s[idx - 1] + (level - a) / max(b - a, 1e-9) * step

    return float(cross(0.9) - cross(0.1))


_SIGMAS = np.geomspace(0.2, 12.0, 64)
_W_PER_SIGMA = 2.5631  # 10–90 % rise of a Gaussian-blurred step, in σ


def _margin_width(profile: np.ndarray, s: np.ndarray, margin: float) -> float:
    """10–90 % width of the edge of a ChArUco square side: the profile (s from the black
    square, across the edge at 0, into the white margin of width ``margin`` before the
    marker's black border) is fitted as ``lo + amp·(Φ(s/σ) − Φ((s − m)/σ))`` over a grid of
    σ, the levels by linear least squares for each (all σ at once); NaN without a clear white
    margin (amp < 8 grey levels)."""
    z0 = s[None, :] / _SIGMAS[:, None]
    z1 = (s[None, :] - margin) / _SIGMAS[:, None]
    # Φ by the tanh approximation (as the code fit's)
    B = 0.5 * (np.tanh(z0 * (0.7978845608 + 0.0356774081 * z0 * z0))
               - np.tanh(z1 * (0.7978845608 + 0.0356774081 * z1 * z1)))      # (σ, n)
    bm = B.mean(axis=1, keepdims=True)
    pm = float(profile.mean())
    Bc = B - bm
    vb = (Bc * Bc).sum(axis=1)
    cov = Bc @ (profile - pm)
    amp = cov / np.maximum(vb, 1e-12)
    sse = float(((profile - pm) ** 2).sum()) - amp * cov        # residual of each σ
    sse = np.where((amp >= 8.0) & (vb > 1e-9), sse, np.inf)
    k = int(np.argmin(sse))
    return _W_PER_SIGMA * float(_SIGMAS[k]) if np.isfinite(sse[k]) else math.nan


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
        ts = np.linspace(0.3, 0.7, 7)
        mids = a[None, :] + ts[:, None] * v[None, :]
        pts = mids[:, None, :] + s[None, :, None] * nrm[None, None, :]
        mx = pts[..., 0].astype(np.float32)
        my = pts[..., 1].astype(np.float32)
        samp = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if board.kind == "charuco":
            # the white square holds a marker: white only for (1 − ratio)/2 of a square
            prof = samp.mean(axis=0)
            margin = (1.0 - board.marker_ratio) / 2.0 * L
            if prof[s > 0][:8].mean() < prof[s < 0][-8:].mean():
                prof, s_or = prof[::-1], -s[::-1]      # white side toward +s
            else:
                s_or = s
            keep = s_or <= margin + 0.5 * margin       # into the marker's black border
            w = _margin_width(prof[keep], s_or[keep], margin)
        else:
            w = _rise_width(samp.mean(axis=0), step)
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
