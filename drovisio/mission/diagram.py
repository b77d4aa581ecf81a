"""The mission machine drawn from its transition table (:data:`~.machine.TRANSITIONS`).

``mermaid()`` gives a Mermaid ``stateDiagram-v2`` (renders on GitHub and in the web tool),
``dot()`` Graphviz DOT, ``svg()`` a self-contained SVG laid out here (no Graphviz needed).

Grouping keeps the drawing readable without hiding anything: the phases are composite states,
and an edge drawn from a composite state means "from every state inside it". An edge is drawn
from a group only when *every* member has that very (trigger, target) in the table; the rest
is drawn state by state. ``geofence`` leaves every flying state but the safe ones, drawn from
the pseudo-state "any flying state".
"""

from __future__ import annotations

import html
import math
from dataclasses import dataclass

from drovisio.mission.machine import (
    DROP_STATES,
    FLYING_STATES,
    PICK_STATES,
    TRANSITIONS,
    State,
    Transition,
)

__all__ = ["mermaid", "dot", "svg", "grouped_edges", "GROUPS"]


@dataclass(frozen=True)
class Group:
    key: str
    label: str
    members: tuple[State, ...]
    parent: str | None = None
    drawn: bool = True  # False: a pseudo-group shown as one node (ANY)


GROUPS: tuple[Group, ...] = (
    Group("PICK_PHASE", "pick phase", PICK_STATES),
    Group("PICK_VISION", "vision-guided",
          (State.ACQUIRE_BRICK, State.ALIGN_BRICK, State.DESCEND_BRICK), parent="PICK_PHASE"),
    Group("DROP_PHASE", "drop phase", DROP_STATES),
    Group("CARRYING", "carrying the brick", DROP_STATES[:-1], parent="DROP_PHASE"),
    Group("DROP_VISION", "vision-guided",
          (State.ACQUIRE_SLOT, State.ALIGN_SLOT, State.DESCEND_SLOT), parent="CARRYING"),
    Group("ANY_FLYING", "any flying state except the safe ones",
          tuple(s for s in FLYING_STATES if s not in (State.GO_SAFE, State.LAND_SAFE)),
          drawn=False),
)


def grouped_edges(transitions=TRANSITIONS) -> list[tuple[str, str, str, str]]:
    """(source node or group key, trigger, target, guard) covering every transition once."""
    by_key: dict[tuple[str, State], list[Transition]] = {}
    for t in transitions:
        by_key.setdefault((t.trigger, t.target), []).append(t)
    out = []
    for (trigger, target), ts in by_key.items():
        sources = {t.source for t in ts}
        guard = ts[0].guard
        for g in sorted(GROUPS, key=lambda g: -len(g.members)):
            if len(g.members) >= 2 and set(g.members) <= sources:
                out.append((g.key, trigger, target.value, guard))
                sources -= set(g.members)
        for t in ts:
            if t.source in sources:
                out.append((t.source.value, trigger, target.value, t.guard))
    return out


def _label(trigger: str, guard: str) -> str:
    if trigger in ("fail", "fail_final"):
        return f"{trigger} [{guard}]"
    return trigger


def mermaid() -> str:
    """Mermaid ``stateDiagram-v2`` text."""
    lines = ["stateDiagram-v2", "    direction TB"]
    in_group = {}
    for g in GROUPS:
        if g.drawn:
            for m in g.members:
                in_group[m] = g.key  # innermost wins (children come after parents)

    def emit(group_key: str | None, indent: str) -> None:
        for g in GROUPS:
            if g.drawn and g.parent == group_key:
                lines.append(f'{indent}state "{g.label}" as {g.key} {{')
                emit(g.key, indent + "    ")
                for m in g.members:
                    if in_group.get(m) == g.key:
                        lines.append(f"{indent}    {m.value}")
                lines.append(f"{indent}}}")

    emit(None, "    ")
    lines.append('    state "any flying state (but GO_SAFE, LAND_SAFE)" as ANY_FLYING')
    lines.append("    [*] --> IDLE")
    for src, trig, dst, guard in grouped_edges():
        lines.append(f"    {src} --> {dst} : {_label(trig, guard)}")
    lines.append("    DONE --> [*]")
    lines.append("    SHUTDOWN --> [*]")
    return "\n".join(lines) + "\n"


