"""The rules a valid scenario keeps beyond its schema: one small check per rule.

The rules run in stages (:data:`RULE_STAGES`): the inventory and the plan's entries, then what
each upper brick rests on, then the wall as a whole, then the geometry against the site and
the settings. A stage runs only when the ones before it found nothing, so a message never
rests on a broken premise. Each rule returns ``(field, message)`` pairs, the field as it is
written in the file (``wall.plan[6].rests_on``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from drovisio.mission.scenario_model import Brick, ScenarioModel

__all__ = ["Issue", "Rule", "RULE_STAGES", "semantic_issues"]

Issue = tuple[str, str]
"""(field, message)."""
Rule = Callable[[ScenarioModel], list[Issue]]


# ------------------------------------------------------------------------- the inventory
def _instance_issues(i: int, b: Brick, lay: Any) -> list[Issue]:
    if lay.has_codes:
        if b.instance is None:
            return [(f"bricks[{i}].instance", f"layout {b.layout!r} has codes: give the "
                                              "brick's instance number")]
        if lay.instances is not None and b.instance >= lay.instances:
            return [(f"bricks[{i}].instance", f"{b.instance} is out of range: layout "
                                              f"{b.layout!r} has instances "
                                              f"0..{lay.instances - 1}")]
    elif b.instance is not None:
        return [(f"bricks[{i}].instance", f"layout {b.layout!r} has no codes: instance "
                                          "must be null")]
    return []


def _pick_issues(scn: ScenarioModel, i: int, b: Brick) -> list[Issue]:
    out: list[Issue] = []
    p = b.pick.position
    a = scn.site.pick_area
    if not (abs(p[0] - a.center[0]) <= a.size[0] / 2 + 1e-9
            and abs(p[1] - a.center[1]) <= a.size[1] / 2 + 1e-9):
        out.append((f"bricks[{i}].pick.position", f"{p} is outside site.pick_area"))
    apart = scn.wall.brick_pitch_m * 1.5
    # the first brick listed before it that lies too near (one problem a brick, not a pair)
    near = next((q for q in scn.bricks[:i] if math.dist(p, q.pick.position) < apart), None)
    if near is not None:
        out.append((f"bricks[{i}].pick.position", f"{p} is within {apart:.2f} m of brick "
                                                  f"{near.id!r}: bricks to pick must lie apart"))
    return out


def _brick_issues(scn: ScenarioModel, i: int, b: Brick, first: dict[str, int]) -> list[Issue]:
    """One brick of the inventory: its id, its layout, its instance, where it lies."""
    out: list[Issue] = []
    if first[b.id] != i:
        out.append((f"bricks[{i}].id", f"duplicate brick id {b.id!r}"))
    if b.layout not in scn.layouts:
        out.append((f"bricks[{i}].layout", f"{b.layout!r} is not in 'layouts' "
                                           f"({', '.join(scn.layouts)})"))
        return out
    lay = scn._layouts.get(b.layout)
    if lay is None:
        return out
    return out + _instance_issues(i, b, lay) + _pick_issues(scn, i, b)


def bricks(scn: ScenarioModel) -> list[Issue]:
    """Each brick of the inventory (see :func:`_brick_issues`)."""
    first: dict[str, int] = {}
    for i, b in enumerate(scn.bricks):
        first.setdefault(b.id, i)
    return [x for i, b in enumerate(scn.bricks) for x in _brick_issues(scn, i, b, first)]


def codes_unique(scn: ScenarioModel) -> list[Issue]:
    """No two bricks carry the same codes."""
    out: list[Issue] = []
    seen_codes: dict[tuple[str, int], str] = {}
    for i, b in enumerate(scn.bricks):
        if b.instance is not None:
            key = (b.layout, b.instance)
            if key in seen_codes:
                out.append((f"bricks[{i}].instance", f"brick {b.id!r} has the same codes as "
                                                     f"{seen_codes[key]!r} "
                                                     f"({b.layout} #{b.instance})"))
            seen_codes[key] = b.id
    return out


def plan_entries(scn: ScenarioModel) -> list[Issue]:
    """Each planned brick exists, is planned once, and course 1's slots are distinct."""
    out: list[Issue] = []
    planned: set[str] = set()
    slots: dict[int, str] = {}
    for i, e in enumerate(scn.wall.plan):
        where = f"wall.plan[{i}]"
        if e.brick not in scn.brick_by_id:
            out.append((f"{where}.brick", f"{e.brick!r} is not in 'bricks'"))
        if e.brick in planned:
            out.append((f"{where}.brick", f"brick {e.brick!r} is planned twice"))
        if e.course == 1 and e.slot is not None:
            if e.slot in slots:
                out.append((f"{where}.slot", f"slot {e.slot} already holds {slots[e.slot]!r}"))
            slots[e.slot] = e.brick
        planned.add(e.brick)
    return out


