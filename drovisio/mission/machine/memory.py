"""What the machine keeps: the plan (read-only) and the memory between ticks."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drovisio.mission.machine.signals import Setpoint
from drovisio.mission.machine.states import State
from drovisio.mission.scenario import Pose4, Scenario

__all__ = ["MissionPlan", "Memory", "current_brick"]


@dataclass(frozen=True)
class MissionPlan:
    """Everything :func:`~drovisio.mission.machine.step` needs from the scenario, precomputed
    (read-only). Bounds are the site's geofence corners (x, y, z), site frame, metres."""

    scenario: Scenario
    order: tuple[str, ...]
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]

    @classmethod
    def from_scenario(cls, scn: Scenario) -> MissionPlan:
        b = scn.site.bounds
        return cls(scn, tuple(scn.order), (b.min[0], b.min[1], b.min[2]),
                   (b.max[0], b.max[1], b.max[2]))

    def inside(self, p: Sequence[float] | np.ndarray) -> bool:
        """Whether the site-frame point ``p`` (x, y, z) lies inside the geofence."""
        return all(self.bounds_min[i] - 1e-9 <= p[i] <= self.bounds_max[i] + 1e-9
                   for i in range(3))

    def clamp_xy(self, xy: Sequence[float] | np.ndarray) -> tuple[float, float]:
        """``xy`` moved 5 cm inside the geofence's horizontal bounds."""
        m = 0.05
        return (min(max(xy[0], self.bounds_min[0] + m), self.bounds_max[0] - m),
                min(max(xy[1], self.bounds_min[1] + m), self.bounds_max[1] - m))


@dataclass(frozen=True)
class Memory:
    """The machine's state between ticks (immutable: each step returns a new one)."""

    state: State = State.IDLE
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


def current_brick(plan: MissionPlan, mem: Memory) -> str | None:
    """The brick being built, or None once the wall is done."""
    return plan.order[mem.brick_index] if mem.brick_index < len(plan.order) else None
