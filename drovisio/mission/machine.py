"""The thesis's pick-and-place strategy (ch. 8.3–8.4) as a finite-state machine.

States and transitions are **data** (:data:`TRANSITIONS`): each state's handler only says
*what happened* (a trigger such as ``aligned``, ``fail``, ``disagreement``), and the table
says *where that leads*. A (state, trigger) pair that is not in the table is a bug and raises,
so the diagram drawn from the table (:mod:`drovisio.mission.diagram`) is the machine.

:func:`step` is a pure function on a given clock: ``step(plan, memory, readings) ->
(memory, output)``; it never reads a clock, a random generator or a global. Inputs
(:class:`Readings`): the time, the total station's position (or None), the autopilot's own
position/heading estimate, the vision frame (bricks in the drone's body frame, or None when no
frame arrived this tick), the picker sensor. Outputs (:class:`Output`): a setpoint (position
and heading in the site frame, see :mod:`.frames`), the picker command, the motors, events and
telemetry.

The strategy, as the thesis states it, with the choices made where it is silent:

* take off to the cruise altitude (above 1 m); **pick phase**: go above the brick's pick
  position at the approach height (1–2 m above it); acquire it by vision (by code id, or by
  position for bricks without ids); align position and yaw; descend while vision keeps the
  alignment; below ``blind_below_m`` (camera to target) descend blind, straight, on the total
  station; grab; the picker sensor must confirm. With the scenario's
  ``autopilot.precision_landing`` the autopilot steers the pick descent on its own target
  estimate: the contact is taken where it touches down (height and heading), not only within
  ``contact_position_tolerance_m`` of the machine's setpoint.
* climb to the cruise altitude; **drop phase**: go above the slot; find it from the bricks
  below it (course ≥ 2: the two it straddles, recognised by id or position; course 1: the
  plan through the total station and the heading, the placed neighbour must be seen);
  align, descend, blind
  descent, release; the picker sensor must confirm; climb and **verify** the placement by
  vision against the plan.
* each phase has ``retries`` attempts: a failure (vision lost above the blind height, target
  not found, alignment timeout, total station lost, grab or release not confirmed) climbs
  straight up and starts the phase again; the ``retries``-th failure sends the drone to the
  safe zone, where it lands and shuts down.
* if the total-station position and the vision position (from a brick whose site position
  is known: the pick pose, the as-built wall) disagree by more than ``disagreement_m`` for
  ``disagreement_frames`` frames, the drone goes to the safe zone at once; so it does after a
  placement found out of tolerance, a brick lost in flight, or a setpoint that would leave
  the site (geofence guard).
* the machine never commands a descent onto a target while its yaw error exceeds
  ``align_yaw_tolerance_deg`` (it stops and realigns), and never outputs a setpoint outside
  ``site.bounds``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any

import numpy as np

from drovisio.mission.frames import nearest_mod_pi, site_from_body, wrap_half, yaw_of
from drovisio.mission.scenario import Pose4, Scenario

__all__ = ["State", "Transition", "TRANSITIONS", "PICK_STATES", "DROP_STATES", "FLYING_STATES",
           "TERMINAL_STATES", "SAFE_STATES", "DESCENT_STATES", "Sighting", "Readings",
           "Setpoint", "Event", "Output", "Memory", "MissionPlan", "step", "Machine",
           "next_state"]


class State(str, Enum):
    IDLE = "IDLE"
    TAKE_OFF = "TAKE_OFF"
    GO_TO_BRICK = "GO_TO_BRICK"
    ACQUIRE_BRICK = "ACQUIRE_BRICK"
    ALIGN_BRICK = "ALIGN_BRICK"
    DESCEND_BRICK = "DESCEND_BRICK"
    BLIND_DESCENT_BRICK = "BLIND_DESCENT_BRICK"
    GRAB = "GRAB"
    RETRY_PICK = "RETRY_PICK"
    CLIMB_WITH_BRICK = "CLIMB_WITH_BRICK"
    GO_TO_WALL = "GO_TO_WALL"
    ACQUIRE_SLOT = "ACQUIRE_SLOT"
    ALIGN_SLOT = "ALIGN_SLOT"
    DESCEND_SLOT = "DESCEND_SLOT"
    BLIND_DESCENT_SLOT = "BLIND_DESCENT_SLOT"
    RELEASE = "RELEASE"
    RETRY_DROP = "RETRY_DROP"
    CLIMB_AFTER_RELEASE = "CLIMB_AFTER_RELEASE"
    VERIFY_PLACEMENT = "VERIFY_PLACEMENT"
    RETURN_HOME = "RETURN_HOME"
    LAND = "LAND"
    DONE = "DONE"
    GO_SAFE = "GO_SAFE"
    LAND_SAFE = "LAND_SAFE"
    SHUTDOWN = "SHUTDOWN"

    def __str__(self) -> str:  # pragma: no cover - cosmetic
        return self.value


S = State
PICK_STATES = (S.GO_TO_BRICK, S.ACQUIRE_BRICK, S.ALIGN_BRICK, S.DESCEND_BRICK,
               S.BLIND_DESCENT_BRICK, S.GRAB)
DROP_STATES = (S.CLIMB_WITH_BRICK, S.GO_TO_WALL, S.ACQUIRE_SLOT, S.ALIGN_SLOT, S.DESCEND_SLOT,
               S.BLIND_DESCENT_SLOT, S.RELEASE)
SAFE_STATES = (S.GO_SAFE, S.LAND_SAFE, S.SHUTDOWN)
TERMINAL_STATES = (S.DONE, S.SHUTDOWN)
DESCENT_STATES = (S.DESCEND_BRICK, S.BLIND_DESCENT_BRICK, S.DESCEND_SLOT, S.BLIND_DESCENT_SLOT)
FLYING_STATES = tuple(s for s in S if s not in (S.IDLE, S.DONE, S.SHUTDOWN))
VISION_STATES = (S.ACQUIRE_BRICK, S.ALIGN_BRICK, S.DESCEND_BRICK, S.ACQUIRE_SLOT, S.ALIGN_SLOT,
                 S.DESCEND_SLOT, S.VERIFY_PLACEMENT)


@dataclass(frozen=True)
class Transition:
    """One edge of the machine: in ``source``, ``trigger`` leads to ``target``."""

    source: State
    trigger: str
    target: State
    guard: str = ""
    """When the handler fires the trigger (documentation; drawn on the diagram)."""


def _build_transitions() -> tuple[Transition, ...]:
    T = Transition
    t: list[Transition] = [
        T(S.IDLE, "start", S.TAKE_OFF, "mission started"),
        T(S.TAKE_OFF, "reached", S.GO_TO_BRICK, "at cruise altitude"),
        T(S.TAKE_OFF, "ts_lost", S.GO_SAFE, "no total station"),
        T(S.GO_TO_BRICK, "reached", S.ACQUIRE_BRICK, "above the pick pose"),
        T(S.ACQUIRE_BRICK, "acquired", S.ALIGN_BRICK, "brick seen in settle frames"),
        T(S.ALIGN_BRICK, "aligned", S.DESCEND_BRICK, "yaw and position within tolerance"),
        T(S.DESCEND_BRICK, "misaligned", S.ALIGN_BRICK, "yaw or position error too large"),
        T(S.DESCEND_BRICK, "blind", S.BLIND_DESCENT_BRICK, "camera below blind height"),
        T(S.BLIND_DESCENT_BRICK, "contact", S.GRAB, "at grab height"),
        T(S.GRAB, "grabbed", S.CLIMB_WITH_BRICK, "picker sensor: holding"),
        T(S.RETRY_PICK, "reached", S.GO_TO_BRICK, "climbed; total station present"),
        T(S.RETRY_PICK, "ts_lost", S.GO_SAFE, "no total station for ts_wait_s"),
        T(S.CLIMB_WITH_BRICK, "reached", S.GO_TO_WALL, "at cruise altitude"),
        T(S.GO_TO_WALL, "reached", S.ACQUIRE_SLOT, "above the slot"),
        T(S.ACQUIRE_SLOT, "acquired", S.ALIGN_SLOT, "bricks below seen (or course 1)"),
        T(S.ALIGN_SLOT, "aligned", S.DESCEND_SLOT, "yaw and position within tolerance"),
        T(S.DESCEND_SLOT, "misaligned", S.ALIGN_SLOT, "yaw or position error too large"),
        T(S.DESCEND_SLOT, "blind", S.BLIND_DESCENT_SLOT, "camera below blind height"),
        T(S.BLIND_DESCENT_SLOT, "contact", S.RELEASE, "brick on the bricks below"),
        T(S.RELEASE, "released", S.CLIMB_AFTER_RELEASE, "picker sensor: empty"),
        T(S.RETRY_DROP, "reached", S.GO_TO_WALL, "climbed; total station present"),
        T(S.RETRY_DROP, "ts_lost", S.GO_SAFE, "no total station for ts_wait_s"),
        T(S.CLIMB_AFTER_RELEASE, "reached", S.VERIFY_PLACEMENT, "at approach height"),
        T(S.CLIMB_AFTER_RELEASE, "ts_lost", S.GO_SAFE, "no total station"),
        T(S.VERIFY_PLACEMENT, "placed_next", S.GO_TO_BRICK, "within tolerance; bricks left"),
        T(S.VERIFY_PLACEMENT, "placed_last", S.RETURN_HOME, "within tolerance; wall done"),
        T(S.VERIFY_PLACEMENT, "out_of_tolerance", S.GO_SAFE, "placed brick off its plan"),
        T(S.VERIFY_PLACEMENT, "unverified", S.GO_SAFE, "placed brick not seen / no TS"),
        T(S.RETURN_HOME, "reached", S.LAND, "above home"),
        T(S.RETURN_HOME, "ts_lost", S.GO_SAFE, "no total station"),
        T(S.LAND, "landed", S.DONE, "on the ground"),
        T(S.GO_SAFE, "reached", S.LAND_SAFE, "above the safe zone"),
        T(S.LAND_SAFE, "landed", S.SHUTDOWN, "on the ground: motors off"),
    ]
    for s in (S.ACQUIRE_BRICK, S.ALIGN_BRICK, S.DESCEND_BRICK, S.ACQUIRE_SLOT, S.ALIGN_SLOT,
              S.DESCEND_SLOT, S.VERIFY_PLACEMENT):
        t.append(T(s, "disagreement", S.GO_SAFE, "total station vs vision > disagreement_m"))
    for s in PICK_STATES:
        t.append(T(s, "fail", S.RETRY_PICK, "failure n < retries"))
        t.append(T(s, "fail_final", S.GO_SAFE, "failure n = retries"))
    for s in DROP_STATES:
        t.append(T(s, "fail", S.RETRY_DROP, "failure n < retries"))
        t.append(T(s, "fail_final", S.GO_SAFE, "failure n = retries"))
        if s is not S.RELEASE:
            t.append(T(s, "brick_lost", S.GO_SAFE, "picker sensor: empty in flight"))
    for s in FLYING_STATES:
        if s not in (S.GO_SAFE, S.LAND_SAFE):
            t.append(T(s, "geofence", S.GO_SAFE, "setpoint would leave the site"))
    return tuple(t)


TRANSITIONS: tuple[Transition, ...] = _build_transitions()
_TABLE: dict[tuple[State, str], State] = {(tr.source, tr.trigger): tr.target for tr in TRANSITIONS}
assert len(_TABLE) == len(TRANSITIONS), "duplicate (state, trigger) in TRANSITIONS"


def next_state(state: State, trigger: str) -> State:
    """The table lookup; a pair that is not in the table is a programming error."""
    try:
        return _TABLE[(state, trigger)]
    except KeyError:
        raise RuntimeError(f"no transition from {state.value} on {trigger!r}") from None


# ============================================================================ inputs / outputs
@dataclass(frozen=True)
class Sighting:
    """One brick seen in one vision frame, in the drone's FRD body frame."""

    layout: str
    instance: int | None
    body_from_brick: np.ndarray