# ------------------------------------------------------------------------- the courses
def rests_on(scn: ScenarioModel) -> list[Issue]:
    """An upper brick rests on two different bricks of the course below, and no pair carries
    two bricks (checked only while nothing else is wrong)."""
    out: list[Issue] = []
    pairs: dict[frozenset[str], str] = {}
    for i, e in enumerate(scn.wall.plan):
        if e.course == 1 or e.rests_on is None:
            continue
        where = f"wall.plan[{i}].rests_on"
        if e.rests_on[0] == e.rests_on[1]:   # said once, not once for each of the two
            out.append((where, f"names {e.rests_on[0]!r} twice: the two bricks below must "
                               "differ"))
            continue
        for o in e.rests_on:
            oe = scn.plan_by_id.get(o)
            if oe is None:
                out.append((where, f"{o!r} is not planned in the wall"))
            elif oe.course != e.course - 1:
                out.append((where, f"{o!r} is in course {oe.course}; a course-{e.course} "
                                   f"brick rests on course {e.course - 1}"))
        if out:
            continue
        key = frozenset(e.rests_on)
        if key in pairs:
            out.append((where, f"the pair {e.rests_on} already carries {pairs[key]!r}"))
        pairs[key] = e.brick
    return out


# ------------------------------------------------------------------------- the wall
def neighbours(scn: ScenarioModel) -> list[Issue]:
    """The two bricks below an upper brick are neighbours of one course."""
    out: list[Issue] = []
    pitch = scn.wall.brick_pitch_m
    for i, e in enumerate(scn.wall.plan):
        if e.course > 1 and e.rests_on is not None:
            a, b = (scn.slot_pose(o) for o in e.rests_on)
            gap = math.dist((a.x, a.y), (b.x, b.y))
            if abs(gap - pitch) > 1e-6 or abs(a.z - b.z) > 1e-9:
                out.append((f"wall.plan[{i}].rests_on", f"{e.rests_on} are not neighbours "
                                                        f"(centres {gap:.3f} m apart, pitch "
                                                        f"{pitch} m)"))
    return out


def build_order(scn: ScenarioModel) -> list[Issue]:
    """The order lists every planned brick once, each after the bricks it rests on."""
    order = scn.order
    if sorted(order) != sorted(e.brick for e in scn.wall.plan):
        return [("wall.order", "must list every planned brick exactly once")]
    return [("wall.order", f"{bid!r} is built before {o!r}, which it rests on")
            for k, bid in enumerate(order) for o in scn.supports(bid) if o not in order[:k]]


def all_planned(scn: ScenarioModel) -> list[Issue]:
    """Every brick of the inventory is in the wall."""
    plan_ids = {e.brick for e in scn.wall.plan}
    unplanned = [b.id for b in scn.bricks if b.id not in plan_ids]
    if unplanned:
        more = f" and {len(unplanned) - 10} more" if len(unplanned) > 10 else ""
        return [("bricks", f"bricks not in the wall plan: {', '.join(unplanned[:10])}{more}")]
    return []


# ------------------------------------------------------------------------- the site
def site_points(scn: ScenarioModel) -> list[Issue]:
    """Home, the safe zone's and the pick area's centres lie inside the geofence."""
    site = scn.site
    return [(name, f"{xy} is not inside site.bounds with a 0.3 m margin")
            for name, xy in [("site.home", site.home),
                             ("site.safe_zone.center", site.safe_zone.center),
                             ("site.pick_area.center", site.pick_area.center)]
            if not site.bounds.contains(xy, margin=0.3)]


def safe_zone_inside(scn: ScenarioModel) -> list[Issue]:
    b, sz = scn.site.bounds, scn.site.safe_zone
    if not (b.contains(np.asarray(sz.center) - sz.radius) and
            b.contains(np.asarray(sz.center) + sz.radius)):
        return [("site.safe_zone", "the safe zone must lie inside site.bounds")]
    return []


