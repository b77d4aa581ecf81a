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
and heading in the site frame, see :mod:`drovisio.mission.frames`), the picker command, the
motors, events and telemetry.

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
  align, descend, blind descent, release; the picker sensor must confirm; climb and
  **verify** the placement by vision against the plan.
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

The package, by subject: :mod:`.states` (the states and the transition table),
:mod:`.signals` (readings in, outputs out), :mod:`.memory` (the plan and the memory between
ticks), :mod:`.context` (one tick's working state, entering a state, failing a phase, the
moves every state shares), :mod:`.targets` (vision sightings to site poses, the target's
estimate, the total station against vision), :mod:`.handlers` (one handler per state) and
:mod:`.tick` (:func:`step`, :class:`Machine`).
"""

from __future__ import annotations

from drovisio.mission.machine.memory import Memory, MissionPlan, current_brick
from drovisio.mission.machine.signals import Event, Output, Readings, Setpoint, Sighting
from drovisio.mission.machine.states import (
    ATTEMPT_STATES,
    DESCENT_STATES,
    DROP_STATES,
    FLYING_STATES,
    PICK_STATES,
    SAFE_STATES,
    TERMINAL_STATES,
    TRANSITIONS,
    VISION_STATES,
    State,
    Transition,
    next_state,
)
from drovisio.mission.machine.tick import Machine, step

__all__ = ["State", "Transition", "TRANSITIONS", "PICK_STATES", "DROP_STATES", "FLYING_STATES",
           "TERMINAL_STATES", "SAFE_STATES", "DESCENT_STATES", "VISION_STATES",
           "ATTEMPT_STATES", "Sighting", "Readings", "Setpoint", "Event", "Output", "Memory",
           "MissionPlan", "step", "Machine", "next_state", "current_brick"]