@dataclass(frozen=True)
class Readings:
    """What the machine knows at time ``t`` (s)."""

    t: float
    ts_position: tuple[float, float, float] | None
    """Total station: the body origin in the site frame, or None (dropout, no line of sight)."""
    nav_position: tuple[float, float, float]
    """The autopilot's own position estimate (drifts without the total station)."""
    nav_yaw: float
    """The autopilot's heading (radians, site frame convention)."""
    vision: tuple[Sighting, ...] | None = None
    """Bricks seen in a frame that arrived this tick; None = no new frame."""
    holding: bool = False
    """Picker sensor: a brick is held."""


@dataclass(frozen=True)
class Setpoint:
    position: tuple[float, float, float]
    yaw: float

    def to_json(self) -> dict:
        return {"position": [round(float(v), 4) for v in self.position],
                "yaw": round(float(self.yaw), 5)}


@dataclass(frozen=True)
class Event:
    t: float
    kind: str
    detail: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"t": round(self.t, 3), "kind": self.kind, **self.detail}


@dataclass(frozen=True)
class Output:
    state: State
    setpoint: Setpoint | None
    picker: str
    """``open`` or ``closed``."""
    motors: bool
    events: tuple[Event, ...]
    telemetry: dict


# ============================================================================ plan / memory
@dataclass(frozen=True)
class MissionPlan:
    """Everything :func:`step` needs from the scenario, precomputed (read-only)."""

    scenario: Scenario
    order: tuple[str, ...]
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]

    @classmethod
    def from_scenario(cls, scn: Scenario) -> MissionPlan:
        b = scn.site.bounds
        return cls(scn, tuple(scn.order), tuple(b.min), tuple(b.max))

    def inside(self, p) -> bool:
        return all(self.bounds_min[i] - 1e-9 <= p[i] <= self.bounds_max[i] + 1e-9
                   for i in range(3))

    def clamp_xy(self, xy) -> tuple[float, float]:
        m = 0.05
        return (min(max(xy[0], self.bounds_min[0] + m), self.bounds_max[0] - m),
                min(max(xy[1], self.bounds_min[1] + m), self.bounds_max[1] - m))


