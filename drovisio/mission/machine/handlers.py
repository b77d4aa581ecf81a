"""One handler per state: what the machine does in that state on one tick.

A handler returns the setpoint, or None when it took a transition (the caller then runs the
new state's handler on the same tick). :func:`handle` looks the handler up in
:data:`HANDLERS`, after the bound every attempt of a phase shares (``attempt_timeout_s``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import cast

import numpy as np

from drovisio.mission.frames import nearest_mod_pi, wrap_half
from drovisio.mission.machine.context import (
    StepContext,
    camera_height,
    contact_z,
    enter,
    fail,
    go_to,
    hold,
    reset_failures,
    settled,
)
from drovisio.mission.machine.signals import Setpoint
from drovisio.mission.machine.states import ATTEMPT_STATES, TERMINAL_STATES, State
from drovisio.mission.machine.targets import (
    body_goal,
    body_xy_from_site_xy,
    errors,
    mean_pose,
    monitor_disagreement,
    target_sightings,
    update_target,
)
from drovisio.mission.scenario import Pose4

__all__ = ["HANDLERS", "handle"]

Handler = Callable[[StepContext], "Setpoint | None"]


def _in_flight_lost(c: StepContext, drop: bool) -> bool:
    """The checks of every phase in flight: the held brick is gone (drop phase), or the total
    station is. True when they took a transition."""
    if drop and not c.readings.holding:
        enter(c, "brick_lost", reason="picker sensor says the brick is gone")
        return True
    if c.ts_age > c.th.ts_grace_s:
        c.event("ts_lost", age_s=round(c.ts_age, 2))
        fail(c, "total station lost")
        return True
    return False


def _top(c: StepContext, brick: str, drop: bool) -> float:
    """Height of the target's top face: the slot's (drop) or the brick's on the ground."""
    return c.scn.slot_pose(brick).z if drop else c.scn.pick_pose(brick).z


# ------------------------------------------------------------------------- take-off, transit
def _idle(c: StepContext) -> Setpoint | None:
    enter(c, "start")
    return None


def _take_off(c: StepContext) -> Setpoint | None:
    th, alt = c.th, c.alt
    if c.ts_age > th.ts_grace_s and c.now - c.mem.entered_t > th.ts_wait_s:
        enter(c, "ts_lost", reason="no total station at take-off")
        return None
    home = c.scn.site.home
    sp = Setpoint((home[0], home[1], alt.cruise_m), c.yaw if c.mem.setpoint is None
                  else c.mem.setpoint.yaw)
    if settled(c, c.ts_age <= th.ts_grace_s and abs(c.position[2] - alt.cruise_m) < 0.08):
        enter(c, "reached")
        return None
    return sp


def _go_to_target(c: StepContext, drop: bool) -> Setpoint | None:
    """GO_TO_BRICK / GO_TO_WALL: above the pick pose or the slot, at the approach height."""
    if _in_flight_lost(c, drop):
        return None
    brick = c.active_brick
    target = c.scn.slot_pose(brick) if drop else c.scn.pick_pose(brick)
    goal_xy = target.xy
    if drop and c.mem.held is not None:
        goal_xy, _ = body_goal(c, target, True)
    sp, reached = go_to(c, goal_xy, target.z + c.alt.approach_m)
    if reached:
        enter(c, "reached")
        return None
    return sp


def _climb_with_brick(c: StepContext) -> Setpoint | None:
    if _in_flight_lost(c, drop=True):
        return None
    cruise = c.alt.cruise_m
    sp = hold(c, z=cruise)
    if settled(c, abs(c.position[2] - cruise) < 0.08):
        enter(c, "reached")
        return None
    return sp


# ------------------------------------------------------------------------- vision phases
@dataclass(frozen=True)
class _Approach:
    """What ACQUIRE / ALIGN / DESCEND share on one tick."""

    brick: str
    drop: bool
    top: float
    """Height of the target's top face, site frame, m."""
    vision_needed: bool