def dot() -> str:
    """Graphviz DOT text (clusters for the phases)."""
    out = ["digraph mission {", '  graph [rankdir=TB, compound=true, fontname="Helvetica"];',
           '  node [shape=box, style="rounded", fontname="Helvetica", fontsize=10];',
           '  edge [fontname="Helvetica", fontsize=9];']
    drawn_groups = [g for g in GROUPS if g.drawn]
    # each state goes in its innermost cluster
    order: list[Group] = []

    def depth(g: Group) -> int:
        d, p = 0, g.parent
        while p:
            d += 1
            p = next(x for x in GROUPS if x.key == p).parent
        return d

    for g in sorted(drawn_groups, key=depth, reverse=True):
        order.append(g)
    owner: dict[State, str] = {}
    for g in order:
        for m in g.members:
            owner.setdefault(m, g.key)

    def emit2(parent: str | None, indent: str) -> None:
        for g in drawn_groups:
            if g.parent == parent:
                out.append(f'{indent}subgraph cluster_{g.key} {{ label="{g.label}";')
                emit2(g.key, indent + "  ")
                for m in g.members:
                    if owner.get(m) == g.key:
                        out.append(f"{indent}  {m.value};")
                out.append(f"{indent}}}")

    emit2(None, "  ")
    for s in State:
        if s not in owner:
            out.append(f"  {s.value};")
    out.append('  ANY_FLYING [label="any flying state\\n(but GO_SAFE, LAND_SAFE)", '
               'shape=note];')
    out.append('  start [shape=point];')
    out.append("  start -> IDLE;")
    anchor = {g.key: g.members[0].value for g in GROUPS}
    for src, trig, dst, guard in grouped_edges():
        label = _label(trig, guard).replace('"', "'")
        if src in anchor and src != "ANY_FLYING":
            out.append(f'  {anchor[src]} -> {dst} [label="{label}", ltail=cluster_{src}];')
        else:
            out.append(f'  {src} -> {dst} [label="{label}"];')
    out.append("}")
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------- SVG
#: Where each state is drawn in the SVG (column, row); a state missing here goes to an extra
#: row at the bottom, so a new state is never silently left out.
GRID: dict[State, tuple[int, int]] = {
    State.IDLE: (0, 0), State.TAKE_OFF: (1, 0), State.GO_TO_BRICK: (2, 0),
    State.ACQUIRE_BRICK: (3, 0), State.ALIGN_BRICK: (4, 0), State.DESCEND_BRICK: (5, 0),
    State.BLIND_DESCENT_BRICK: (6, 0), State.GRAB: (7, 0), State.RETRY_PICK: (3, 1),
    State.CLIMB_WITH_BRICK: (7, 2), State.GO_TO_WALL: (6, 2), State.ACQUIRE_SLOT: (5, 2),
    State.ALIGN_SLOT: (4, 2), State.DESCEND_SLOT: (3, 2), State.BLIND_DESCENT_SLOT: (2, 2),
    State.RELEASE: (1, 2), State.CLIMB_AFTER_RELEASE: (0, 2), State.RETRY_DROP: (5, 3),
    State.VERIFY_PLACEMENT: (0, 3), State.RETURN_HOME: (0, 4), State.LAND: (1, 4),
    State.DONE: (2, 4), State.GO_SAFE: (5, 4), State.LAND_SAFE: (6, 4), State.SHUTDOWN: (7, 4),
}