@dataclass(frozen=True)
class Memory:
    """The machine's state between ticks (immutable: each step returns a new one)."""

    state: State = S.IDLE
    entered_t: float = 0.0
    t: float | None = None
    brick_index: int = 0
    failures: tuple[tuple[str, int], ...] = (("pick", 0), ("drop", 0))
    attempt_t: float = 0.0
    align_t: float | None = None
    last_ts_t: float = -1e9
    setpoint: Setpoint | None = None
    picker: str = "open"
    picker_t: float = 0.0
    samples: tuple[tuple[float, float, float, float], ...] = ()
    """Recent estimates of the current target (x, y, z, yaw) in the site frame."""
    last_seen_t: float = -1e9
    seen_frames: int = 0
    disagree: int = 0
    ok_since: float | None = None
    held: tuple[float, float, float] | None = None
    """Held brick's offset in the body frame (x fwd, y right, yaw), estimated at the grab."""
    as_built: tuple[tuple[str, Pose4], ...] = ()
    yaw_error: float | None = None
    xy_error: float | None = None
    abort_reason: str = ""
    placed: tuple[str, ...] = ()

    def failures_of(self, phase: str) -> int:
        return dict(self.failures)[phase]


# ============================================================================ helpers
def _body_xy_to_site(v, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] + s * v[1], s * v[0] - c * v[1]])


def _site_xy_to_body(d, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)  # the FRD rotation is its own inverse
    return np.array([c * d[0] + s * d[1], s * d[0] - c * d[1]])


def _mean_pose(samples) -> Pose4:
    a = np.asarray(samples, float)
    y0 = a[-1, 3]
    yaw = y0 + float(np.mean([wrap_half(y - y0) for y in a[:, 3]]))
    return Pose4(float(a[:, 0].mean()), float(a[:, 1].mean()), float(a[:, 2].mean()), yaw)


def _sighting_site_pose(s: Sighting, p, yaw: float) -> Pose4:
    T = site_from_body(p, yaw) @ np.asarray(s.body_from_brick, float)
    return Pose4(float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), yaw_of(T))


def current_brick(plan: MissionPlan, mem: Memory) -> str | None:
    return plan.order[mem.brick_index] if mem.brick_index < len(plan.order) else None


# ============================================================================ step
class _Ctx:
    """Per-tick working state of :func:`step` (never outlives the call)."""

    def __init__(self, plan: MissionPlan, mem: Memory, r: Readings):
        self.plan, self.scn, self.r = plan, plan.scenario, r
        self.m = mem
        self.events: list[Event] = []
        self.dt = 0.0 if mem.t is None else max(0.0, r.t - mem.t)
        self.ts_ok = r.ts_position is not None
        last_ts = r.t if self.ts_ok else mem.last_ts_t
        self.m = replace(self.m, last_ts_t=last_ts, t=r.t)
        self.ts_age = r.t - last_ts
        self.p = np.asarray(r.ts_position if self.ts_ok else r.nav_position, float)
        self.yaw = float(r.nav_yaw)

    def ev(self, kind: str, **detail: Any) -> None:
        self.events.append(Event(self.r.t, kind, detail))

    def set(self, **kw: Any) -> None:
        self.m = replace(self.m, **kw)

    @property
    def th(self):
        return self.scn.thresholds

    @property
    def alt(self):
        return self.scn.altitudes


