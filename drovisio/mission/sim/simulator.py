"""The simulated mission: the drone's dynamics, its sensors, and the loop that steps the
machine on them (see :mod:`drovisio.mission.sim`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import replace

import numpy as np

from drovisio.autopilot.precland import LandingParams
from drovisio.mission.faults import Fault
from drovisio.mission.frames import site_from_body, wrap_pi
from drovisio.mission.machine import (
    TERMINAL_STATES,
    VISION_STATES,
    Machine,
    Output,
    Readings,
    Sighting,
    State,
)
from drovisio.mission.scenario import Scenario
from drovisio.mission.sim.fault_state import FaultState, segment_hits_box
from drovisio.mission.sim.landing import PICK_DESCENT, Landings
from drovisio.mission.sim.params import SimParams, Tick, Trace
from drovisio.mission.sim.rig import body_from_camera_for, camera_for, landing_blind_heights
from drovisio.mission.sim.world import BrickWorld
from drovisio.mission.vision import DetectorModel, RenderVision

__all__ = ["Simulator", "simulate"]

_VISION_STATE_VALUES = {s.value for s in VISION_STATES}
_PROGRESS_EVENTS = ("placed", "safe_zone", "phase_failed")


class Simulator:
    """One simulated mission (see :mod:`drovisio.mission.sim`).

    The truth: ``pos`` (3,) the body origin and ``yaw`` the heading, site frame; ``world``
    the bricks. The autopilot's view: ``est_err`` (its position estimate's error) and
    ``bias`` (its compass bias, radians).
    """

    def __init__(self, scenario: Scenario, faults: tuple[Fault, ...] = (),
                 params: SimParams | None = None,
                 progress: Callable[[str], None] | None = None):
        self.scn = scenario
        self.p = params or SimParams()
        self.faults = tuple(faults)
        self.progress = progress
        self.rng = np.random.default_rng(self.p.seed)
        self.camera = camera_for(scenario)
        self.mount = body_from_camera_for(scenario)
        ap = scenario.autopilot
        vp = self.p.vision_params
        if ap.rate_hz is not None:
            vp = replace(vp, rate_hz=ap.rate_hz)
        if ap.detect_prob is not None:
            vp = replace(vp, miss_prob=1.0 - ap.detect_prob)
        self.vision_params = vp
        self._next_frame = 0.0
        self.model = DetectorModel(self.camera, vp)
        # the autopilot's own draws (wind) come from their own stream: the scenario's other
        # draws stay those of a run without it
        self.ap_rng = np.random.default_rng([self.p.seed, 0x504C4E44])
        self.precland = ap.precision_landing
        self.landings = Landings(
            scenario, self.precland, ap.latency_ms / 1e3,
            (ap.latency_ms if ap.plnd_lag_ms is None else ap.plnd_lag_ms) / 1e3, self.p.dt)
        self.machine = Machine(self._machine_scenario())
        self._init_wind()
        self.render: RenderVision | None = None
        if self.p.vision == "render":
            self.render = RenderVision(self.camera, [scenario.layout(n) for n in scenario.layouts],
                                       ss=self.p.render_ss, seed=self.p.seed)
        # truth
        home = scenario.site.home
        self.pos = np.array([home[0], home[1], scenario.drone.gear_height_m])
        self.yaw = math.radians(90.0)
        self.vel_gust = np.zeros(3)
        self.est_err = np.zeros(3)
        self.bias = math.radians(self.p.heading_bias_deg)
        self.world = BrickWorld.laid_by_hand(scenario, self.p, self.rng)
        self.picker = "open"
        self.fs = FaultState(self.faults)
        self.last_state: str | None = None
        self.vision_frames = 0

    def _machine_scenario(self) -> Scenario:
        """The scenario the machine flies: with precision landing, vision is lost above the
        scenario's blind height when the brick leaves the picture there, and the descent goes
        blind at that height."""
        scenario = self.scn
        if not self.precland:
            return scenario
        blind_m = landing_blind_heights(scenario, self.camera, self.mount)
        self.landings.blind_m = blind_m
        highest = max((b for b in blind_m.values() if b is not None), default=0.0)
        alt = scenario.altitudes
        if highest + 0.02 > alt.blind_below_m:
            return scenario.model_copy(update={"altitudes": alt.model_copy(
                update={"blind_below_m": highest + 0.02})})
        return scenario

    def _init_wind(self) -> None:
        self.wind = np.zeros(2)
        wind_mps = self.scn.autopilot.wind_mps
        if wind_mps > 0:
            a = self.ap_rng.uniform(0.0, 2 * math.pi)
            self.wind = np.array([math.cos(a), math.sin(a)]) * wind_mps
        self.air_gust = np.zeros(2)
        self.v_wind = np.zeros(2)

    # ------------------------------------------------------------------ sensors
    def _ts_reading(self, t: float) -> tuple[float, float, float] | None:
        p = self.p
        k = int(round(t / p.dt))
        every = max(1, int(round(1.0 / (p.ts_rate_hz * p.dt))))
        if k % every:
            return None
        if self.fs.get("ts_dropout", t) or self.rng.random() < p.ts_dropout_prob:
            return None
        for f, _ in self.fs.get("ts_blocked", t):
            if f.box and segment_hits_box(np.asarray(p.ts_position), self.pos, f.box,
                                          f.magnitude):
                return None
        r = self.pos + self.rng.normal(0.0, p.ts_sigma_m, 3)
        for _, v in self.fs.get("ts_offset", t):
            r = r + v
        return (float(r[0]), float(r[1]), float(r[2]))

    def _frame_due(self, t: float, use_render: bool) -> bool:
        """Whether a vision frame arrives at ``t``."""
        p = self.p
        rate = p.render_rate_hz if use_render else self.vision_params.rate_hz
        if self.scn.autopilot.rate_hz is not None and not use_render:
            # a rate the tick does not divide: frames on the ticks nearest to it
            if t + 1e-9 < self._next_frame:
                return False
            self._next_frame += 1.0 / rate
            return True
        every = max(1, int(round(1.0 / (rate * p.dt))))
        return not int(round(t / p.dt)) % every

    def _vision(self, t: float, state: str, brick: str | None) -> tuple[Sighting, ...] | None:
        p = self.p
        use_render = self.render is not None and state in _VISION_STATE_VALUES and (
            p.render_bricks is None or brick in p.render_bricks)
        if not self._frame_due(t, use_render):
            return None
        self.vision_frames += 1
        if self.fs.get("vision_loss", t):
            return ()
        wfb = site_from_body(self.pos, self.yaw)
        wfc = wfb @ self.mount
        source: DetectorModel | RenderVision = (
            self.render if use_render and self.render is not None else self.model)
        seen = source.observe(wfc, self.world.world_bricks(), self.rng)
        offs = self.fs.get("vision_offset", t)
        out = []
        for s in seen:
            bfb = self.mount @ s.camera_from_brick
            if offs:
                shift = np.linalg.inv(wfb)[:3, :3] @ offs[0][1]
                bfb = bfb.copy()
                bfb[:3, 3] += shift
            out.append(Sighting(s.layout, s.instance, bfb))
        return tuple(out)

    # ------------------------------------------------------------------ picker
    def _picker(self, cmd: str, brick: str | None) -> None:
        if cmd == self.picker:
            return
        self.picker = cmd
        self.world.picker(cmd, brick, self.pos, self.yaw, self.p, self.fs)

    # ------------------------------------------------------------------ dynamics
    def _drift_and_gusts(self, t: float, has_ts: bool, ts: tuple[float, float, float] | None
                         ) -> np.ndarray:
        """Update the autopilot's estimate error (the total station resets it, else it
        drifts) and the gusts; returns the gust velocity (3,), m/s."""
        p = self.p
        dt = p.dt
        if has_ts:
            self.est_err = np.asarray(ts) - self.pos
        else:
            self.est_err = self.est_err + self.rng.normal(0.0, p.drift_m_per_sqrt_s * math.sqrt(dt),
                                                          3) * np.array([1, 1, 0.3])
        a = math.exp(-dt / p.gust_tau_s)
        self.vel_gust = a * self.vel_gust + math.sqrt(1 - a * a) * self.rng.normal(
            0.0, p.gust_sigma_mps, 3) * np.array([1, 1, 0.4])
        gust = self.vel_gust.copy()
        for _, v in self.fs.get("gust", t):
            gust = gust + v
        if self.scn.autopilot.wind_mps > 0:
            gust[:2] += self._wind_push(dt)
        return gust

    def _move(self, out: Output, t: float, has_ts: bool, ts: tuple[float, float, float] | None,
              xy: np.ndarray | None = None) -> None:
        """``xy``: the autopilot's own horizontal target (precision landing) instead of the
        setpoint's."""
        p = self.p
        dt = p.dt
        gust = self._drift_and_gusts(t, has_ts, ts)
        if out.motors and out.setpoint is not None:
            sp = np.array(out.setpoint.position, float)
            if xy is not None:
                sp[:2] = xy
            est = self.pos + self.est_err
            v = (sp - est) / p.settle_tau_s
            vh = float(np.hypot(v[0], v[1]))
            if vh > p.vmax_xy:
                v[:2] *= p.vmax_xy / vh
            v[2] = float(np.clip(v[2], -p.vmax_z, p.vmax_z))
            self.pos = self.pos + (v + gust) * dt
            yaw_est = self.yaw + self.bias
            dyaw = wrap_pi(out.setpoint.yaw - yaw_est) / 0.3
            rate = math.radians(p.yaw_rate_deg)
            noise = self.rng.normal(0.0, math.radians(p.yaw_noise_deg)) * math.sqrt(dt)
            self.yaw = wrap_pi(self.yaw + float(np.clip(dyaw, -rate, rate)) * dt + noise)
        self.pos[2] = max(self.pos[2], self.world.floor(self.pos, self.yaw))

    def _wind_push(self, dt: float) -> np.ndarray:
        """The drift velocity (m/s) the wind's gusts leave: the steady wind's drag is held by
        the autopilot (as in :mod:`drovisio.autopilot.precland`, whose constants these are);
        the gusts' extra drag accelerates the drone until its position loop
        (``settle_tau_s``) takes it back."""
        lp = LandingParams()
        w = float(np.hypot(*self.wind))
        a = math.exp(-dt / lp.gust_tau_s)
        self.air_gust = a * self.air_gust + math.sqrt(1 - a * a) * self.ap_rng.normal(
            0.0, lp.gust_ratio * w, 2)
        air = self.wind + self.air_gust
        acc = lp.drag_per_m * (air * float(np.hypot(*air)) - self.wind * w)
        self.v_wind = self.v_wind + (acc - self.v_wind / self.p.settle_tau_s) * dt
        return self.v_wind

    # ------------------------------------------------------------------ run
    def _feed_autopilot(self, t: float, state: str, brick: str | None,
                        vis: tuple[Sighting, ...] | None) -> None:
        cam = site_from_body(self.pos, self.yaw) @ self.mount[:, 3]
        self.landings.feed(t, state, brick, vis, self.pos + self.est_err, self.yaw + self.bias,
                           cam[2], self.world.bricks)

    def _tick(self, t: float) -> tuple[Tick, Output, tuple[float, float, float] | None]:
        """Sensors, the machine's step and what it commands (the picker), at time ``t``."""
        state = self.machine.state.value
        brick = self._brick()
        self.fs.on_time(t, self.rng)
        ts = self._ts_reading(t)
        vis = self._vision(t, state, brick)
        yaw_est = wrap_pi(self.yaw + self.bias + self.rng.normal(0.0, math.radians(0.05)))
        nav = self.pos + self.est_err
        readings = Readings(t=t, ts_position=ts,
                            nav_position=(float(nav[0]), float(nav[1]), float(nav[2])),
                            nav_yaw=yaw_est, vision=vis, holding=self.world.held is not None)
        if self.precland:
            self._feed_autopilot(t, state, brick, vis)
        out = self.machine.step(readings)
        self.landings.record(t, state, out.state.value, self._brick(), self.pos,
                             self.world.bricks)
        if out.state.value != state:
            self.fs.on_state(t, out.state.value, self._brick(), self.rng)
        self._picker(out.picker, self._brick())
        tick = Tick(
            t=t, state=out.state.value, position=(float(self.pos[0]), float(self.pos[1]),
                                                  float(self.pos[2])),
            yaw=float(self.yaw), setpoint=out.setpoint.to_json() if out.setpoint else None,
            picker=out.picker, holding=self.world.held,
            events=[e.to_json() for e in out.events], telemetry=out.telemetry, ts=ts,
            vision=None if vis is None else [f"{s.layout}#{s.instance}" for s in vis],
            bricks=self.world.poses(self.pos, self.yaw))
        return tick, out, ts

    def _report(self, tick: Tick) -> None:
        if self.progress is None:
            return
        for e in tick.events:
            if e["kind"] in _PROGRESS_EVENTS:
                self.progress(f"t={tick.t:7.1f} s  {e}")

    def run(self) -> Trace:
        p, scn = self.p, self.scn
        ticks: list[Tick] = []
        n_max = int(p.max_time_s / p.dt)
        for k in range(n_max):
            t = round(k * p.dt, 6)
            tick, out, ts = self._tick(t)
            ticks.append(tick)
            self._report(tick)
            if out.state in TERMINAL_STATES:
                break
            xy = self.landings.target_xy() if self.precland and out.state.value in PICK_DESCENT \
                else None
            self._move(out, t, ts is not None, ts, xy)
        final = ticks[-1].state if ticks else State.IDLE.value
        render = self.render
        return Trace(scn, p, ticks, self.faults, final,
                     self.world.placements(set(self.machine.memory.placed)),
                     self.world.poses(self.pos, self.yaw), self.vision_frames,
                     render.seconds if render else 0.0,
                     ", ".join(render.detector_names) if render else "model",
                     render.frames if render else 0, self.landings.landings)

    def _brick(self) -> str | None:
        i = self.machine.memory.brick_index
        order = self.machine.plan.order
        return order[i] if i < len(order) else None


def simulate(scenario: Scenario, faults: Iterable[Fault] = (), params: SimParams | None = None,
             progress: Callable[[str], None] | None = None) -> Trace:
    """Run one simulated mission; see :class:`Simulator`."""
    return Simulator(scenario, tuple(faults), params, progress).run()
