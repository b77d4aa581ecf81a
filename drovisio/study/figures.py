"""The study's figures (matplotlib, no display needed): one PNG per thesis figure.

* 6.2–6.9: box plots of the figure's error per step, one box per method side by side, one
  panel per layout (rows) and varied axis (columns), the 5 cm / 3° budget drawn as a line
  (for z in %, the 5 cm at each distance); methods that cannot read a layout are named in the
  panel, not dropped silently; the poses Drovisio flags ambiguous (without gravity the image
  cannot tell a square-on code from its mirror) are drawn and counted in the panel.
* 6.10: frame rate against the number of bricks in view, per method and layout.
* 6.11: resident memory over the run, per method.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from drovisio.fileio import save_figure
from drovisio.study.analysis import ERRORS
from drovisio.study.protocol import FIGURES

__all__ = ["box_figure", "fps_figure", "memory_figure"]


def _plt():
    """matplotlib with its file backend (deferred: heavy, and only the report draws)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def box_figure(fig_id: str, records: list[dict], methods: dict,
               not_applicable: dict, path: Path) -> dict:
    """Draw thesis figure ``fig_id`` from the per-frame ``records``; returns what was drawn
    (panels, boxes per method and step) so a test can read it back."""
    plt = _plt()
    spec = FIGURES[fig_id]
    recs = [r for r in records if r["figure"] == fig_id]
    rows = sorted({r["layout"] for r in recs})
    cols = [v for v in spec["vary"] if any(r["vary"] == v for r in recs)]
    drawn: dict = {"figure": fig_id, "panels": []}
    if not rows or not cols:
        return drawn
    # one column of panels, each about a phone screen wide at 90 dpi (648 px) with text of
    # 9 pt or more: legible on a 390 px phone scrolled sideways inside its box (report.html)
    n_panels = len(rows) * len(cols)
    fig, grid = plt.subplots(n_panels, 1, figsize=(7.2, 4.6 * n_panels), squeeze=False)
    axes = [[grid[i * len(cols) + j][0] for j in range(len(cols))] for i in range(len(rows))]
    names = _methods_in(methods, recs)
    for i, lay in enumerate(rows):
        for j, vary in enumerate(cols):
            here = _methods_in(names, [r for r in recs if r["layout"] == lay])
            panel_recs = [r for r in recs if r["layout"] == lay and r["vary"] == vary]
            drawn["panels"].append(_box_panel(axes[i][j], spec, panel_recs, lay, vary, here,
                                              methods, not_applicable.get(lay, {})))
    fig.suptitle(f"Fig. {fig_id}: {spec['title']}")
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)
    drawn["file"] = str(path)
    return drawn


def _methods_in(methods: Iterable[str], recs: list[dict]) -> list[str]:
    """The ``methods`` (in their order) that have a record in ``recs``."""
    return [m for m in methods if any(r["method"] == m for r in recs)]


def _box_panel(ax: Any, spec: dict, recs: list[dict], lay: str, vary: str, here: list[str],
               methods: dict, na: dict) -> dict:
    """One panel of a box figure: layout ``lay`` against the varied axis ``vary``, a box per
    method in ``here`` and step, the budget line, the notes; ``recs`` are the panel's
    records. Returns what was drawn."""
    err = spec["error"]
    label, budget = ERRORS[err]
    values = sorted({r["value"] for r in recs})
    panel: dict = {"layout": lay, "vary": vary, "values": values, "boxes": {}}
    width = 0.8 / max(1, len(here))
    for k, m in enumerate(here):
        panel["boxes"][m] = _method_boxes(ax, recs, values, m, err, methods[m],
                                          (k - (len(here) - 1) / 2) * width, width)
    _panel_axes(ax, values, vary, label, budget, lay)
    kind = "dots" if spec["kind"] == "dots" else "codes"
    notes = [f"{methods[m].label}: not applicable ({why})" for m, why in na.items()
             if m in methods and (m.startswith("drovisio-dots") == (kind == "dots"))]
    for m in here:
        mine = [r for r in recs if r["method"] == m and r["found"]]
        flagged = sum(bool(r.get("ambiguous")) for r in mine)
        if flagged:
            notes.append(f"{methods[m].label}: {flagged} of {len(mine)} poses flagged "
                         "ambiguous (drawn)")
        panel.setdefault("flagged", {})[m] = flagged
    if notes:        # room above the data and the budget line for the notes
        lo, hi = ax.get_ylim()
        ax.set_ylim(lo, hi + (hi - lo) * 0.12 * (len(notes) + 1))
        ax.text(0.01, 0.98, "\n".join(notes), transform=ax.transAxes, va="top",
                fontsize=9, color="#444")
    panel["not_applicable"] = sorted(na)
    panel["xlabel"], panel["ylabel"] = ax.get_xlabel(), ax.get_ylabel()
    # below the panel, not beside it: the figure stays one phone wide
    ax.legend(fontsize=9, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)
    return panel