_BW, _BH = 140, 28
"""A state's box, px."""
_CW, _RH = 205, 92
"""Column and row pitch, px."""
_MX, _MY = 20, 40
"""Margins, px."""
_SAFE = {State.GO_SAFE, State.LAND_SAFE, State.SHUTDOWN}

Point = tuple[float, float]
Frame = tuple[float, float, float, float]


def _svg_centres() -> tuple[dict[State, Point], int]:
    """Each state's box centre (px) and the number of rows."""
    grid = dict(GRID)
    extra = [s for s in State if s not in grid]
    for i, s in enumerate(extra):
        grid[s] = (i, 5)
    rows = max(r for _, r in grid.values()) + 1
    centre = {s: (_MX + c * _CW + _BW / 2, _MY + r * _RH + _BH / 2)
              for s, (c, r) in grid.items()}
    return centre, rows


def _svg_frames(centre: dict[State, Point]) -> dict[str, Frame]:
    """The frame (x0, y0, x1, y1) around each drawn top-level group's states."""
    frames = {}
    for g in GROUPS:
        if g.drawn and g.parent is None:
            xs = [centre[m][0] for m in g.members]
            ys = [centre[m][1] for m in g.members]
            frames[g.key] = (min(xs) - _BW / 2 - 8, min(ys) - _BH / 2 - 16,
                             max(xs) + _BW / 2 + 8, max(ys) + _BH / 2 + 8)
    return frames


def _svg_head(width: int, height: int) -> list[str]:
    return [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
            f'viewBox="0 0 {width} {height}" font-family="Helvetica,Arial,sans-serif" '
            'font-size="10">',
            '<defs>' + "".join(
                f'<marker id="{k}" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="7" '
                f'markerHeight="7" orient="auto-start-reverse"><path d="M0,0L10,5L0,10z" '
                f'fill="{c}"/></marker>' for k, c in (("a", "#555"), ("r", "#c33")))
            + '</defs>']


def _svg_group_frames(frames: dict[str, Frame]) -> list[str]:
    el = []
    for g in GROUPS:
        if g.key in frames:
            x0, y0, x1, y1 = frames[g.key]
            el.append(f'<rect x="{x0:.0f}" y="{y0:.0f}" width="{x1 - x0:.0f}" '
                      f'height="{y1 - y0:.0f}" rx="10" fill="none" stroke="#999" '
                      'stroke-dasharray="4 3"/>')
            el.append(f'<text x="{x0 + 6:.0f}" y="{y0 + 11:.0f}" fill="#777">{g.label}</text>')
    return el


def _svg_anchor(src: str, toward: Point, frames: dict[str, Frame],
                centre: dict[State, Point]) -> Point:
    """Where an edge leaves ``src`` (a group's frame or a state's box) toward a point."""
    if src in frames:
        x0, y0, x1, y1 = frames[src]
        return (min(max(toward[0], x0 + 20), x1 - 20), y1 if toward[1] > y1 else y0)
    x, y = centre[State(src)]
    dx, dy = toward[0] - x, toward[1] - y
    if abs(dy) * _BW > abs(dx) * _BH:
        return (x + dx * (_BH / 2) / abs(dy), y + math.copysign(_BH / 2, dy))
    return (x + math.copysign(_BW / 2, dx), y + dy * (_BW / 2) / max(abs(dx), 1e-9))


def _svg_bend(src: str, dst: str, start: Point, end: Point,
              pairs: set[tuple[str, str]]) -> float:
    """How far an edge bows out (px): apart from its reverse, around states in between."""
    (sx, sy), (ex, ey) = start, end
    if (dst, src) in pairs:
        return 14.0
    if abs(sx - ex) > 2.5 * _CW or (abs(sy - ey) > 1.5 * _RH and abs(sx - ex) < 1):
        return 40.0
    return 0.0


