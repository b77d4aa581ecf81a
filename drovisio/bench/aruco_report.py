"""The figures of ``drovisio bench aruco``: what one scene row gathers (:class:`Stats`) and the
table and JSON made of the rows (:func:`report`).

Rows are keyed by (scene kind, brick count) and hold three :class:`Stats`: the detector
given gravity, the detector without it, and AprilTag 3 on the same frames (empty when it did
not run). Times are in seconds in :class:`Stats`, milliseconds in the report.
"""

from __future__ import annotations

import argparse
import math
import statistics
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["FLIP_DEG", "MIN_CODE_PX", "SIZE_BINS", "Rows", "Stats", "report"]

FLIP_DEG = 20.0
MIN_CODE_PX = 14.0
#: recall is also reported by the size of a brick's largest countable code (px across)
SIZE_BINS = ((MIN_CODE_PX, 20.0, "14-20 px"), (20.0, 30.0, "20-30 px"), (30.0, math.inf, ">30 px"))


@dataclass
class Stats:
    frames: int = 0
    t_ours: list[float] = field(default_factory=list)
    t_plain: list[float] = field(default_factory=list)
    countable: int = 0
    found: int = 0
    false: int = 0
    lateral_mm: list[float] = field(default_factory=list)
    depth_pct: list[float] = field(default_factory=list)
    yaw_deg: list[float] = field(default_factory=list)
    flips: int = 0
    unflagged_flips: int = 0
    ambiguous: int = 0
    poses: int = 0
    by_size: dict[str, list[int]] = field(default_factory=dict)
    """size bin -> [countable, found]"""
    t_peer: list[float] = field(default_factory=list)
    """AprilTag 3's time per frame (the row with gravity holds AprilTag's figures)."""


Rows = dict[tuple[str, int], tuple[Stats, Stats, Stats]]
"""(scene kind, bricks) → (with gravity, without gravity, AprilTag 3)."""

_HEADER = (f"{'scene':<10}{'grav':>5}{'frames':>7}{'ours ms':>9}{'plain ms':>9}{'ratio':>7}"
           f"{'recall':>13}{'lat p50/p95 mm':>16}{'depth p50/p95 %':>17}"
           f"{'yaw p50/p95 deg':>17}{'flips':>7}{'unflag':>7}{'ambig':>7}{'false':>7}")


def pct(v: list[float], q: float) -> float:
    """The ``q``-th percentile of ``v`` (NaN for none)."""
    return float(np.percentile(v, q)) if v else float("nan")


def _fmt(x: float, nd: int = 1) -> str:
    return "  -  " if not np.isfinite(x) else f"{x:.{nd}f}"


def _scene_name(kind: str, n_b: int) -> str:
    return f"{n_b} brick" + ("s" if n_b != 1 else "") if kind == "bricks" else "no brick"


def _recall_text(found: int, countable: int) -> str:
    return f"{found}/{countable} {100 * found / countable:.1f}%" if countable else "-"


def _error_cells(lat: list[float], dep: list[float], yaw: list[float]) -> str:
    """Median and 95th percentile of the lateral, depth and yaw errors, as table cells."""
    return (f"{_fmt(pct(lat, 50)):>7}/{_fmt(pct(lat, 95)):<8}"
            f"{_fmt(pct(dep, 50), 2):>8}/{_fmt(pct(dep, 95), 2):<8}"
            f"{_fmt(pct(yaw, 50), 2):>8}/{_fmt(pct(yaw, 95), 2):<8}")


