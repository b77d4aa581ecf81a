"""The machine's states and its transition table.

States and transitions are data: a state's handler only says *what happened* (a trigger such
as ``aligned``, ``fail``, ``disagreement``) and :data:`TRANSITIONS` says *where that leads*. A
(state, trigger) pair that is not in the table is a bug and raises, so the diagram drawn from
the table (:mod:`drovisio.mission.diagram`) is the machine.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

__all__ = ["State", "Transition", "TRANSITIONS", "PICK_STATES", "DROP_STATES", "FLYING_STATES",
           "TERMINAL_STATES", "SAFE_STATES", "DESCENT_STATES", "VISION_STATES",
           "ATTEMPT_STATES", "next_state"]


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


PICK_STATES = (State.GO_TO_BRICK, State.ACQUIRE_BRICK, State.ALIGN_BRICK, State.DESCEND_BRICK,
               State.BLIND_DESCENT_BRICK, State.GRAB)
DROP_STATES = (State.CLIMB_WITH_BRICK, State.GO_TO_WALL, State.ACQUIRE_SLOT, State.ALIGN_SLOT,
               State.DESCEND_SLOT, State.BLIND_DESCENT_SLOT, State.RELEASE)
SAFE_STATES = (State.GO_SAFE, State.LAND_SAFE, State.SHUTDOWN)
TERMINAL_STATES = (State.DONE, State.SHUTDOWN)
DESCENT_STATES = (State.DESCEND_BRICK, State.BLIND_DESCENT_BRICK, State.DESCEND_SLOT,
                  State.BLIND_DESCENT_SLOT)
FLYING_STATES = tuple(s for s in State if s not in (State.IDLE, State.DONE, State.SHUTDOWN))
VISION_STATES = (State.ACQUIRE_BRICK, State.ALIGN_BRICK, State.DESCEND_BRICK, State.ACQUIRE_SLOT,
                 State.ALIGN_SLOT, State.DESCEND_SLOT, State.VERIFY_PLACEMENT)
ATTEMPT_STATES = tuple(s for s in FLYING_STATES if s not in (
    State.GO_SAFE, State.LAND_SAFE, State.TAKE_OFF, State.RETRY_PICK, State.RETRY_DROP,
    State.CLIMB_AFTER_RELEASE, State.VERIFY_PLACEMENT, State.RETURN_HOME, State.LAND))
"""States bounded by ``attempt_timeout_s`` (an attempt of the pick or the drop phase)."""


@dataclass(frozen=True)
class Transition:
    """One edge of the machine: in ``source``, ``trigger`` leads to ``target``."""

    source: State
    trigger: str
    target: State
    guard: str = ""
    """When the handler fires the trigger (documentation; drawn on the diagram)."""


def _main_edges() -> list[Transition]:
    """The edges of a mission that goes well, the retries' way back, and the landings."""
    S, T = State, Transition  # short names keep the table one edge per line
    return [
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


def _abort_edges() -> list[Transition]:
    """The edges many states share: disagreement, failures, a lost brick, the geofence."""
    t: list[Transition] = []
    for s in VISION_STATES:
        t.append(Transition(s, "disagreement", State.GO_SAFE,
                            "total station vs vision > disagreement_m"))
    for s in PICK_STATES:
        t.append(Transition(s, "fail", State.RETRY_PICK, "failure n < retries"))
        t.append(Transition(s, "fail_final", State.GO_SAFE, "failure n = retries"))
    for s in DROP_STATES:
        t.append(Transition(s, "fail", State.RETRY_DROP, "failure n < retries"))
        t.append(Transition(s, "fail_final", State.GO_SAFE, "failure n = retries"))
        if s is not State.RELEASE:
            t.append(Transition(s, "brick_lost", State.GO_SAFE,
                                "picker sensor: empty in flight"))
    for s in FLYING_STATES:
        if s not in (State.GO_SAFE, State.LAND_SAFE):
            t.append(Transition(s, "geofence", State.GO_SAFE, "setpoint would leave the site"))
    return t


TRANSITIONS: tuple[Transition, ...] = tuple(_main_edges() + _abort_edges())
_TABLE: dict[tuple[State, str], State] = {(tr.source, tr.trigger): tr.target for tr in TRANSITIONS}
assert len(_TABLE) == len(TRANSITIONS), "duplicate (state, trigger) in TRANSITIONS"


def next_state(state: State, trigger: str) -> State:
    """The table lookup; a pair that is not in the table is a programming error."""
    try:
        return _TABLE[(state, trigger)]
    except KeyError:
        raise RuntimeError(f"no transition from {state.value} on {trigger!r}") from None