def _svg_edge(src: str, trig: str, d: State, guard: str, start: Point, end: Point,
              bend: float, labels_at: list[Point]) -> list[str]:
    """One edge: a quadratic curve and its label (moved down off the labels drawn)."""
    (sx, sy), (ex, ey) = start, end
    nxm, nym = (sx + ex) / 2, (sy + ey) / 2
    L = math.hypot(ex - sx, ey - sy) or 1.0
    cx, cy = nxm - (ey - sy) / L * bend, nym + (ex - sx) / L * bend
    col, mk = ("#c33", "r") if (d in _SAFE) else ("#555", "a")
    lx, ly = (sx + 2 * cx + ex) / 4, (sy + 2 * cy + ey) / 4
    while any(abs(lx - a) < 40 and abs(ly - b) < 9 for a, b in labels_at):
        ly += 10
    labels_at.append((lx, ly))
    horizontal = abs(ex - sx) > 3 * abs(ey - sy)
    anchor_txt = ' text-anchor="middle"' if horizontal else ""
    return [f'<path d="M{sx:.0f},{sy:.0f} Q{cx:.0f},{cy:.0f} {ex:.0f},{ey:.0f}" '
            f'fill="none" stroke="{col}" marker-end="url(#{mk})"/>',
            f'<text x="{lx + (0 if horizontal else 3):.0f}" y="{ly - 4:.0f}" '
            f'fill="{col}"{anchor_txt}>{html.escape(_label(trig, guard))}</text>']


def _svg_edges(frames: dict[str, Frame], centre: dict[State, Point]) -> list[str]:
    """The table's edges; the many edges to GO_SAFE from single states are left to the
    note."""
    el: list[str] = []
    edges = grouped_edges()
    pairs = {(a, b) for a, _, b, _ in edges}
    labels_at: list[Point] = []
    for src, trig, dst, guard in edges:
        if src == "ANY_FLYING":
            continue
        d = State(dst)
        if d is State.GO_SAFE and trig != "reached" and src not in frames:
            continue  # summarised by the note
        start = _svg_anchor(src, centre[d], frames, centre)
        end = _svg_anchor(d.value, start, frames, centre)
        el += _svg_edge(src, trig, d, guard, start, end,
                        _svg_bend(src, dst, start, end, pairs), labels_at)
    return el


def _svg_states(centre: dict[State, Point]) -> list[str]:
    el = []
    for s, (x, y) in centre.items():
        fill = "#fde2e2" if s in _SAFE else ("#e2f0fd" if s in PICK_STATES else
                                              "#e6f7e2" if s in DROP_STATES else "#f2f2f2")
        el.append(f'<rect x="{x - _BW / 2:.0f}" y="{y - _BH / 2:.0f}" width="{_BW}" '
                  f'height="{_BH}" rx="8" fill="{fill}" stroke="#333"/>')
        el.append(f'<text x="{x:.0f}" y="{y + 4:.0f}" text-anchor="middle">{s.value}</text>')
    return el


_SVG_NOTE = ("Also to GO_SAFE (red): total-station/vision disagreement (vision-guided states, "
             "verify), brick lost in flight, placement off its plan or unverified, no total "
             "station (take-off, retries, climb, return), and from any flying state the "
             "geofence guard.")


def svg() -> str:
    """A self-contained SVG of the machine: pick phase (blue) left to right, drop phase
    (green) right to left, the safe path in red. Edges come from the table; an edge from a
    phase leaves the phase's frame. The Mermaid/DOT texts are the exact drawings."""
    centre, rows = _svg_centres()
    width = _MX * 2 + _CW * 8
    height = _MY + rows * _RH + 40
    frames = _svg_frames(centre)
    el = (_svg_head(width, height) + _svg_group_frames(frames) + _svg_edges(frames, centre)
          + _svg_states(centre))
    el.append(f'<text x="{_MX}" y="{height - 14}" fill="#c33">{html.escape(_SVG_NOTE)}</text>')
    el.append("</svg>")
    return "\n".join(el) + "\n"