def report(rows: Rows, corner_acc: dict[str, list[float]], args: argparse.Namespace
           ) -> dict[str, Any]:
    """The benchmark's table (``"text"``) and the same figures as JSON (``"data"``)."""
    lines = [_HEADER, "-" * len(_HEADER)]
    data: dict[str, Any] = {"threads": args.threads, "repeat": args.repeat,
                            "clock": args.clock, "rows": []}
    for (kind, n_b), triple in rows.items():
        for grav, st in zip(("yes", "no"), triple[:2]):
            line, row = _detector_row(kind, n_b, grav, st, triple[0])
            lines.append(line)
            data["rows"].append(row)
    for (kind, n_b), triple in rows.items():   # AprilTag 3 on the same frames
        if triple[2].frames:
            line, row = _apriltag_row(kind, n_b, triple[2], triple[0])
            lines.append(line)
            data["rows"].append(row)
    for gi, grav in enumerate(("yes", "no")):  # totals over brick scenes
        sts = [t[gi] for (kind, _), t in rows.items() if kind == "bricks"]
        if sts:
            lines.append(_total_line(grav, sts))
    lines += _recall_by_size(rows, data)
    lines.append("")
    lines += _legend(args)
    lines += _corner_lines(corner_acc, data)
    return {"text": "\n".join(lines), "data": data}


def _detector_row(kind: str, n_b: int, grav: str, st: Stats, timed: Stats
                  ) -> tuple[str, dict[str, Any]]:
    """One scene's line and JSON row for the detector; the times are ``timed``'s (the run
    given gravity), shown on its line only."""
    t_o = statistics.median(timed.t_ours) * 1e3 if timed.t_ours else float("nan")
    t_p = statistics.median(timed.t_plain) * 1e3 if timed.t_plain else float("nan")
    # the median of per-frame ratios (both timed on the same frame, interleaved: the
    # machine's load cancels better than in a ratio of medians)
    ratio = (statistics.median(o / p for o, p in zip(timed.t_ours, timed.t_plain))
             if timed.t_ours else float("nan"))
    timing = (f"{_fmt(t_o, 2):>9}{_fmt(t_p, 2):>9}{_fmt(ratio, 2):>7}"
              if grav == "yes" else f"{'':>9}{'':>9}{'':>7}")
    rec = _recall_text(st.found, st.countable)
    line = (f"{_scene_name(kind, n_b):<10}{grav:>5}{st.frames:>7}{timing}{rec:>13}"
            f"{_error_cells(st.lateral_mm, st.depth_pct, st.yaw_deg)}"
            f"{st.flips:>7}{st.unflagged_flips:>7}{st.ambiguous:>7}{st.false:>7}")
    row = {
        "scene": kind, "bricks": n_b, "gravity": grav == "yes", "frames": st.frames,
        "ours_ms_median": t_o, "plain_ms_median": t_p, "ratio_per_frame_median": ratio,
        "ratio_of_medians": t_o / t_p,
        "countable": st.countable, "found": st.found, "poses": st.poses,
        "lateral_mm_p50": pct(st.lateral_mm, 50), "lateral_mm_p95": pct(st.lateral_mm, 95),
        "depth_pct_p50": pct(st.depth_pct, 50), "depth_pct_p95": pct(st.depth_pct, 95),
        "yaw_deg_p50": pct(st.yaw_deg, 50), "yaw_deg_p95": pct(st.yaw_deg, 95),
        "flips": st.flips, "unflagged_flips": st.unflagged_flips,
        "ambiguous": st.ambiguous, "false_bricks": st.false}
    return line, row


def _apriltag_row(kind: str, n_b: int, st: Stats, timed: Stats
                  ) -> tuple[str, dict[str, Any]]:
    """One scene's line and JSON row for AprilTag 3, timed against plain ``detectMarkers``
    on the same frames (``timed.t_plain``)."""
    t_a = statistics.median(st.t_peer) * 1e3
    ratio = statistics.median(a / p for a, p in zip(st.t_peer, timed.t_plain))
    rec = _recall_text(st.found, st.countable)
    line = (f"{_scene_name(kind, n_b):<10}{'AT3':>5}{st.frames:>7}{_fmt(t_a, 2):>9}"
            f"{_fmt(statistics.median(timed.t_plain) * 1e3, 2):>9}"
            f"{_fmt(ratio, 2):>7}{rec:>13}{'':>67}{st.false:>7}")
    row = {"scene": kind, "bricks": n_b, "method": "apriltag3",
           "frames": st.frames, "apriltag_ms_median": t_a,
           "ratio_per_frame_median": ratio, "countable": st.countable,
           "found": st.found, "false_bricks": st.false}
    return line, row