def _approach(c: StepContext, drop: bool) -> _Approach | None:
    """The checks and the target update of ACQUIRE / ALIGN / DESCEND (pick or drop); None
    when they took a transition."""
    th, scn = c.th, c.scn
    brick = c.active_brick
    if _in_flight_lost(c, drop):
        return None
    if monitor_disagreement(c):
        return None
    update_target(c, brick, drop)
    acquire = c.mem.state in (State.ACQUIRE_BRICK, State.ACQUIRE_SLOT)
    vision_needed = not (drop and (not scn.references(brick) or
                                   (scn.plan_by_id[brick].course == 1 and not acquire)))
    if vision_needed and c.now - c.mem.last_seen_t > th.vision_timeout_s and not acquire:
        fail(c, "vision lost")
        return None
    return _Approach(brick, drop, _top(c, brick, drop), vision_needed)


def _acquire(c: StepContext, drop: bool) -> Setpoint | None:
    """ACQUIRE_BRICK / ACQUIRE_SLOT: hover at the approach height until the target is seen."""
    a = _approach(c, drop)
    if a is None:
        return None
    th, scn = c.th, c.scn
    if c.mem.seen_frames >= (th.settle_frames if scn.references(a.brick) or not drop else 1):
        c.event("acquired", brick=a.brick, frames=c.mem.seen_frames)
        enter(c, "acquired")
        return None
    if c.now - c.mem.entered_t > th.acquire_timeout_s:
        fail(c, "target not found")
        return None
    return hold(c, z=a.top + c.alt.approach_m)


@dataclass(frozen=True)
class _Aim:
    """Where the body must go to meet the target, and how far it is from there."""

    goal_xy: np.ndarray
    """(2,) site frame, m."""
    body_yaw: float
    xy_err: float
    yaw_err: float
    cur_z: float
    """The height the last setpoint held (or the body's), m."""

    def detail(self) -> dict[str, float]:
        return {"yaw_error_deg": round(math.degrees(self.yaw_err), 2),
                "xy_error_m": round(self.xy_err, 3)}


def _aim(c: StepContext, a: _Approach) -> _Aim | None:
    """The goal from the target's estimate and the errors to it (recorded in the memory);
    None when there is no estimate (a failure)."""
    if not c.mem.samples:
        fail(c, "no target estimate")
        return None
    target = mean_pose(c.mem.samples)
    goal_xy, body_yaw = body_goal(c, target, a.drop)
    xy_err, yaw_err = errors(c, goal_xy, body_yaw)
    c.update(yaw_error=yaw_err, xy_error=xy_err)
    sp = c.mem.setpoint
    cur_z = sp.position[2] if sp is not None else float(c.position[2])
    return _Aim(goal_xy, body_yaw, xy_err, yaw_err, cur_z)


def _align(c: StepContext, drop: bool) -> Setpoint | None:
    """ALIGN_BRICK / ALIGN_SLOT: move over the target and turn to it, at the same height."""
    a = _approach(c, drop)
    aim = _aim(c, a) if a is not None else None
    if a is None or aim is None:
        return None
    th = c.th
    if c.now - (c.mem.align_t or c.mem.entered_t) > th.align_timeout_s:
        fail(c, "alignment timeout")
        return None
    fresh = (c.now - c.mem.last_seen_t) <= th.vision_timeout_s or not a.vision_needed
    tol_yaw = math.radians(th.align_yaw_tolerance_deg)
    ok = (fresh and aim.xy_err < th.align_position_tolerance_m
          and abs(aim.yaw_err) < 0.5 * tol_yaw)
    if settled(c, ok):
        c.event("aligned", brick=a.brick, yaw_error_deg=round(math.degrees(aim.yaw_err), 2),
                xy_error_m=round(aim.xy_err, 3))
        enter(c, "aligned")
        return None
    return Setpoint((float(aim.goal_xy[0]), float(aim.goal_xy[1]), aim.cur_z), aim.body_yaw)


