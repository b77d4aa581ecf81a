"""A simulator to run the mission machine before any flight.

One tick is ``dt`` seconds (0.05 s by default) of a simulated clock; the machine
(:func:`drovisio.mission.machine.step`) sees only sensor readings, never the truth.

* **Drone**: kinematic. The autopilot flies its *own estimate* of the position to the
  setpoint (first order, time constant ``settle_tau_s``, speed limits); the estimate is the
  total station's reading when there is one, and drifts as a random walk when there is none.
  Wind gusts are an Ornstein–Uhlenbeck velocity added to the true motion. The heading
  estimate carries a constant compass bias (``heading_bias_deg``), which the machine must
  overcome with vision. The drone cannot go through the ground or a brick.
* **Total station**: the body origin in the site frame with Gaussian noise at ``rate_hz``;
  dropouts (random and injected), loss of line of sight behind an obstacle, a wrong lock.
* **Picker**: closing grabs the brick under it if the picker is within ``capture_radius_m``
  and ``capture_yaw_deg`` of it at contact height; opening sets it down level on what is
  below (the ground, or the bricks under its two pyramids). Failures on demand.
* **Vision**: :class:`~drovisio.mission.vision.DetectorModel` (every ``1/rate_hz`` s) or
  :class:`~drovisio.mission.vision.RenderVision` (only in the states that use vision, at
  ``render_rate_hz``); poses are turned into the body frame with the camera mount.
* **Precision landing** (the scenario's ``autopilot.precision_landing``): the pick descents
  are flown as ArduPilot flies them, by one
  :class:`~drovisio.autopilot.precland.PrecLandEstimator` per brick fed the vision's sightings
  of it as ``LANDING_TARGET`` messages (arriving ``latency_ms`` after the capture, paired with
  the attitude and position ``PLND_LAG`` old); the horizontal setpoint of ``DESCEND_BRICK`` and
  ``BLIND_DESCENT_BRICK`` is its estimate once initialised, its last estimate once lost, the
  mission's own setpoint when it never initialised. The machine goes blind where the brick
  leaves the picture (:func:`drovisio.autopilot.blind.blind_height`, this lens and mount) when
  that is above ``altitudes.blind_below_m``. ``autopilot.wind_mps``: the steady wind is held
  by the autopilot, its gusts' drag moves the drone. Each pick descent's touchdown (truth) is
  in :attr:`Trace.landings`.
* **Pick area**: each brick lies within ``pick_sigma_m`` / ``pick_yaw_sigma_deg`` of its
  scenario pick pose (laid by hand).

:func:`simulate` returns a :class:`Trace`: every tick (truth, readings summary, machine
output) and the outcome, placement errors included.

The package, by subject: :mod:`.params` (the simulator's parameters, a tick, the trace),
:mod:`.rig` (the scenario's camera and mount, where a brick leaves the picture),
:mod:`.fault_state` (injected faults as they fire), :mod:`.world` (the bricks where they truly
are, the picker, what the drone rests on), :mod:`.landing` (the autopilot's precision landing
fed by vision) and :mod:`.simulator` (:class:`Simulator`, :func:`simulate`).
"""

from __future__ import annotations

from drovisio.mission.sim.params import SimParams, Tick, Trace
from drovisio.mission.sim.rig import body_from_camera_for, camera_for, landing_blind_heights
from drovisio.mission.sim.simulator import Simulator, simulate

__all__ = ["SimParams", "Tick", "Trace", "Simulator", "simulate", "camera_for",
           "body_from_camera_for", "landing_blind_heights"]