def _enter(c: _Ctx, trigger: str, **detail: Any) -> None:
    src = c.m.state
    dst = next_state(src, trigger)
    c.ev("transition", source=src.value, target=dst.value, trigger=trigger, **detail)
    c.set(state=dst, entered_t=c.r.t, ok_since=None)
    # entry actions
    if dst in (S.GO_TO_BRICK,):
        c.set(attempt_t=c.r.t, align_t=None, samples=(), seen_frames=0, disagree=0,
              yaw_error=None, xy_error=None)
    if dst in (S.GO_TO_WALL,):
        c.set(attempt_t=c.r.t, align_t=None, samples=(), seen_frames=0, disagree=0,
              yaw_error=None, xy_error=None)
    if dst is S.CLIMB_WITH_BRICK:
        c.set(attempt_t=c.r.t, samples=(), seen_frames=0, yaw_error=None, xy_error=None)
    if dst in (S.ACQUIRE_BRICK, S.ACQUIRE_SLOT, S.VERIFY_PLACEMENT):
        c.set(samples=(), seen_frames=0, disagree=0, last_seen_t=c.r.t)
    if dst in (S.ALIGN_BRICK, S.ALIGN_SLOT) and c.m.align_t is None:
        c.set(align_t=c.r.t)
    if dst is S.GRAB:
        c.set(picker="closed", picker_t=c.r.t)
    if dst is S.RELEASE:
        c.set(picker="open", picker_t=c.r.t)
    if dst is S.RETRY_PICK:
        c.set(picker="open", picker_t=c.r.t)
    if dst is S.RETRY_DROP:
        c.set(picker="closed", picker_t=c.r.t)
    if dst in (S.GO_SAFE,):
        reason = detail.get("reason", trigger)
        c.set(abort_reason=reason)
        c.ev("safe_zone", reason=reason, brick=current_brick(c.plan, c.m))
    if dst is S.SHUTDOWN:
        c.ev("shutdown", reason=c.m.abort_reason)
    if dst is S.DONE:
        c.ev("done", placed=len(c.m.placed))


def _fail(c: _Ctx, reason: str) -> None:
    phase = "pick" if c.m.state in PICK_STATES else "drop"
    n = c.m.failures_of(phase) + 1
    f = dict(c.m.failures)
    f[phase] = n
    c.set(failures=tuple(f.items()))
    brick = current_brick(c.plan, c.m)
    c.ev("phase_failed", phase=phase, brick=brick, failure=n, reason=reason)
    if n >= c.th.retries:
        _enter(c, "fail_final", reason=f"failure {n}/{c.th.retries} of the {phase} phase "
                                       f"({reason})")
    else:
        _enter(c, "fail", reason=reason)
        c.ev("retry", phase=phase, brick=brick, attempt=n + 1)


def _reset_failures(c: _Ctx, phase: str) -> None:
    f = dict(c.m.failures)
    f[phase] = 0
    c.set(failures=tuple(f.items()))


def _hold(c: _Ctx, z: float | None = None, yaw: float | None = None) -> Setpoint:
    sp = c.m.setpoint
    base = sp.position if sp is not None else tuple(c.p)
    return Setpoint((base[0], base[1], base[2] if z is None else z),
                    sp.yaw if (sp is not None and yaw is None) else (c.yaw if yaw is None else yaw))


def _settled(c: _Ctx, cond: bool, seconds: float = 0.5) -> bool:
    """True once ``cond`` has held for ``seconds``."""
    if not cond:
        c.set(ok_since=None)
        return False
    if c.m.ok_since is None:
        c.set(ok_since=c.r.t)
    return c.r.t - c.m.ok_since >= seconds - 1e-9


def _go_to(c: _Ctx, goal_xy, goal_z: float, yaw: float | None = None) -> tuple[Setpoint, bool]:
    """Transit at the cruise altitude, then to the goal; returns (setpoint, reached)."""
    cruise = c.alt.cruise_m
    sp = c.m.setpoint
    cur_xy = np.asarray(sp.position[:2] if sp is not None else c.p[:2])
    keep_yaw = sp.yaw if sp is not None else c.yaw
    y = keep_yaw if yaw is None else yaw
    far = float(np.hypot(*(np.asarray(goal_xy) - c.p[:2]))) > 0.25
    if far:
        c.set(ok_since=None)
    if far and c.p[2] < cruise - 0.15:
        return Setpoint((float(cur_xy[0]), float(cur_xy[1]), cruise), keep_yaw), False
    if far:
        return Setpoint((float(goal_xy[0]), float(goal_xy[1]), cruise), y), False
    g = Setpoint((float(goal_xy[0]), float(goal_xy[1]), float(goal_z)), y)
    err = float(np.linalg.norm(np.asarray(g.position) - c.p))
    return g, _settled(c, err < 0.08 and c.ts_age <= c.th.ts_grace_s)


def _contact_z(c: _Ctx, top: float) -> float:
    return top + c.scn.drone.picker_depth_m


def _camera_height(c: _Ctx, top: float) -> float:
    return float(c.p[2] - c.scn.drone.camera.mount.offset_m[2] - top)


