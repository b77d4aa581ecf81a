"""Faults injected into a simulated mission.

A :class:`Fault` is triggered either by the machine entering a state (optionally only while
it works on a given brick, the n-th time, after a delay) or at a time; it then lasts
``duration_s``. Kinds:

``grab_fail``      the next ``count`` grab attempts fail (picker closes on nothing)
``release_fail``   the next ``count`` releases jam (the brick stays in the picker)
``vision_loss``    the camera gives frames with no brick in them
``vision_offset``  vision reports every brick ``magnitude`` m off (a wrong detection)
``ts_dropout``     the total station gives no reading
``ts_offset``      the total station locks ``magnitude`` m off (a wrong reflection): the
                   autopilot follows it, vision does not → disagreement
``ts_blocked``     line of sight lost while the prism is behind a ``magnitude``-high wall
                   (a box around ``box``); only with ``box`` set
``gust``           a wind gust of ``magnitude`` m/s (random direction) for ``duration_s``

:data:`CHECK_FAULTS` is the table ``drovisio mission check`` runs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

__all__ = ["Fault", "FaultCase", "CHECK_FAULTS", "KINDS", "preset"]

Kind = Literal["grab_fail", "release_fail", "vision_loss", "vision_offset", "ts_dropout",
               "ts_offset", "ts_blocked", "gust"]
KINDS: tuple[str, ...] = ("grab_fail", "release_fail", "vision_loss", "vision_offset",
                          "ts_dropout", "ts_offset", "ts_blocked", "gust")


@dataclass(frozen=True)
class Fault:
    kind: Kind
    state: str | None = None
    """Trigger when the machine enters this state (None: at ``at_s``, or at once)."""
    brick: str | None = None
    """Only while working on this brick: its id, or ``#k`` for the k-th brick of the build
    order (clamped to the last one; see :meth:`FaultCase.for_order`)."""
    occurrence: int = 1
    """The n-th entry into ``state`` (for that brick) triggers it."""
    delay_s: float = 0.0
    at_s: float | None = None
    duration_s: float = 2.0
    count: int = 1
    magnitude: float = 0.3
    box: tuple[float, float, float, float] | None = None
    """(xmin, ymin, xmax, ymax) of an obstacle for ``ts_blocked``."""

    def describe(self) -> str:
        where = f" in {self.state}" if self.state else (f" at {self.at_s:g} s" if self.at_s
                                                        is not None else "")
        on = f" on {self.brick}" if self.brick else ""
        nth = f" (entry {self.occurrence})" if self.occurrence > 1 else ""
        if self.kind in ("grab_fail", "release_fail"):
            return f"{self.kind} ×{self.count}{on}"
        return f"{self.kind}{where}{on}{nth} for {self.duration_s:g} s"


@dataclass(frozen=True)
class FaultCase:
    """A named row of the fault table: faults and the outcome the strategy must produce."""

    name: str
    faults: tuple[Fault, ...]
    expect: Literal["completed", "safe_zone"]
    note: str = ""

    def for_order(self, order: list[str]) -> FaultCase:
        """The case with ``#k`` bricks resolved against a build order."""
        def res(b: str | None) -> str | None:
            if b is None or not b.startswith("#"):
                return b
            k = min(int(b[1:]), len(order))
            return order[k - 1]
        return replace(self, faults=tuple(replace(f, brick=res(f.brick)) for f in self.faults))


CHECK_FAULTS: tuple[FaultCase, ...] = (
    FaultCase("no fault", (), "completed", "baseline"),
    FaultCase("missed grab", (Fault("grab_fail", brick="#2", count=1),), "completed",
              "picker sensor says empty after the grab: retry the pick"),
    FaultCase("vision lost during descent",
              (Fault("vision_loss", state="DESCEND_BRICK", brick="#3", delay_s=1.0,
                     duration_s=3.0),), "completed",
              "no sighting above the blind height: climb and retry"),
    FaultCase("total-station dropout",
              (Fault("ts_dropout", state="BLIND_DESCENT_SLOT", brick="#6", delay_s=0.5,
                     duration_s=2.5),), "completed",
              "blind descent without the total station: abort the drop, retry"),
    FaultCase("disagreement (total station locks 0.3 m off)",
              (Fault("ts_offset", state="ALIGN_SLOT", brick="#7", duration_s=1e9,
                     magnitude=0.3),), "safe_zone",
              "total station vs vision beyond the threshold: safe zone"),
    FaultCase("three failed drops", (Fault("release_fail", brick="#4", count=3),), "safe_zone",
              "the release jams three times: safe zone with the brick"),
    FaultCase("three missed grabs", (Fault("grab_fail", brick="#5", count=3),), "safe_zone",
              "the third failure of the pick phase: safe zone"),
    FaultCase("wind gust during descent",
              (Fault("gust", state="DESCEND_SLOT", brick="#8", delay_s=0.5, duration_s=2.0,
                     magnitude=0.5),), "completed",
              "the gust pushes the drone off: stop descending, realign, go on"),
)


def preset(name: str) -> FaultCase:
    """A row of :data:`CHECK_FAULTS` by (case-insensitive prefix of) its name."""
    key = name.lower().replace("-", " ").replace("_", " ")
    for case in CHECK_FAULTS:
        if case.name.lower().startswith(key):
            return case
    raise KeyError(f"no fault case {name!r}; known: "
                   + ", ".join(repr(c.name) for c in CHECK_FAULTS))
