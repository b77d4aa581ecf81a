"""Injected faults as the simulation meets them: when each fires, which are active, and the
grab and release failures still to come."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drovisio.mission.faults import Fault

__all__ = ["FaultState", "segment_hits_box"]


class FaultState:
    """The faults of one run: which fired, which are active now (kind, start and end time, a
    random horizontal direction scaled by the fault's magnitude), the grab and release failures
    left per brick (None: any brick)."""

    def __init__(self, faults: tuple[Fault, ...]):
        self.faults = faults
        self.active: list[tuple[Fault, float, float, np.ndarray]] = []
        self.entries: dict[tuple[str, str | None], int] = {}
        self.fired: set[int] = set()
        self.grab_fail: dict[str | None, int] = {}
        self.release_fail: dict[str | None, int] = {}
        for f in faults:
            if f.kind == "grab_fail":
                self.grab_fail[f.brick] = self.grab_fail.get(f.brick, 0) + f.count
            elif f.kind == "release_fail":
                self.release_fail[f.brick] = self.release_fail.get(f.brick, 0) + f.count

    def on_state(self, t: float, state: str, brick: str | None, rng: np.random.Generator) -> None:
        key = (state, brick)
        self.entries[key] = self.entries.get(key, 0) + 1
        for i, f in enumerate(self.faults):
            if i in self.fired or f.state is None or f.kind in ("grab_fail", "release_fail"):
                continue
            if f.state == state and (f.brick is None or f.brick == brick):
                n = self.entries[key] if f.brick else sum(
                    v for (s, _), v in self.entries.items() if s == state)
                if n == f.occurrence:
                    self._start(i, f, t + f.delay_s, rng)

    def on_time(self, t: float, rng: np.random.Generator) -> None:
        for i, f in enumerate(self.faults):
            if i in self.fired or f.kind in ("grab_fail", "release_fail") or f.state is not None:
                continue
            if t >= (f.at_s or 0.0):
                self._start(i, f, max(t, f.at_s or 0.0), rng)

    def _start(self, i: int, f: Fault, t0: float, rng: np.random.Generator) -> None:
        self.fired.add(i)
        a = rng.uniform(0, 2 * math.pi)
        vec = np.array([math.cos(a), math.sin(a), 0.0]) * f.magnitude
        self.active.append((f, t0, t0 + f.duration_s, vec))

    def get(self, kind: str, t: float) -> list[tuple[Fault, np.ndarray]]:
        return [(f, v) for f, a, b, v in self.active if f.kind == kind and a <= t < b]

    def take(self, table: dict[str | None, int], brick: str | None) -> bool:
        """Use up one failure of ``table`` for ``brick`` (or for any brick)."""
        for key in (brick, None):
            if table.get(key, 0) > 0:
                table[key] -= 1
                return True
        return False


def segment_hits_box(p0: np.ndarray, p1: np.ndarray, box: Sequence[float], height: float
                     ) -> bool:
    """Whether the segment p0–p1 (site frame, m) passes through ``box`` (xmin, ymin, xmax,
    ymax) below ``height`` (sampled at 25 points)."""
    xmin, ymin, xmax, ymax = box
    for s in np.linspace(0.0, 1.0, 25):
        q = p0 + s * (p1 - p0)
        if xmin <= q[0] <= xmax and ymin <= q[1] <= ymax and q[2] <= height:
            return True
    return False
