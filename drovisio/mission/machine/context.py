"""One tick's working state and the actions every state handler shares.

A :class:`StepContext` lives for one call of :func:`~drovisio.mission.machine.step`: it holds
the readings, the memory as it is being updated and the events of the tick. :func:`enter` takes a
transition from the table and runs the target state's entry action (:data:`ENTRY_ACTIONS`);
:func:`fail` counts a failure of the phase and takes ``fail`` or ``fail_final``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from drovisio.mission.machine.memory import Memory, MissionPlan, current_brick
from drovisio.mission.machine.signals import Event, Readings, Setpoint
from drovisio.mission.machine.states import PICK_STATES, State, next_state
from drovisio.mission.scenario import Altitudes, Scenario, Thresholds

__all__ = ["StepContext", "enter", "fail", "reset_failures", "hold", "settled", "go_to",
           "contact_z", "camera_height", "ENTRY_ACTIONS"]


class StepContext:
    """Per-tick working state of :func:`~drovisio.mission.machine.step` (never outlives the
    call).

    Attributes:
        plan: the mission plan.
        scn: the scenario.
        readings: this tick's readings.
        mem: the memory, replaced as the tick updates it.
        events: the events of the tick, in order.
        dt: time since the previous tick, s (0 on the first).
        ts_ok: whether the total station gave a position this tick.
        ts_age: time since the total station's last position, s.
        position: (3,) the body origin in the site frame, m: the total station's, else the
            autopilot's own estimate.
        yaw: the autopilot's heading, radians.
    """

    def __init__(self, plan: MissionPlan, mem: Memory, readings: Readings):
        self.plan, self.scn, self.readings = plan, plan.scenario, readings
        self.events: list[Event] = []
        self.dt = 0.0 if mem.t is None else max(0.0, readings.t - mem.t)
        self.ts_ok = readings.ts_position is not None
        last_ts = readings.t if self.ts_ok else mem.last_ts_t
        self.mem = replace(mem, last_ts_t=last_ts, t=readings.t)
        self.ts_age = readings.t - last_ts
        self.position = np.asarray(readings.ts_position if readings.ts_position is not None
                                   else readings.nav_position, float)
        self.yaw = float(readings.nav_yaw)

    @property
    def now(self) -> float:
        """This tick's time, s."""
        return self.readings.t

    @property
    def th(self) -> Thresholds:
        return self.scn.thresholds

    @property
    def alt(self) -> Altitudes:
        return self.scn.altitudes

    @property
    def brick(self) -> str | None:
        """The brick being built (None once the wall is done)."""
        return current_brick(self.plan, self.mem)

    @property
    def active_brick(self) -> str:
        """The brick of a pick or drop phase (there always is one there)."""
        brick = self.brick
        if brick is None:  # pragma: no cover - the phases only run while bricks are left
            raise RuntimeError(f"{self.mem.state.value} without a brick to build")
        return brick

    def event(self, kind: str, **detail: Any) -> None:
        self.events.append(Event(self.now, kind, detail))

    def update(self, **changes: Any) -> None:
        """Replace fields of the memory."""
        self.mem = replace(self.mem, **changes)


# ------------------------------------------------------------------------- entry actions
def _start_attempt(c: StepContext) -> None:
    c.update(attempt_t=c.now, align_t=None, samples=(), seen_frames=0, disagree=0,
             yaw_error=None, xy_error=None)


def _start_climb(c: StepContext) -> None:
    c.update(attempt_t=c.now, samples=(), seen_frames=0, yaw_error=None, xy_error=None)


def _start_looking(c: StepContext) -> None:
    c.update(samples=(), seen_frames=0, disagree=0, last_seen_t=c.now)


def _start_aligning(c: StepContext) -> None:
    if c.mem.align_t is None:
        c.update(align_t=c.now)


def _picker(command: str) -> Callable[[StepContext], None]:
    def act(c: StepContext) -> None:
        c.update(picker=command, picker_t=c.now)
    return act


def _shut_down(c: StepContext) -> None:
    c.event("shutdown", reason=c.mem.abort_reason)


def _done(c: StepContext) -> None:
    c.event("done", placed=len(c.mem.placed))