def _target_brick_sightings(c: _Ctx, brick: str, expected_xy) -> list[Pose4]:
    """Site poses of ``brick`` in this frame (by id, or the one nearest where expected)."""
    if not c.r.vision:
        return []
    scn = c.scn
    b = scn.brick_by_id[brick]
    poses = []
    for s in c.r.vision:
        if s.layout != b.layout:
            continue
        if scn.has_ids(brick):
            if s.instance == b.instance:
                poses.append(_sighting_site_pose(s, c.p, c.yaw))
        else:
            pose = _sighting_site_pose(s, c.p, c.yaw)
            if math.dist((pose.x, pose.y), expected_xy) <= c.th.match_radius_m:
                poses.append(pose)
    if not scn.has_ids(brick) and len(poses) > 1:
        poses.sort(key=lambda q: math.dist((q.x, q.y), expected_xy))
        poses = poses[:1]
    return poses


def _known_positions(c: _Ctx) -> dict[tuple[str, int], Pose4]:
    """Bricks with codes whose site position the machine knows: the as-built wall, and the
    bricks still lying at their (surveyed) pick poses."""
    scn = c.scn
    built = dict(c.m.as_built)
    cur = current_brick(c.plan, c.m)
    out: dict[tuple[str, int], Pose4] = {}
    for b in scn.bricks:
        if not scn.has_ids(b.id):
            continue
        if b.id in built:
            out[(b.layout, b.instance)] = built[b.id]
        elif b.id not in c.m.placed and (b.id != cur or c.m.state in PICK_STATES):
            out[(b.layout, b.instance)] = scn.pick_pose(b.id)
    return out


def _monitor_disagreement(c: _Ctx) -> bool:
    """Thesis 8.4.3: compare the total station with vision on every frame. A brick of known
    site position seen by vision gives the drone's position; beyond ``disagreement_m`` for
    ``disagreement_frames`` frames in a row, go to the safe zone. Bricks without ids are
    matched by position and cannot reveal an offset larger than ``match_radius_m``."""
    if not c.ts_ok or c.r.vision is None:
        return False
    known = _known_positions(c)
    worst = None
    for s in c.r.vision:
        k = known.get((s.layout, s.instance))
        if k is None:
            continue
        seen = _sighting_site_pose(s, c.p, c.yaw)
        d = float(np.hypot(k.x - seen.x, k.y - seen.y))
        worst = d if worst is None else max(worst, d)
    if worst is None:
        return False
    n = c.m.disagree + 1 if worst > c.th.disagreement_m else 0
    c.set(disagree=n)
    if n >= c.th.disagreement_frames:
        c.ev("disagreement", distance_m=round(worst, 3), threshold_m=c.th.disagreement_m)
        _enter(c, "disagreement", reason=f"total station and vision disagree by {worst:.2f} m")
        return True
    return False


def _as_built(c: _Ctx) -> dict[str, Pose4]:
    return dict(c.m.as_built)


def _update_target(c: _Ctx, brick: str, drop: bool) -> bool | None:
    """Fold this frame's sightings into the target estimate.

    Returns True if the target was seen in this frame, False if a frame came without it,
    None if no frame arrived.
    """
    scn = c.scn
    if not drop:
        nominal = scn.pick_pose(brick)
        if c.r.vision is None:
            return None
        expected = _mean_pose(c.m.samples).xy if c.m.samples else nominal.xy
        poses = _target_brick_sightings(c, brick, expected)
        if not poses:
            return False
        pose = poses[0]
        cand = (pose.x, pose.y, nominal.z, pose.yaw)
    else:
        slot = scn.slot_pose(brick)
        refs = scn.references(brick)
        built = _as_built(c)
        if not refs:
            # course 1 with no placed neighbour: the total station and the plan only
            cand = (slot.x, slot.y, slot.z, slot.yaw)
            c.set(samples=(cand,), last_seen_t=c.r.t, seen_frames=c.m.seen_frames + 1)
            return True
        if c.r.vision is None:
            return None
        xs, ys, yaws = [], [], []
        for ref in refs:
            known = built.get(ref, scn.slot_pose(ref))
            poses = _target_brick_sightings(c, ref, known.xy)
            if not poses:
                continue
            seen = poses[0]
            rel = scn.ref_from_slot(ref, brick)
            ref_yaw = nearest_mod_pi(seen.yaw, known.yaw)
            dxy = np.array([[math.cos(ref_yaw), -math.sin(ref_yaw)],
                            [math.sin(ref_yaw), math.cos(ref_yaw)]]) @ np.array([rel.x, rel.y])
            xs.append(seen.x + dxy[0])
            ys.append(seen.y + dxy[1])
            yaws.append(ref_yaw + rel.yaw)
        if not xs:
            return False
        y0 = yaws[0]
        yaw = y0 + float(np.mean([wrap_half(y - y0) for y in yaws]))
        if scn.plan_by_id[brick].course == 1:
            # course 1: the plan through the total station and the heading. The neighbour is
            # only checked (seen, consistent): chaining the yaw to it was measured worse (its
            # estimate noise adds up brick after brick along the course)
            cand = (slot.x, slot.y, slot.z, slot.yaw)
        else:
            cand = (float(np.mean(xs)), float(np.mean(ys)), slot.z, nearest_mod_pi(yaw, slot.yaw))
    samples = (c.m.samples + (cand,))[-c.th.filter_frames:]
    c.set(samples=samples, last_seen_t=c.r.t, seen_frames=c.m.seen_frames + 1)
    return True


def _body_goal(c: _Ctx, target: Pose4, drop: bool) -> tuple[np.ndarray, float]:
    """Where the body must be (xy) and its heading so the picker / held brick meets target."""
    if drop and c.m.held is not None:
        hx, hy, hyaw = c.m.held
    else:
        hx, hy, hyaw = 0.0, 0.0, 0.0
    body_yaw = nearest_mod_pi(target.yaw - hyaw, c.yaw)
    xy = target.xy - _body_xy_to_site((hx, hy), body_yaw)
    return xy, body_yaw


