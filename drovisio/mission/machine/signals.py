"""What the machine reads each tick and what it outputs."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drovisio.mission.machine.states import State

__all__ = ["Sighting", "Readings", "Setpoint", "Event", "Output"]


@dataclass(frozen=True)
class Sighting:
    """One brick seen in one vision frame, in the drone's FRD body frame."""

    layout: str
    instance: int | None
    body_from_brick: np.ndarray
    """(4, 4) homogeneous transform, brick frame to FRD body frame, metres."""


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
    """Where the machine wants the body: position (x, y, z) in the site frame, metres, and
    heading (radians, site frame)."""

    position: tuple[float, float, float]
    yaw: float

    def to_json(self) -> dict[str, Any]:
        return {"position": [round(float(v), 4) for v in self.position],
                "yaw": round(float(self.yaw), 5)}


@dataclass(frozen=True)
class Event:
    """Something the machine did or saw at time ``t`` (s): ``kind`` and its details."""

    t: float
    kind: str
    detail: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"t": round(self.t, 3), "kind": self.kind, **self.detail}


@dataclass(frozen=True)
class Output:
    """One tick's output: the state after the tick, the setpoint (None with the motors off),
    the picker command, the motors, the tick's events and telemetry."""

    state: State
    setpoint: Setpoint | None
    picker: str
    """``open`` or ``closed``."""
    motors: bool
    events: tuple[Event, ...]
    telemetry: dict[str, Any]