ENTRY_ACTIONS: dict[State, Callable[[StepContext], None]] = {
    State.GO_TO_BRICK: _start_attempt,
    State.GO_TO_WALL: _start_attempt,
    State.CLIMB_WITH_BRICK: _start_climb,
    State.ACQUIRE_BRICK: _start_looking,
    State.ACQUIRE_SLOT: _start_looking,
    State.VERIFY_PLACEMENT: _start_looking,
    State.ALIGN_BRICK: _start_aligning,
    State.ALIGN_SLOT: _start_aligning,
    State.GRAB: _picker("closed"),
    State.RELEASE: _picker("open"),
    State.RETRY_PICK: _picker("open"),
    State.RETRY_DROP: _picker("closed"),
    State.SHUTDOWN: _shut_down,
    State.DONE: _done,
}
"""What entering a state does (:data:`State.GO_SAFE`'s, which needs the reason, is in
:func:`enter`)."""


def enter(c: StepContext, trigger: str, **detail: Any) -> None:
    """Take the table's transition from the current state on ``trigger``."""
    src = c.mem.state
    dst = next_state(src, trigger)
    c.event("transition", source=src.value, target=dst.value, trigger=trigger, **detail)
    c.update(state=dst, entered_t=c.now, ok_since=None)
    if dst is State.GO_SAFE:
        reason = detail.get("reason", trigger)
        c.update(abort_reason=reason)
        c.event("safe_zone", reason=reason, brick=c.brick)
        return
    action = ENTRY_ACTIONS.get(dst)
    if action is not None:
        action(c)


def fail(c: StepContext, reason: str) -> None:
    """A failure of the current phase: retry it, or the safe zone after ``retries``."""
    phase = "pick" if c.mem.state in PICK_STATES else "drop"
    n = c.mem.failures_of(phase) + 1
    f = dict(c.mem.failures)
    f[phase] = n
    c.update(failures=tuple(f.items()))
    brick = c.brick
    c.event("phase_failed", phase=phase, brick=brick, failure=n, reason=reason)
    if n >= c.th.retries:
        enter(c, "fail_final", reason=f"failure {n}/{c.th.retries} of the {phase} phase "
                                      f"({reason})")
    else:
        enter(c, "fail", reason=reason)
        c.event("retry", phase=phase, brick=brick, attempt=n + 1)


def reset_failures(c: StepContext, phase: str) -> None:
    f = dict(c.mem.failures)
    f[phase] = 0
    c.update(failures=tuple(f.items()))


# ------------------------------------------------------------------------- motion
def hold(c: StepContext, z: float | None = None, yaw: float | None = None) -> Setpoint:
    """Stay where the last setpoint was (or where the body is), at height ``z`` if given."""
    sp = c.mem.setpoint
    base = sp.position if sp is not None else tuple(c.position)
    keep_yaw = sp.yaw if (sp is not None and yaw is None) else (c.yaw if yaw is None else yaw)
    return Setpoint((base[0], base[1], base[2] if z is None else z), keep_yaw)


def settled(c: StepContext, cond: bool, seconds: float = 0.5) -> bool:
    """True once ``cond`` has held for ``seconds``."""
    if not cond:
        c.update(ok_since=None)
        return False
    if c.mem.ok_since is None:
        c.update(ok_since=c.now)
    ok_since = c.mem.ok_since
    assert ok_since is not None
    return c.now - ok_since >= seconds - 1e-9


def go_to(c: StepContext, goal_xy: Sequence[float] | np.ndarray, goal_z: float,
          yaw: float | None = None) -> tuple[Setpoint, bool]:
    """Transit at the cruise altitude, then to the goal; returns (setpoint, reached)."""
    cruise = c.alt.cruise_m
    sp = c.mem.setpoint
    cur_xy = np.asarray(sp.position[:2] if sp is not None else c.position[:2])
    keep_yaw = sp.yaw if sp is not None else c.yaw
    y = keep_yaw if yaw is None else yaw
    far = float(np.hypot(*(np.asarray(goal_xy) - c.position[:2]))) > 0.25
    if far:
        c.update(ok_since=None)
    if far and c.position[2] < cruise - 0.15:
        return Setpoint((float(cur_xy[0]), float(cur_xy[1]), cruise), keep_yaw), False
    if far:
        return Setpoint((float(goal_xy[0]), float(goal_xy[1]), cruise), y), False
    g = Setpoint((float(goal_xy[0]), float(goal_xy[1]), float(goal_z)), y)
    err = float(np.linalg.norm(np.asarray(g.position) - c.position))
    return g, settled(c, err < 0.08 and c.ts_age <= c.th.ts_grace_s)


def contact_z(scn: Scenario, top: float) -> float:
    """Body height at which the picker touches a top face at height ``top`` (m)."""
    return top + scn.drone.picker_depth_m


def camera_height(c: StepContext, top: float) -> float:
    """The camera's height above a top face at height ``top`` (m)."""
    return float(c.position[2] - c.scn.drone.camera.mount.offset_m[2] - top)