def _descend(c: StepContext, drop: bool) -> Setpoint | None:
    """DESCEND_BRICK / DESCEND_SLOT: down while vision keeps the alignment, then blind."""
    a = _approach(c, drop)
    aim = _aim(c, a) if a is not None else None
    if a is None or aim is None:
        return None
    th, alt = c.th, c.alt
    if (abs(aim.yaw_err) > math.radians(th.align_yaw_tolerance_deg)
            or aim.xy_err > th.descent_position_tolerance_m):
        c.event("misaligned", brick=a.brick, **aim.detail())
        enter(c, "misaligned")
        return None
    if camera_height(c, a.top) <= alt.blind_below_m:
        c.event("blind", brick=a.brick, **aim.detail())
        enter(c, "blind")
        return None
    z = max(aim.cur_z - alt.descent_speed_mps * c.dt, contact_z(c.scn, a.top))
    return Setpoint((float(aim.goal_xy[0]), float(aim.goal_xy[1]), z), aim.body_yaw)


def _on_target(c: StepContext, sp: Setpoint, drop: bool) -> tuple[bool, float, float]:
    """Whether the total station puts the body on the target and the heading on its setpoint
    (a gust may have pushed the drone off): (on target, xy error m, yaw error rad)."""
    th = c.th
    xy_err = float(np.hypot(sp.position[0] - c.position[0], sp.position[1] - c.position[1]))
    yaw_err = wrap_half(sp.yaw - c.yaw)
    # with the autopilot's precision landing the pick's horizontal is the autopilot's: it
    # touches down where its estimate says, and the picker sensor tells whether that was right
    xy_ok = xy_err < th.contact_position_tolerance_m or (
        not drop and c.scn.autopilot.precision_landing)
    on_target = (c.ts_age <= th.ts_grace_s and xy_ok
                 and abs(yaw_err) < math.radians(th.contact_yaw_tolerance_deg))
    return on_target, xy_err, yaw_err


def _blind(c: StepContext, drop: bool) -> Setpoint | None:
    """BLIND_DESCENT_BRICK / BLIND_DESCENT_SLOT: straight down on the total station to the
    contact."""
    th = c.th
    brick = c.active_brick
    if _in_flight_lost(c, drop):
        return None
    zc = contact_z(c.scn, _top(c, brick, drop))
    sp = c.mem.setpoint
    assert sp is not None  # the descent before set one
    z = max(sp.position[2] - c.alt.blind_speed_mps * c.dt, zc)
    if c.now - c.mem.entered_t > th.contact_timeout_s:
        fail(c, "no steady contact on target")
        return None
    # at contact, grab or release only when on the target
    on_target, xy_err, yaw_err = _on_target(c, sp, drop)
    if settled(c, z <= zc + 1e-9 and abs(c.position[2] - zc) < 0.02 and on_target, 0.2):
        c.event("contact", brick=brick, xy_error_m=round(xy_err, 4),
                yaw_error_deg=round(math.degrees(yaw_err), 2))
        enter(c, "contact")
        return None
    return Setpoint((sp.position[0], sp.position[1], z), sp.yaw)


# ------------------------------------------------------------------------- picker
def _grab(c: StepContext) -> Setpoint | None:
    sp = hold(c)
    if c.now - c.mem.picker_t < c.th.grab_time_s:
        return sp
    if not c.readings.holding:
        fail(c, "grab not confirmed by the picker sensor")
        return None
    brick = c.active_brick
    target = mean_pose(c.mem.samples) if c.mem.samples else c.scn.pick_pose(brick)
    d = body_xy_from_site_xy(target.xy - c.position[:2], c.yaw)
    c.update(held=(float(d[0]), float(d[1]), wrap_half(target.yaw - c.yaw)))
    reset_failures(c, "pick")
    c.event("grabbed", brick=brick, offset_m=[round(float(d[0]), 3), round(float(d[1]), 3)])
    enter(c, "grabbed")
    return None


def _release(c: StepContext) -> Setpoint | None:
    sp = hold(c)
    if c.now - c.mem.picker_t < c.th.grab_time_s:
        return sp
    if c.readings.holding:
        fail(c, "release not confirmed by the picker sensor")
        return None
    c.event("released", brick=c.brick)
    c.update(held=None)
    enter(c, "released")
    return None