def _errors(c: _Ctx, xy, body_yaw: float) -> tuple[float, float]:
    return float(np.hypot(*(np.asarray(xy) - c.p[:2]))), wrap_half(body_yaw - c.yaw)


def _vision_phase(c: _Ctx, drop: bool) -> Setpoint | None:
    """ACQUIRE / ALIGN / DESCEND (pick or drop). Returns the setpoint, or None if the state
    changed (the caller then runs the new state's handler on the same tick)."""
    st, th, alt, scn = c.m.state, c.th, c.alt, c.scn
    brick = current_brick(c.plan, c.m)
    if drop and not c.r.holding:
        _enter(c, "brick_lost", reason="picker sensor says the brick is gone")
        return None
    if c.ts_age > th.ts_grace_s:
        c.ev("ts_lost", age_s=round(c.ts_age, 2))
        _fail(c, "total station lost")
        return None
    if _monitor_disagreement(c):
        return None
    _update_target(c, brick, drop)
    top = scn.slot_pose(brick).z if drop else scn.pick_pose(brick).z
    approach_z = top + alt.approach_m
    acquire = st in (S.ACQUIRE_BRICK, S.ACQUIRE_SLOT)
    vision_needed = not (drop and (not scn.references(brick) or
                                   (scn.plan_by_id[brick].course == 1 and not acquire)))
    if vision_needed and c.r.t - c.m.last_seen_t > th.vision_timeout_s and not acquire:
        _fail(c, "vision lost")
        return None
    if acquire:
        if c.m.seen_frames >= (th.settle_frames if scn.references(brick) or not drop else 1):
            c.ev("acquired", brick=brick, frames=c.m.seen_frames)
            _enter(c, "acquired")
            return None
        if c.r.t - c.m.entered_t > th.acquire_timeout_s:
            _fail(c, "target not found")
            return None
        return _hold(c, z=approach_z)
    if not c.m.samples:
        _fail(c, "no target estimate")
        return None
    target = _mean_pose(c.m.samples)
    goal_xy, body_yaw = _body_goal(c, target, drop)
    xy_err, yaw_err = _errors(c, goal_xy, body_yaw)
    c.set(yaw_error=yaw_err, xy_error=xy_err)
    tol_yaw = math.radians(th.align_yaw_tolerance_deg)
    sp = c.m.setpoint
    cur_z = sp.position[2] if sp is not None else float(c.p[2])
    if st in (S.ALIGN_BRICK, S.ALIGN_SLOT):
        if c.r.t - (c.m.align_t or c.m.entered_t) > th.align_timeout_s:
            _fail(c, "alignment timeout")
            return None
        fresh = (c.r.t - c.m.last_seen_t) <= th.vision_timeout_s or not vision_needed
        ok = fresh and xy_err < th.align_position_tolerance_m and abs(yaw_err) < 0.5 * tol_yaw
        if _settled(c, ok):
            c.ev("aligned", brick=brick, yaw_error_deg=round(math.degrees(yaw_err), 2),
                 xy_error_m=round(xy_err, 3))
            _enter(c, "aligned")
            return None
        return Setpoint((float(goal_xy[0]), float(goal_xy[1]), cur_z), body_yaw)
    # DESCEND
    if abs(yaw_err) > tol_yaw or xy_err > th.descent_position_tolerance_m:
        c.ev("misaligned", brick=brick, yaw_error_deg=round(math.degrees(yaw_err), 2),
             xy_error_m=round(xy_err, 3))
        _enter(c, "misaligned")
        return None
    if _camera_height(c, top) <= alt.blind_below_m:
        c.ev("blind", brick=brick, yaw_error_deg=round(math.degrees(yaw_err), 2),
             xy_error_m=round(xy_err, 3))
        _enter(c, "blind")
        return None
    z = max(cur_z - alt.descent_speed_mps * c.dt, _contact_z(c, top))
    return Setpoint((float(goal_xy[0]), float(goal_xy[1]), z), body_yaw)


def _blind(c: _Ctx, drop: bool) -> Setpoint | None:
    th, scn = c.th, c.scn
    brick = current_brick(c.plan, c.m)
    if drop and not c.r.holding:
        _enter(c, "brick_lost", reason="picker sensor says the brick is gone")
        return None
    if c.ts_age > th.ts_grace_s:
        c.ev("ts_lost", age_s=round(c.ts_age, 2))
        _fail(c, "total station lost")
        return None
    top = scn.slot_pose(brick).z if drop else scn.pick_pose(brick).z
    zc = _contact_z(c, top)
    sp = c.m.setpoint
    z = max(sp.position[2] - c.alt.blind_speed_mps * c.dt, zc)
    if c.r.t - c.m.entered_t > c.th.contact_timeout_s:
        _fail(c, "no steady contact on target")
        return None
    # at contact, grab or release only when the total station puts the body on the target
    # and the heading is on its setpoint (a gust may have pushed the drone off)
    xy_err = float(np.hypot(sp.position[0] - c.p[0], sp.position[1] - c.p[1]))
    yaw_err = wrap_half(sp.yaw - c.yaw)
    # with the autopilot's precision landing the pick's horizontal is the autopilot's: it
    # touches down where its estimate says, and the picker sensor tells whether that was right
    xy_ok = xy_err < th.contact_position_tolerance_m or (
        not drop and scn.autopilot.precision_landing)
    on_target = (c.ts_age <= th.ts_grace_s and xy_ok
                 and abs(yaw_err) < math.radians(th.contact_yaw_tolerance_deg))
    if _settled(c, z <= zc + 1e-9 and abs(c.p[2] - zc) < 0.02 and on_target, 0.2):
        c.ev("contact", brick=brick, xy_error_m=round(xy_err, 4),
             yaw_error_deg=round(math.degrees(yaw_err), 2))
        _enter(c, "contact")
        return None
    return Setpoint((sp.position[0], sp.position[1], z), sp.yaw)