def _method_boxes(ax: Any, recs: list[dict], values: list[float], m: str, err: str,
                  method: Any, offset: float, width: float) -> int:
    """One method's boxes, one per step with a found pose, ``offset`` beside the step's
    tick; returns how many were drawn."""
    data, pos = [], []
    for s, v in enumerate(values):
        vals = [r["errors"][err] for r in recs if r["value"] == v
                and r["method"] == m and r["found"]]
        if vals:
            data.append(vals)
            pos.append(s + offset)
    if data:
        bp = ax.boxplot(data, positions=pos, widths=width * 0.9, patch_artist=True,
                        showfliers=True, manage_ticks=False)
        for b in bp["boxes"]:
            b.set_facecolor(method.colour)
            b.set_alpha(0.75)
        ax.plot([], [], color=method.colour, lw=6, alpha=0.75, label=method.label)
    return len(data)


def _panel_axes(ax: Any, values: list[float], vary: str, label: str, budget: float | None,
                lay: str) -> None:
    """The budget line (for z in %, 5 cm at each distance), ticks, labels and title."""
    if budget is not None:
        ax.axhline(budget, color="k", ls="--", lw=1, label=f"budget {budget:g}")
    elif vary == "distance":    # 5 cm as a share of the distance
        ax.plot(range(len(values)), [5.0 / v for v in values], "k--", lw=1, label="5 cm")
    ax.set_xticks(range(len(values)))
    unit = "°" if vary.startswith("rot") else " m"
    ax.set_xticklabels([f"{v:g}{unit}" for v in values])
    ax.set_xlabel(vary.replace("_", " ") + (" (°)" if vary.startswith("rot") else " (m)"))
    ax.set_ylabel(label)
    ax.set_title(f"{lay} — {vary.replace('_', ' ')}", fontsize=11)
    ax.grid(axis="y", alpha=0.3)


def fps_figure(speed: list[dict], methods: dict, path: Path) -> dict:
    """Fig. 6.10: frames per second against the number of bricks in view."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.2, 4.6))
    lines = {}
    for key in sorted({(s["method"], s["layout"]) for s in speed}):
        pts = sorted((s["bricks"], s["fps"]) for s in speed if (s["method"], s["layout"]) == key)
        m, lay = key
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", color=methods[m].colour,
                alpha=0.9, ls="-" if "36h11" not in lay else ":",
                label=f"{methods[m].label} · {lay}")
        lines[f"{m} · {lay}"] = pts
    ax.set_xlabel("bricks in view")
    ax.set_ylabel("frames per second (one core)")
    ax.set_title("Fig. 6.10: frame rate against the number of bricks")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)
    return {"file": str(path), "lines": lines}


def memory_figure(memory: dict, methods: dict, path: Path) -> dict:
    """Fig. 6.11: resident memory over the run, per method."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.2, 4.6))
    for m, series in memory.items():
        t = np.array([p[0] for p in series])
        mb = np.array([p[1] for p in series])
        if len(t):
            ax.plot(t, mb - mb[0], color=methods[m].colour, label=methods[m].label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("resident memory − at start (MB)")
    ax.set_title("Fig. 6.11: memory over a long run")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)
    return {"file": str(path), "methods": sorted(memory)}
