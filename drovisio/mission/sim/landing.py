"""The pick descents: the autopilot's precision landing fed by vision (when the scenario turns
it on), and a record of each descent.

With precision landing, one :class:`~drovisio.autopilot.precland.PrecLandEstimator` per brick
is fed the vision's sightings of it as ``LANDING_TARGET`` messages (arriving ``latency_ms``
after the capture, paired with the attitude and position ``PLND_LAG`` old); the horizontal
setpoint of a pick descent is its estimate once initialised, its last estimate once lost.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drovisio.autopilot.precland import PrecLandEstimator
from drovisio.mission.frames import site_from_body
from drovisio.mission.machine import Sighting, State
from drovisio.mission.scenario import Scenario

__all__ = ["Landings", "NED_FROM_SITE", "PICK_FEED", "PICK_DESCENT"]

NED_FROM_SITE = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""The site is x east, y north, z up; ArduPilot's local frame is north, east, down."""
PICK_FEED = (State.ACQUIRE_BRICK.value, State.ALIGN_BRICK.value, State.DESCEND_BRICK.value,
             State.BLIND_DESCENT_BRICK.value)
"""States in which the brick to pick is sent to the autopilot."""
PICK_DESCENT = (State.DESCEND_BRICK.value, State.BLIND_DESCENT_BRICK.value)
"""States in which the autopilot flies the descent on its own estimate."""


class Landings:
    """The autopilot's side of the pick descents, and their records.

    Args:
        scn: The scenario.
        precland: Whether the autopilot's precision landing flies the pick descents.
        latency_s: Capture to ``LANDING_TARGET`` at the autopilot, s.
        plnd_lag_s: ``PLND_LAG``, s.
        dt: The simulator's tick, s.
    """

    def __init__(self, scn: Scenario, precland: bool, latency_s: float, plnd_lag_s: float,
                 dt: float):
        self.scn = scn
        self.precland = precland
        self.latency_s = latency_s
        self.plnd_lag_s = plnd_lag_s
        self.dt = dt
        self.blind_m: dict[str, float | None] = {}
        """Per layout, the camera height at which the brick leaves the picture."""
        self.estimator: PrecLandEstimator | None = None
        self.estimator_brick: str | None = None
        self.last_sent_h: float | None = None
        self.landing: dict[str, Any] | None = None
        self.landings: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ precision landing
    def _target_vector(self, vis: tuple[Sighting, ...], brick: str) -> np.ndarray | None:
        """The current brick's centre in the body frame (FRD, m) in this frame's sightings:
        what Drovisio sends as its ``LANDING_TARGET``."""
        b = self.scn.brick_by_id[brick]
        lay = self.scn.layout_of(brick)
        has_ids = lay.has_codes
        best: np.ndarray | None = None
        for sgt in vis:
            if sgt.layout != lay.name or (has_ids and sgt.instance != b.instance):
                continue
            v = np.asarray(sgt.body_from_brick, float)[:3, 3]
            if best is None or math.hypot(v[0], v[1]) < math.hypot(best[0], best[1]):
                best = v   # without ids: the one nearest below the drone
        return best

    def feed(self, t: float, state: str, brick: str | None, vis: tuple[Sighting, ...] | None,
             nav: np.ndarray, yaw_est: float, camera_z: float,
             bricks: dict[str, np.ndarray]) -> None:
        """The autopilot's side of one tick: its state into the lag buffer, the target seen in
        this frame sent, the filter updated.

        Args:
            nav: (3,) the autopilot's position estimate, site frame, m.
            yaw_est: The autopilot's heading, radians.
            camera_z: The camera's true height, site frame, m.
            bricks: Brick id → (4, 4) true ``site_from_brick``.
        """
        if state in PICK_FEED and brick is not None and (
                self.estimator is None or self.estimator_brick != brick):
            self.estimator = PrecLandEstimator(self.plnd_lag_s, self.dt)
            self.estimator_brick = brick
            self.last_sent_h = None
        est = self.estimator
        if est is None:
            return
        est.record(np.array([nav[1], nav[0]]),
                   NED_FROM_SITE @ site_from_body(nav, yaw_est)[:3, :3])
        if vis and state in PICK_FEED and brick is not None and brick == self.estimator_brick:
            v = self._target_vector(vis, brick)
            if v is not None:
                # on the simulator's clock (rounded like its ticks): a message due at a tick
                # is taken at that tick, paired with the state PLND_LAG before it
                est.send(round(t + self.latency_s, 6), v)
                self.last_sent_h = float(camera_z - bricks[brick][2, 3])
        est.update(t)

    def target_xy(self) -> np.ndarray | None:
        """Where the autopilot flies in a pick descent: the estimate, else the last one
        ((2,) site frame, m), None without either."""
        est = self.estimator
        if est is None:
            return None
        e = est.estimate if est.estimate is not None else est.last_estimate
        return None if e is None else np.array([e[1], e[0]])

    # ------------------------------------------------------------------ records
    def record(self, t: float, before: str, after: str, brick: str | None, pos: np.ndarray,
               bricks: dict[str, np.ndarray]) -> None:
        """Open a record when a pick descent starts, close it when it ends.

        Args:
            before: The state before this tick; ``after``: after it.
            brick: The brick being built.
            pos: (3,) the body's true position, site frame, m.
            bricks: Brick id → (4, 4) true ``site_from_brick``.
        """
        if after == State.DESCEND_BRICK.value and before != after and self.landing is None \
                and brick is not None:
            self.landing = {"brick": brick, "t_start": round(t, 3)}
            if self.estimator is not None:
                # a last estimate holds within one descent: one from an earlier attempt is
                # stale (not acquired now, the autopilot lands where the mission put it)
                self.estimator.last_estimate = self.estimator.estimate
            return
        if self.landing is None:
            return
        if self.estimator is not None and self.estimator.acquired:
            self.landing["initialised"] = True
        if after in PICK_DESCENT:
            return
        self._close(t, after, pos, bricks)

    def _close(self, t: float, after: str, pos: np.ndarray,
               bricks: dict[str, np.ndarray]) -> None:
        assert self.landing is not None
        b = self.landing["brick"]
        T = bricks[b]
        rec = dict(self.landing, t_end=round(t, 3), outcome=after,
                   error_m=round(math.dist(pos[:2], T[:2, 3]), 4))
        if self.precland:
            rec.update(self._precland_fields(b, T))
        self.landings.append(rec)
        self.landing = None

    def _precland_fields(self, b: str, T: np.ndarray) -> dict[str, Any]:
        """What the precision landing did in the descent onto ``b`` (at ``T``)."""
        assert self.landing is not None
        blind = self.blind_m.get(self.scn.brick_by_id[b].layout)
        est = self.estimator
        if est is None or self.estimator_brick != b:
            return dict(initialised=False, init_failures=0, measurements=0,
                        last_seen_camera_height_m=None, blind_height_m=blind,
                        estimate_error_m=None)
        xy = self.target_xy()
        return dict(initialised=bool(self.landing.get("initialised")),
                    init_failures=est.init_fail,
                    measurements=est.n_meas,
                    last_seen_camera_height_m=None if self.last_sent_h is None
                    else round(self.last_sent_h, 3),
                    blind_height_m=blind,
                    estimate_error_m=None if xy is None
                    else round(math.dist(xy, T[:2, 3]), 4))