def _handle(c: _Ctx) -> Setpoint | None:
    """Run the current state's handler once; None means 'state changed, run again'."""
    st, th, alt, scn = c.m.state, c.th, c.alt, c.scn
    brick = current_brick(c.plan, c.m)
    home = scn.site.home
    flying = st in FLYING_STATES
    if flying and st not in (S.GO_SAFE, S.LAND_SAFE, S.TAKE_OFF, S.RETRY_PICK, S.RETRY_DROP,
                             S.CLIMB_AFTER_RELEASE, S.VERIFY_PLACEMENT, S.RETURN_HOME, S.LAND) \
            and c.r.t - c.m.attempt_t > th.attempt_timeout_s:
        _fail(c, "attempt timeout")
        return None
    if st is S.IDLE:
        _enter(c, "start")
        return None
    if st is S.TAKE_OFF:
        if c.ts_age > th.ts_grace_s and c.r.t - c.m.entered_t > th.ts_wait_s:
            _enter(c, "ts_lost", reason="no total station at take-off")
            return None
        sp = Setpoint((home[0], home[1], alt.cruise_m), c.yaw if c.m.setpoint is None
                      else c.m.setpoint.yaw)
        if _settled(c, c.ts_age <= th.ts_grace_s and abs(c.p[2] - alt.cruise_m) < 0.08):
            _enter(c, "reached")
            return None
        return sp
    if st in (S.GO_TO_BRICK, S.GO_TO_WALL, S.CLIMB_WITH_BRICK):
        drop = st is not S.GO_TO_BRICK
        if drop and not c.r.holding:
            _enter(c, "brick_lost", reason="picker sensor says the brick is gone")
            return None
        if c.ts_age > th.ts_grace_s:
            c.ev("ts_lost", age_s=round(c.ts_age, 2))
            _fail(c, "total station lost")
            return None
        if st is S.CLIMB_WITH_BRICK:
            sp = _hold(c, z=alt.cruise_m)
            if _settled(c, abs(c.p[2] - alt.cruise_m) < 0.08):
                _enter(c, "reached")
                return None
            return sp
        target = scn.slot_pose(brick) if drop else scn.pick_pose(brick)
        goal_xy = target.xy
        if drop and c.m.held is not None:
            goal_xy, _ = _body_goal(c, target, True)
        sp, reached = _go_to(c, goal_xy, target.z + alt.approach_m)
        if reached:
            _enter(c, "reached")
            return None
        return sp
    if st in (S.ACQUIRE_BRICK, S.ALIGN_BRICK, S.DESCEND_BRICK):
        return _vision_phase(c, drop=False)
    if st in (S.ACQUIRE_SLOT, S.ALIGN_SLOT, S.DESCEND_SLOT):
        return _vision_phase(c, drop=True)
    if st is S.BLIND_DESCENT_BRICK:
        return _blind(c, drop=False)
    if st is S.BLIND_DESCENT_SLOT:
        return _blind(c, drop=True)
    if st is S.GRAB:
        sp = _hold(c)
        if c.r.t - c.m.picker_t >= th.grab_time_s:
            if c.r.holding:
                target = _mean_pose(c.m.samples) if c.m.samples else scn.pick_pose(brick)
                d = _site_xy_to_body(target.xy - c.p[:2], c.yaw)
                c.set(held=(float(d[0]), float(d[1]), wrap_half(target.yaw - c.yaw)))
                _reset_failures(c, "pick")
                c.ev("grabbed", brick=brick, offset_m=[round(float(d[0]), 3),
                                                      round(float(d[1]), 3)])
                _enter(c, "grabbed")
                return None
            _fail(c, "grab not confirmed by the picker sensor")
            return None
        return sp
    if st is S.RELEASE:
        sp = _hold(c)
        if c.r.t - c.m.picker_t >= th.grab_time_s:
            if not c.r.holding:
                c.ev("released", brick=brick)
                c.set(held=None)
                _enter(c, "released")
                return None
            _fail(c, "release not confirmed by the picker sensor")
            return None
        return sp
    if st in (S.RETRY_PICK, S.RETRY_DROP):
        if c.ts_age > th.ts_wait_s:
            _enter(c, "ts_lost", reason=f"no total station for {th.ts_wait_s:.0f} s")
            return None
        drop = st is S.RETRY_DROP
        if drop and not c.r.holding:
            # the brick came loose while retrying: nothing safe to do with it but stop
            pass
        top = scn.slot_pose(brick).z if drop else scn.pick_pose(brick).z
        z = max(top + alt.approach_m, min(float(c.p[2]), alt.cruise_m))
        sp = _hold(c, z=z)
        if _settled(c, c.ts_age <= th.ts_grace_s and abs(c.p[2] - z) < 0.08
                    and c.r.t - c.m.entered_t >= th.grab_time_s):
            _enter(c, "reached")
            return None
        return sp
    if st is S.CLIMB_AFTER_RELEASE:
        if c.ts_age > th.ts_wait_s:
            _enter(c, "ts_lost", reason="no total station after the release")
            return None
        z = scn.slot_pose(brick).z + alt.approach_m
        sp = _hold(c, z=z)
        if _settled(c, c.ts_age <= th.ts_grace_s and abs(c.p[2] - z) < 0.08):
            _enter(c, "reached")
            return None
        return sp
    if st is S.VERIFY_PLACEMENT:
        sp = _hold(c)
        slot = scn.slot_pose(brick)
        if _monitor_disagreement(c):
            return None
        if c.ts_age <= th.ts_grace_s and c.r.vision is not None:
            expected = _mean_pose(c.m.samples).xy if c.m.samples else slot.xy
            poses = _target_brick_sightings(c, brick, expected)
            if poses:
                q = poses[0]
                c.set(samples=(c.m.samples + ((q.x, q.y, slot.z, q.yaw),))[-th.filter_frames:],
                      seen_frames=c.m.seen_frames + 1, last_seen_t=c.r.t)
        if c.m.seen_frames >= th.settle_frames:
            est = _mean_pose(c.m.samples)
            err = math.dist((est.x, est.y), (slot.x, slot.y))
            yerr = math.degrees(abs(wrap_half(est.yaw - slot.yaw)))
            tol = scn.placement_tolerance
            if err <= tol.position_m and yerr <= tol.yaw_deg:
                built = dict(c.m.as_built)
                built[brick] = Pose4(est.x, est.y, slot.z, nearest_mod_pi(est.yaw, slot.yaw))
                _reset_failures(c, "drop")
                c.set(as_built=tuple(built.items()), placed=c.m.placed + (brick,))
                c.ev("placed", brick=brick, error_m=round(err, 4), yaw_error_deg=round(yerr, 2))
                c.set(brick_index=c.m.brick_index + 1)
                last = c.m.brick_index >= len(c.plan.order)
                _enter(c, "placed_last" if last else "placed_next")
                return None
            c.ev("placement_out_of_tolerance", brick=brick, error_m=round(err, 4),
                 yaw_error_deg=round(yerr, 2))
            _enter(c, "out_of_tolerance", reason=f"{brick} placed {err * 100:.1f} cm / "
                                                 f"{yerr:.1f}° off its plan")
            return None
        if c.r.t - c.m.entered_t > th.verify_timeout_s:
            _enter(c, "unverified", reason=f"could not verify {brick}")
            return None
        return sp
    if st is S.RETURN_HOME:
        if c.ts_age > th.ts_wait_s:
            _enter(c, "ts_lost", reason="no total station on the way home")
            return None
        sp, reached = _go_to(c, home, alt.cruise_m)
        if reached:
            _enter(c, "reached")
            return None
        return sp
    if st in (S.LAND, S.LAND_SAFE):
        xy = home if st is S.LAND else scn.site.safe_zone.center
        sp0 = c.m.setpoint
        z0 = sp0.position[2] if sp0 is not None else float(c.p[2])
        touchdown = scn.drone.gear_height_m
        if c.r.holding:
            touchdown = max(touchdown, scn.drone.picker_depth_m + scn.brick_height_m(brick))
        z = max(z0 - 0.4 * c.dt, touchdown - 0.05)
        if _settled(c, c.p[2] <= touchdown + 0.03, 0.5):
            _enter(c, "landed")
            return None
        return Setpoint((float(xy[0]), float(xy[1]), z), sp0.yaw if sp0 else c.yaw)
    if st is S.GO_SAFE:
        sz = scn.site.safe_zone.center
        cruise = alt.cruise_m
        sp0 = c.m.setpoint
        yaw = sp0.yaw if sp0 is not None else c.yaw
        far = math.dist(c.p[:2], sz) > 0.25
        if far and c.p[2] < cruise - 0.15:
            xy = c.plan.clamp_xy(c.p[:2])
            return Setpoint((xy[0], xy[1], cruise), yaw)
        if far:
            return Setpoint((sz[0], sz[1], cruise), yaw)
        if _settled(c, True, 0.5):
            _enter(c, "reached")
            return None
        return Setpoint((sz[0], sz[1], cruise), yaw)
    if st in TERMINAL_STATES:
        return None
    raise RuntimeError(f"no handler for {st}")  # pragma: no cover


