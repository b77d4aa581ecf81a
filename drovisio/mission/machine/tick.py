"""One tick of the machine: :func:`step` and the :class:`Machine` that keeps its memory."""

from __future__ import annotations

from typing import Any

from drovisio.mission.machine.context import StepContext, enter
from drovisio.mission.machine.handlers import handle
from drovisio.mission.machine.memory import Memory, MissionPlan, current_brick
from drovisio.mission.machine.signals import Output, Readings, Setpoint
from drovisio.mission.machine.states import State
from drovisio.mission.machine.targets import mean_pose
from drovisio.mission.scenario import Scenario

__all__ = ["step", "Machine"]


def _run_handlers(c: StepContext) -> Setpoint | None:
    """Run handlers until the state stays (a tick may run through a few immediate
    transitions)."""
    sp: Setpoint | None = None
    for _ in range(8):
        state = c.mem.state
        sp = handle(c)
        if c.mem.state is state:
            return sp
    raise RuntimeError("the machine did not settle within one tick")  # pragma: no cover


def _geofenced(c: StepContext, sp: Setpoint | None) -> Setpoint | None:
    """Never output a setpoint outside the site: go to the safe zone instead."""
    plan = c.plan
    if sp is None or plan.inside(sp.position):
        return sp
    c.event("geofence", setpoint=[round(v, 3) for v in sp.position])
    if c.mem.state not in (State.GO_SAFE, State.LAND_SAFE):
        enter(c, "geofence", reason="a setpoint would have left the site")
        sp = handle(c)
    if sp is not None and not plan.inside(sp.position):  # pragma: no cover - validated
        xy = plan.clamp_xy(sp.position[:2])
        sp = Setpoint((xy[0], xy[1], min(max(sp.position[2], plan.bounds_min[2]),
                                         plan.bounds_max[2])), sp.yaw)
    return sp


def _telemetry(c: StepContext) -> dict[str, Any]:
    mem = c.mem
    return {
        "brick": current_brick(c.plan, mem),
        "pick_failures": mem.failures_of("pick"),
        "drop_failures": mem.failures_of("drop"),
        "yaw_error": mem.yaw_error,
        "xy_error": mem.xy_error,
        "ts_age": round(min(c.ts_age, 1e6), 3),
        "target": (mean_pose(mem.samples).__dict__ if mem.samples else None),
    }


def step(plan: MissionPlan, mem: Memory, readings: Readings) -> tuple[Memory, Output]:
    """Advance the machine by one tick. Pure: same inputs, same outputs.

    Args:
        plan: the mission, from :meth:`MissionPlan.from_scenario`.
        mem: the memory the previous tick returned (``Memory()`` at first).
        readings: this tick's sensor readings.

    Returns:
        The new memory and the tick's output.
    """
    c = StepContext(plan, mem, readings)
    sp = _geofenced(c, _run_handlers(c))
    if sp is not None:
        c.update(setpoint=sp)
    st = c.mem.state
    motors = st not in (State.IDLE, State.DONE, State.SHUTDOWN)
    tel = _telemetry(c)
    return c.mem, Output(st, sp if motors else None, c.mem.picker, motors, tuple(c.events), tel)


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
