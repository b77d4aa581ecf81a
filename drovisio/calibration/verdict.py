"""The verdict: is this calibration good enough? Judged by projection uncertainty, not by RMS.

``ok`` only when all of these hold:

1. a solve exists with at least :attr:`VerdictRules.min_views` (6) kept views;
2. over the region of interest (default: the whole image), the 95th percentile of the
   projection uncertainty σ(q) (1-σ, worst direction; see :mod:`uncertainty`) is at most
   :attr:`VerdictRules.max_uncertainty_p95_px` (0.5 px);
3. the cross-validation agrees with the uncertainty: the difference between the two halves'
   models, divided at each image point by the 1-σ their own covariances predict for it, has a
   p95 of at most 4 (≈ √χ²₉(0.95) = 4.1: if the halves are consistent, z ≤ 4.1 holds at every
   point with 95 % probability, since a 9-parameter difference cannot exceed its Mahalanobis
   norm in any direction). More means the lens model does not fit or some views are
   inconsistent (a bent board, a moving camera). Skipped below 8 views.

Otherwise ``reasons`` say why, naming the image regions whose uncertainty is too high and
whether they lack data ("corners of the image not covered: top-left, bottom-left: move the
board to the bottom-left") or lack geometry (all views facing the camera, all at one distance).
``advice`` carries non-blocking remarks (fixed coefficients, rejected views, high RMS).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio.calibration.coverage import REGION_COVERED, Coverage, region_boxes
from drovisio.calibration.solve import CalibrationResult

__all__ = ["Verdict", "VerdictRules", "judge"]

_CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")
_EDGES = ("top", "bottom", "left", "right")


@dataclass
class VerdictRules:
    max_uncertainty_p95_px: float = 0.5
    min_views: int = 6
    max_cross_validation_z: float = 4.0
    min_tilt_range_deg: float = 20.0
    min_distance_ratio: float = 1.3
    high_rms_px: float = 1.0


@dataclass
class Verdict:
    ok: bool
    reasons: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    region_uncertainty_px: dict[str, float] = field(default_factory=dict)
    """p95 of σ per named region (inside the region of interest)."""

    def to_json(self) -> dict:
        return {"ok": self.ok, "reasons": list(self.reasons), "advice": list(self.advice),
                "region_uncertainty_p95_px": {k: round(v, 4) for k, v in
                                              self.region_uncertainty_px.items()}}


def _region_p95(result: CalibrationResult, roi: tuple[float, float, float, float] | None
                ) -> dict[str, float]:
    um = result.uncertainty
    gx, gy = np.meshgrid(um.xs, um.ys)
    w, h = result.camera.width, result.camera.height
    inroi = um.mask(roi)
    out = {}
    for name, (x0, y0, x1, y1) in region_boxes(w, h).items():
        m = (gx >= x0) & (gx <= x1) & (gy >= y0) & (gy <= y1) & inroi
        if m.any():
            out[name] = float(np.percentile(um.sigma[m], 95))
    return out


def _geometry_hints(coverage: Coverage, rules: VerdictRules) -> list[str]:
    hints = []
    t = coverage.tilt_spread()
    if t["range_deg"] is not None and t["max_deg"] < rules.min_tilt_range_deg + 5:
        hints.append(f"the boards nearly face the camera (tilts {t['min_deg']:.0f}–"
                     f"{t['max_deg']:.0f}°): add views with the board tilted 30–45°")
    d = coverage.distance_spread()
    if d["ratio"] is not None and d["ratio"] < rules.min_distance_ratio:
        hints.append(f"all views at about the same distance ({d['min_m']:.2f}–{d['max_m']:.2f}"
                     " m): add views nearer and farther")
    return hints


def judge(result: CalibrationResult | None, coverage: Coverage,
          rules: VerdictRules | None = None,
          roi: tuple[float, float, float, float] | None = None,
          n_views: int | None = None, suggested_region: str | None = None) -> Verdict:
    """Judge a :class:`~drovisio.calibration.solve.CalibrationResult` (or None: not solved).

    ``suggested_region`` (the next-pose hint's region) is named in "move the board to ..." when
    it is one of the uncovered regions, so that the reasons and the hint agree.
    """
    r = rules or VerdictRules()
    if result is None:
        n = coverage.n_views if n_views is None else n_views
        return Verdict(False, [f"not solved yet: {n} view(s) kept, a solve needs 3 and a "
                               f"verdict {r.min_views}"])
    reasons: list[str] = []
    advice: list[str] = []
    n = len(result.per_view)
    if n < r.min_views:
        reasons.append(f"only {n} views kept; at least {r.min_views} are needed for a verdict")
    stats = result.uncertainty.stats(roi)
    where = "the region of interest" if roi else "the image"
    regions = _region_p95(result, roi)
    p95 = stats["p95"]
    if p95 is None:
        # no point of the image has a finite uncertainty: the solve determines nothing there
        reasons.append(f"projection uncertainty unknown over {where} (no point of it has a "
                       "finite uncertainty): add views that cover it and solve again")
    elif p95 > r.max_uncertainty_p95_px:
        reasons.append(f"projection uncertainty too high: p95 {p95:.2f} px over {where} "
                       f"(limit {r.max_uncertainty_p95_px:g} px), max {stats['max']:.2f} px")
        _uncertain_regions(regions, coverage, r, suggested_region, reasons, advice)
    cv = result.cross_validation or {}
    z = cv.get("normalized_p95")
    if z is not None and z > r.max_cross_validation_z:
        reasons.append(f"the two halves of the views disagree by {cv['p95']:.2f} px (p95), "
                       f"{z:.1f}x what their uncertainty allows (limit "
                       f"{r.max_cross_validation_z:g}x): the lens model does not fit or some "
                       "views are inconsistent (a bent board, a moving camera)")
    advice.extend(_advice(result, r))
    return Verdict(not reasons, reasons, advice, regions)


def _uncertain_regions(regions: dict[str, float], coverage: Coverage, r: VerdictRules,
                       suggested_region: str | None, reasons: list[str],
                       advice: list[str]) -> None:
    """Why the uncertainty is too high, region by region: uncovered corners, edges and
    centre (where to move the board), covered regions that need more or other views; the
    geometry hints go to ``reasons`` when they explain it, else to ``advice``."""
    bad = {k: v for k, v in regions.items() if v > r.max_uncertainty_p95_px}
    uncovered = [k for k in bad if coverage.regions.get(k, 0.0) < REGION_COVERED]
    corners = sorted([k for k in uncovered if k in _CORNERS], key=lambda k: -bad[k])
    edges = sorted([k for k in uncovered if k in _EDGES], key=lambda k: -bad[k])
    if corners:
        reasons.append(_uncovered("corners", corners, bad, suggested_region, ""))
    if edges:
        reasons.append(_uncovered("edges", edges, bad, suggested_region, " edge"))
    if "centre" in uncovered:
        reasons.append("the centre of the image is not covered: hold the board in the "
                       "middle")
    covered_bad = sorted([k for k in bad if k not in uncovered], key=lambda k: -bad[k])
    hints = _geometry_hints(coverage, r)
    if covered_bad or not uncovered:
        where_bad = (" (" + ", ".join(f"{k} {bad[k]:.2f} px" for k in covered_bad) + ")"
                     if covered_bad else "")
        reasons.append(f"uncertainty is high where the image is covered{where_bad}: "
                       "add views there" + ("" if hints else
                                           ", tilted 30–45° and at other distances"))
        reasons.extend(hints)
    else:
        advice.extend(hints)


def _uncovered(what: str, names: list[str], bad: dict[str, float],
               suggested_region: str | None, suffix: str) -> str:
    """One reason naming uncovered regions (``what``: corners or edges) with their
    uncertainty and where to move the board: the hint's region when it is one of them, else
    the worst."""
    return (f"{what} of the image not covered: " + ", ".join(
        f"{k} ({bad[k]:.1f} px)" for k in names) + f": move the board to the "
        f"{suggested_region if suggested_region in names else names[0]}{suffix}")


def _advice(result: CalibrationResult, r: VerdictRules) -> list[str]:
    """The non-blocking remarks: fixed coefficients, rejected views, a high RMS."""
    advice = [f"{k} {why}" for k, why in (result.fixed or {}).items()]
    for rej in result.rejected:
        advice.append(f"view {rej['file']} rejected: {rej['reason']}")
    if result.rms_px > r.high_rms_px:
        advice.append(f"RMS {result.rms_px:.2f} px is high for a chessboard: check the board is "
                      "flat and the images are sharp")
    return advice