# ------------------------------------------------------------------------- retries, verify
def _retry(c: StepContext, drop: bool) -> Setpoint | None:
    """RETRY_PICK / RETRY_DROP: climb straight up (to the approach height at least) and
    wait for the total station; a brick come loose meanwhile changes nothing here."""
    th = c.th
    if c.ts_age > th.ts_wait_s:
        enter(c, "ts_lost", reason=f"no total station for {th.ts_wait_s:.0f} s")
        return None
    top = _top(c, c.active_brick, drop)
    z = max(top + c.alt.approach_m, min(float(c.position[2]), c.alt.cruise_m))
    sp = hold(c, z=z)
    if settled(c, c.ts_age <= th.ts_grace_s and abs(c.position[2] - z) < 0.08
               and c.now - c.mem.entered_t >= th.grab_time_s):
        enter(c, "reached")
        return None
    return sp


def _climb_after_release(c: StepContext) -> Setpoint | None:
    th = c.th
    if c.ts_age > th.ts_wait_s:
        enter(c, "ts_lost", reason="no total station after the release")
        return None
    z = c.scn.slot_pose(c.active_brick).z + c.alt.approach_m
    sp = hold(c, z=z)
    if settled(c, c.ts_age <= th.ts_grace_s and abs(c.position[2] - z) < 0.08):
        enter(c, "reached")
        return None
    return sp


def _judge_placement(c: StepContext, brick: str, slot: Pose4) -> None:
    """The placed brick against its plan: next brick, home, or the safe zone."""
    est = mean_pose(c.mem.samples)
    err = math.dist((est.x, est.y), (slot.x, slot.y))
    yerr = math.degrees(abs(wrap_half(est.yaw - slot.yaw)))
    tol = c.scn.placement_tolerance
    if err <= tol.position_m and yerr <= tol.yaw_deg:
        built = dict(c.mem.as_built)
        built[brick] = Pose4(est.x, est.y, slot.z, nearest_mod_pi(est.yaw, slot.yaw))
        reset_failures(c, "drop")
        c.update(as_built=tuple(built.items()), placed=c.mem.placed + (brick,))
        c.event("placed", brick=brick, error_m=round(err, 4), yaw_error_deg=round(yerr, 2))
        c.update(brick_index=c.mem.brick_index + 1)
        last = c.mem.brick_index >= len(c.plan.order)
        enter(c, "placed_last" if last else "placed_next")
        return
    c.event("placement_out_of_tolerance", brick=brick, error_m=round(err, 4),
            yaw_error_deg=round(yerr, 2))
    enter(c, "out_of_tolerance", reason=f"{brick} placed {err * 100:.1f} cm / "
                                        f"{yerr:.1f}° off its plan")


def _verify_placement(c: StepContext) -> Setpoint | None:
    """VERIFY_PLACEMENT: hover above the placed brick and measure it against its plan."""
    th = c.th
    sp = hold(c)
    brick = c.active_brick
    slot = c.scn.slot_pose(brick)
    if monitor_disagreement(c):
        return None
    if c.ts_age <= th.ts_grace_s and c.readings.vision is not None:
        expected = mean_pose(c.mem.samples).xy if c.mem.samples else slot.xy
        poses = target_sightings(c, brick, expected)
        if poses:
            q = poses[0]
            c.update(samples=(c.mem.samples + ((q.x, q.y, slot.z, q.yaw),))[-th.filter_frames:],
                     seen_frames=c.mem.seen_frames + 1, last_seen_t=c.now)
    if c.mem.seen_frames >= th.settle_frames:
        _judge_placement(c, brick, slot)
        return None
    if c.now - c.mem.entered_t > th.verify_timeout_s:
        enter(c, "unverified", reason=f"could not verify {brick}")
        return None
    return sp