def step(plan: MissionPlan, mem: Memory, readings: Readings) -> tuple[Memory, Output]:
    """Advance the machine by one tick. Pure: same inputs, same outputs."""
    c = _Ctx(plan, mem, readings)
    sp: Setpoint | None = None
    for _ in range(8):  # a tick may run through a few immediate transitions
        state = c.m.state
        sp = _handle(c)
        if c.m.state is state:
            break
    else:  # pragma: no cover - would be a loop in the table
        raise RuntimeError("the machine did not settle within one tick")
    # geofence guard: never output a setpoint outside the site
    if sp is not None and not plan.inside(sp.position):
        c.ev("geofence", setpoint=[round(v, 3) for v in sp.position])
        if c.m.state not in (S.GO_SAFE, S.LAND_SAFE):
            _enter(c, "geofence", reason="a setpoint would have left the site")
            sp = _handle(c)
        if sp is not None and not plan.inside(sp.position):  # pragma: no cover - validated
            xy = plan.clamp_xy(sp.position[:2])
            sp = Setpoint((xy[0], xy[1], min(max(sp.position[2], plan.bounds_min[2]),
                                             plan.bounds_max[2])), sp.yaw)
    if sp is not None:
        c.set(setpoint=sp)
    st = c.m.state
    motors = st not in (S.IDLE, S.DONE, S.SHUTDOWN)
    tel = {
        "brick": current_brick(plan, c.m),
        "pick_failures": c.m.failures_of("pick"),
        "drop_failures": c.m.failures_of("drop"),
        "yaw_error": c.m.yaw_error,
        "xy_error": c.m.xy_error,
        "ts_age": round(min(c.ts_age, 1e6), 3),
        "target": (_mean_pose(c.m.samples).__dict__ if c.m.samples else None),
    }
    return c.m, Output(st, sp if motors else None, c.m.picker, motors, tuple(c.events), tel)


class Machine:
    """Convenience wrapper keeping the memory between calls of :func:`step`."""

    def __init__(self, scenario: Scenario):
        self.plan = MissionPlan.from_scenario(scenario)
        self.memory = Memory()

    @property
    def state(self) -> State:
        return self.memory.state

    def step(self, readings: Readings) -> Output:
        self.memory, out = step(self.plan, self.memory, readings)
        return out