def slots_on_site(scn: ScenarioModel) -> list[Issue]:
    """Each slot lies inside the geofence, and 0.5 m or more from the safe zone."""
    out: list[Issue] = []
    b, sz = scn.site.bounds, scn.site.safe_zone
    for bid in scn.order:
        s = scn.slot_pose(bid)
        if not b.contains((s.x, s.y), margin=0.3):
            out.append(("wall", f"{bid!r}'s slot ({s.x:.2f}, {s.y:.2f}) is not inside "
                                "site.bounds with a 0.3 m margin"))
        if math.dist((s.x, s.y), sz.center) < sz.radius + 0.5:
            out.append(("site.safe_zone", f"the safe zone is within 0.5 m of the wall "
                                          f"(brick {bid!r})"))
    return out


# ------------------------------------------------------------------------- the flight
def cruise_altitude(scn: ScenarioModel) -> list[Issue]:
    """Above 1 m, over the wall with a held brick, under the ceiling."""
    out: list[Issue] = []
    alt = scn.altitudes
    hang = scn.drone.picker_depth_m + max(
        float(scn._layouts[n].dimensions_m[2]) for n in scn.layouts if n in scn._layouts)
    if alt.cruise_m < 1.0:
        out.append(("altitudes.cruise_m", "the thesis climbs above 1 m between phases"))
    if alt.cruise_m < scn.wall_top_m() + hang + 0.3:
        out.append(("altitudes.cruise_m", f"{alt.cruise_m} m does not clear the wall "
                                          f"({scn.wall_top_m():.2f} m) with a held brick "
                                          f"({hang:.2f} m below the body) and 0.3 m to spare"))
    if alt.cruise_m > scn.site.bounds.max[2] - 0.2:
        out.append(("altitudes.cruise_m", f"{alt.cruise_m} m is above the geofence ceiling "
                                          "minus 0.2 m"))
    return out


def approach_and_blind(scn: ScenarioModel) -> list[Issue]:
    out: list[Issue] = []
    alt = scn.altitudes
    if scn.wall_top_m() + alt.approach_m > alt.cruise_m + 1e-9:
        out.append(("altitudes.approach_m", "approach height above the wall top must not "
                                            "exceed the cruise altitude"))
    if alt.blind_below_m >= alt.approach_m - scn.drone.camera.mount.offset_m[2]:
        out.append(("altitudes.blind_below_m", "must be below the camera's approach height"))
    return out


def tolerances(scn: ScenarioModel) -> list[Issue]:
    out: list[Issue] = []
    th = scn.thresholds
    if th.align_yaw_tolerance_deg > scn.placement_tolerance.yaw_deg:
        out.append(("thresholds.align_yaw_tolerance_deg", "must not exceed "
                                                          "placement_tolerance.yaw_deg"))
    if th.align_position_tolerance_m > th.descent_position_tolerance_m:
        out.append(("thresholds.align_position_tolerance_m", "must not exceed "
                                                             "descent_position_tolerance_m"))
    if th.disagreement_m <= th.match_radius_m * 0.2:
        out.append(("thresholds.disagreement_m", "too small to tolerate a brick's pick error"))
    return out


def sensors(scn: ScenarioModel) -> list[Issue]:
    out: list[Issue] = []
    if not scn.sensors.total_station:
        out.append(("sensors.total_station", "this strategy needs the total station (the site "
                                             "frame); a mission without it is not supported"))
    if not scn.sensors.vision:
        out.append(("sensors.vision", "the alignment phases need vision"))
    return out


RULE_STAGES: tuple[tuple[Rule, ...], ...] = (
    (bricks, codes_unique, plan_entries),
    (rests_on,),
    (neighbours, build_order, all_planned),
    (site_points, safe_zone_inside, slots_on_site, cruise_altitude, approach_and_blind,
     tolerances, sensors),
)
"""The rules, stage by stage, in the order their messages are listed."""


def semantic_issues(scn: ScenarioModel) -> list[Issue]:
    """Every broken rule of the first stage that has one (empty: the scenario is valid)."""
    for stage in RULE_STAGES:
        issues = [x for rule in stage for x in rule(scn)]
        if issues:
            return issues
    return []