# ------------------------------------------------------------------------- home, safe zone
def _return_home(c: StepContext) -> Setpoint | None:
    if c.ts_age > c.th.ts_wait_s:
        enter(c, "ts_lost", reason="no total station on the way home")
        return None
    sp, reached = go_to(c, c.scn.site.home, c.alt.cruise_m)
    if reached:
        enter(c, "reached")
        return None
    return sp


def _land(c: StepContext) -> Setpoint | None:
    """LAND / LAND_SAFE: straight down at 0.4 m/s onto home or the safe zone."""
    scn = c.scn
    xy = scn.site.home if c.mem.state is State.LAND else scn.site.safe_zone.center
    sp0 = c.mem.setpoint
    z0 = sp0.position[2] if sp0 is not None else float(c.position[2])
    touchdown = scn.drone.gear_height_m
    if c.readings.holding:
        # only a brick being built can be held (a lookup of None fails, as it always did)
        held_height = scn.brick_height_m(cast(str, c.brick))
        touchdown = max(touchdown, scn.drone.picker_depth_m + held_height)
    z = max(z0 - 0.4 * c.dt, touchdown - 0.05)
    if settled(c, c.position[2] <= touchdown + 0.03, 0.5):
        enter(c, "landed")
        return None
    return Setpoint((float(xy[0]), float(xy[1]), z), sp0.yaw if sp0 else c.yaw)


def _go_safe(c: StepContext) -> Setpoint | None:
    """GO_SAFE: climb where it is (inside the site), then over the safe zone at cruise."""
    sz = c.scn.site.safe_zone.center
    cruise = c.alt.cruise_m
    sp0 = c.mem.setpoint
    yaw = sp0.yaw if sp0 is not None else c.yaw
    far = math.dist(c.position[:2], sz) > 0.25
    if far and c.position[2] < cruise - 0.15:
        xy = c.plan.clamp_xy(c.position[:2])
        return Setpoint((xy[0], xy[1], cruise), yaw)
    if far:
        return Setpoint((sz[0], sz[1], cruise), yaw)
    if settled(c, True, 0.5):
        enter(c, "reached")
        return None
    return Setpoint((sz[0], sz[1], cruise), yaw)


def _stopped(c: StepContext) -> Setpoint | None:
    return None


HANDLERS: dict[State, Handler] = {
    State.IDLE: _idle,
    State.TAKE_OFF: _take_off,
    State.GO_TO_BRICK: partial(_go_to_target, drop=False),
    State.ACQUIRE_BRICK: partial(_acquire, drop=False),
    State.ALIGN_BRICK: partial(_align, drop=False),
    State.DESCEND_BRICK: partial(_descend, drop=False),
    State.BLIND_DESCENT_BRICK: partial(_blind, drop=False),
    State.GRAB: _grab,
    State.RETRY_PICK: partial(_retry, drop=False),
    State.CLIMB_WITH_BRICK: _climb_with_brick,
    State.GO_TO_WALL: partial(_go_to_target, drop=True),
    State.ACQUIRE_SLOT: partial(_acquire, drop=True),
    State.ALIGN_SLOT: partial(_align, drop=True),
    State.DESCEND_SLOT: partial(_descend, drop=True),
    State.BLIND_DESCENT_SLOT: partial(_blind, drop=True),
    State.RELEASE: _release,
    State.RETRY_DROP: partial(_retry, drop=True),
    State.CLIMB_AFTER_RELEASE: _climb_after_release,
    State.VERIFY_PLACEMENT: _verify_placement,
    State.RETURN_HOME: _return_home,
    State.LAND: _land,
    State.LAND_SAFE: _land,
    State.GO_SAFE: _go_safe,
    **{s: _stopped for s in TERMINAL_STATES},
}
assert set(HANDLERS) == set(State), "a state without a handler"


def handle(c: StepContext) -> Setpoint | None:
    """Run the current state's handler once; None means 'state changed, run again'."""
    if c.mem.state in ATTEMPT_STATES and c.now - c.mem.attempt_t > c.th.attempt_timeout_s:
        fail(c, "attempt timeout")
        return None
    return HANDLERS[c.mem.state](c)