def _total_line(grav: str, sts: list[Stats]) -> str:
    """All brick scenes together, with or without gravity."""
    cnt = sum(s.countable for s in sts)
    fnd = sum(s.found for s in sts)
    lat = [x for s in sts for x in s.lateral_mm]
    dep = [x for s in sts for x in s.depth_pct]
    yaw = [x for s in sts for x in s.yaw_deg]
    return (f"{'all':<10}{grav:>5}{sum(s.frames for s in sts):>7}{'':>25}"
            f"{_recall_text(fnd, cnt):>13}"
            f"{_error_cells(lat, dep, yaw)}"
            f"{sum(s.flips for s in sts):>7}{sum(s.unflagged_flips for s in sts):>7}"
            f"{sum(s.ambiguous for s in sts):>7}{sum(s.false for s in sts):>7}")


def _recall_by_size(rows: Rows, data: dict[str, Any]) -> list[str]:
    """Recall by code size over brick scenes (with gravity; AprilTag 3 when run)."""
    lines = []
    methods = [("drovisio", 0)] + ([("apriltag3", 2)] if any(
        t[2].frames for t in rows.values()) else [])
    data["recall_by_size"] = {}
    for mname, i in methods:
        sts = [t[i] for (kind, _), t in rows.items() if kind == "bricks"]
        cells = []
        data["recall_by_size"][mname] = {}
        for _, _, bname in SIZE_BINS:
            c = sum(s.by_size.get(bname, [0, 0])[0] for s in sts)
            f = sum(s.by_size.get(bname, [0, 0])[1] for s in sts)
            data["recall_by_size"][mname][bname] = {"countable": c, "found": f,
                                                    "recall": f / c if c else None}
            cells.append(f"{bname} {f}/{c} {100 * f / c:.1f}%" if c else f"{bname} -")
        lines.append(f"recall by code size, {mname}: " + ", ".join(cells))
    return lines


def _legend(args: argparse.Namespace) -> list[str]:
    clock = ("CPU time of the thread" if args.clock == "cpu" else "wall-clock time")
    return [
        f"times: {clock}, median over frames of the fastest of {args.repeat} runs, "
        f"OpenCV threads = {args.threads}; ratio: median over frames of ours (whole "
        "detect + pose, gravity given) / plain detectMarkers (default parameters) "
        "on the same frame.",
        "lateral: x/y error of tvec in the camera frame; depth: |dz|/z; yaw: rotation "
        "about the brick's z axis; flip: rotation error > 20 deg;",
        "unflag: flips not flagged ambiguous; recall: bricks with a fully visible code "
        f">= {MIN_CODE_PX:g} px across (sqrt of its area) reported with the right id; AT3: "
        "AprilTag 3 (pupil-apriltags, decimate 1) on the same frames."]


def _corner_lines(corner_acc: dict[str, list[float]], data: dict[str, Any]) -> list[str]:
    """Our refined corners and OpenCV's raw ones against the renderer's true corners."""
    lines = []
    for name in ("raw", "ours"):
        rad = corner_acc.get(name + "_radial", [])
        sq = corner_acc.get(name + "_sq", [])
        if rad:
            lines.append(f"corners {name:<5} (blur <= 1 px, {len(rad)} corners): mean signed "
                         f"radial {np.mean(rad):+.3f} px, RMS {math.sqrt(np.mean(sq)):.3f} px")
            data[f"corners_{name}"] = {"n": len(rad), "mean_radial_px": float(np.mean(rad)),
                                       "rms_px": math.sqrt(float(np.mean(sq)))}
    return lines
