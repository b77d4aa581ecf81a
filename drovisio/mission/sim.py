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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from drovisio.autopilot.precland import PrecLandEstimator
from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.mission.faults import Fault
from drovisio.mission.frames import (
    site_from_body,
    site_from_brick,
    wrap_half,
    wrap_pi,
    yaw_of,
)
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
from drovisio.mission.vision import (
    DetectorModel,
    DetectorModelParams,
    RenderVision,
    WorldBrick,
)

__all__ = ["SimParams", "Tick", "Trace", "Simulator", "simulate", "camera_for",
           "body_from_camera_for", "landing_blind_heights"]


@dataclass
class SimParams:
    dt: float = 0.05
    seed: int = 0
    max_time_s: float = 1800.0
    # drone
    settle_tau_s: float = 0.5
    vmax_xy: float = 1.0
    vmax_z: float = 0.5
    yaw_rate_deg: float = 60.0
    gust_sigma_mps: float = 0.02
    gust_tau_s: float = 1.5
    yaw_noise_deg: float = 0.1
    heading_bias_deg: float = 1.0
    drift_m_per_sqrt_s: float = 0.03
    # total station
    ts_rate_hz: float = 10.0
    ts_sigma_m: float = 0.003
    ts_dropout_prob: float = 0.01
    ts_position: tuple[float, float, float] = (0.0, -1.0, 1.5)
    # picker
    capture_radius_m: float = 0.03
    capture_yaw_deg: float = 6.0
    contact_tol_m: float = 0.03
    # pick area
    pick_sigma_m: float = 0.02
    pick_yaw_sigma_deg: float = 3.0
    # vision
    vision: str = "model"
    vision_params: DetectorModelParams = field(default_factory=DetectorModelParams)
    render_rate_hz: float = 4.0
    render_ss: int = 2
    render_bricks: tuple[str, ...] | None = None
    """Render only while working on these bricks (others use the model); None = all."""


@dataclass
class Tick:
    t: float
    state: str
    position: tuple[float, float, float]
    yaw: float
    setpoint: dict | None
    picker: str
    holding: str | None
    events: list[dict]
    telemetry: dict
    ts: tuple[float, float, float] | None
    vision: list[str] | None
    bricks: dict[str, tuple[float, float, float, float]]
    """Brick id → (x, y, z, yaw) of its top-face centre, site frame (truth)."""


@dataclass
class Trace:
    scenario: Scenario
    params: SimParams
    ticks: list[Tick]
    faults: tuple[Fault, ...]
    final_state: str
    placements: dict[str, dict]
    """Brick id → {error_m, error_xy_m, error_z_m, yaw_error_deg} against the plan (truth)."""
    truth_final: dict[str, tuple[float, float, float, float]]
    vision_frames: int = 0
    render_seconds: float = 0.0
    detector: str = "model"
    render_frames: int = 0
    landings: list[dict] = field(default_factory=list)
    """One per pick descent (``DESCEND_BRICK`` to what followed): ``brick``, ``outcome`` (the
    state it led to), ``error_m`` (truth: body origin to the brick's centre, horizontal, when
    the descent ended), and with precision landing ``initialised`` (the filter was
    initialised at some tick of this descent), ``init_failures`` and ``measurements`` (since
    the brick was first looked for), ``last_seen_camera_height_m`` (camera above the brick's top at the last
    LANDING_TARGET sent), ``blind_height_m`` (where the brick leaves the picture, this lens
    and mount), ``estimate_error_m`` (the estimate flown to, against the truth)."""

    @property
    def completed(self) -> bool:
        return self.final_state == State.DONE.value

    @property
    def safe(self) -> bool:
        return self.final_state == State.SHUTDOWN.value

    def events(self, kind: str | None = None) -> list[dict]:
        return [e for tk in self.ticks for e in tk.events if kind is None or e["kind"] == kind]

    def placement_errors(self) -> tuple[np.ndarray, np.ndarray]:
        pos = np.array([p["error_m"] for p in self.placements.values()])
        yaw = np.array([p["yaw_error_deg"] for p in self.placements.values()])
        return pos, yaw


def camera_for(scn: Scenario) -> Camera:
    spec = scn.drone.camera
    if spec.file:
        from pathlib import Path

        p = Path(spec.file)
        if not p.is_absolute() and scn.source is not None:
            p = scn.source.parent / p
        return load_camera(p)
    return Camera.drone_webcam()


def body_from_camera_for(scn: Scenario) -> np.ndarray:
    """The mount: camera looking down (image top toward the drone's front), tilted forward by
    ``tilt_deg``, at ``offset_m`` in the FRD body frame (as :mod:`drovisio.synth_samples`)."""
    import cv2

    m = scn.drone.camera.mount
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    tilt = cv2.Rodrigues(np.array([0.0, math.radians(m.tilt_deg), 0.0]))[0]
    T = np.eye(4)
    T[:3, :3] = tilt @ R
    T[:3, 3] = m.offset_m
    return T


_NED_FROM_SITE = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""The site is x east, y north, z up; ArduPilot's local frame is north, east, down."""
_PICK_FEED = (State.ACQUIRE_BRICK.value, State.ALIGN_BRICK.value, State.DESCEND_BRICK.value,
              State.BLIND_DESCENT_BRICK.value)
_PICK_DESCENT = (State.DESCEND_BRICK.value, State.BLIND_DESCENT_BRICK.value)


def landing_blind_heights(scn: Scenario, camera: Camera | None = None,
                          body_from_camera: np.ndarray | None = None) -> dict[str, float | None]:
    """Per layout, the camera height above a brick at which it leaves the picture on the way
    down (None: seen all the way), with the scenario's lens and mount
    (:func:`drovisio.autopilot.blind.blind_height`).

    Raises:
        ScenarioError: with ``autopilot.precision_landing``, a brick the descent cannot see:
            never in the picture right below the drone, or gone above the approach height.
    """
    from drovisio.autopilot.blind import blind_height
    from drovisio.mission.scenario import ScenarioError
    from drovisio.mount import Mount

    camera = camera if camera is not None else camera_for(scn)
    mount = Mount(body_from_camera if body_from_camera is not None else body_from_camera_for(scn))
    out: dict[str, float | None] = {}
    never = False
    for name in scn.layouts:
        bh = blind_height(camera, mount, scn.layout(name))
        out[name] = bh.leaves_at_m
        never |= bh.highest_seen_m is None
    if not scn.autopilot.precision_landing:
        return out
    where = f"{scn.source}: " if scn.source is not None else ""
    if never:
        raise ScenarioError(
            f"{where}drone.camera.mount.tilt_deg: with this lens and mount the brick right "
            "below the drone is never in the picture: with autopilot.precision_landing the "
            "drone would never see it to land on; tilt the camera less")
    highest = max((b for b in out.values() if b is not None), default=0.0)
    down = scn.drone.camera.mount.offset_m[2]
    approach_cam = scn.altitudes.approach_m - down
    if highest >= approach_cam - 0.05:
        raise ScenarioError(
            f"{where}altitudes.approach_m: with this lens and mount the brick below leaves the "
            f"picture {highest:.2f} m above it (camera height), above the approach "
            f"({approach_cam:.2f} m): with autopilot.precision_landing the drone would never "
            f"see it to land on; raise approach_m above {highest + down + 0.1:.2f} m (and "
            "cruise_m with it) or tilt the camera less")
    return out


class _FaultState:
    def __init__(self, faults: tuple[Fault, ...]):
        self.faults = faults
        self.active: list[tuple[Fault, float, float, np.ndarray | None]] = []
        self.entries: dict[tuple[str, str | None], int] = {}
        self.fired: set[int] = set()
        self.grab_fail: dict[str | None, int] = {}
        self.release_fail: dict[str | None, int] = {}
        for f in faults:
            if f.kind == "grab_fail":
                self.grab_fail[f.brick] = self.grab_fail.get(f.brick, 0) + f.count
            elif f.kind == "release_fail":
                self.release_fail[f.brick] = self.release_fail.get(f.brick, 0) + f.count

    def on_state(self, t: float, state: str, brick: str | None, rng: np.random.Generator):
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

    def on_time(self, t: float, rng: np.random.Generator):
        for i, f in enumerate(self.faults):
            if i in self.fired or f.kind in ("grab_fail", "release_fail") or f.state is not None:
                continue
            if t >= (f.at_s or 0.0):
                self._start(i, f, max(t, f.at_s or 0.0), rng)

    def _start(self, i: int, f: Fault, t0: float, rng: np.random.Generator):
        self.fired.add(i)
        a = rng.uniform(0, 2 * math.pi)
        vec = np.array([math.cos(a), math.sin(a), 0.0]) * f.magnitude
        self.active.append((f, t0, t0 + f.duration_s, vec))

    def get(self, kind: str, t: float) -> list[tuple[Fault, np.ndarray]]:
        return [(f, v) for f, a, b, v in self.active if f.kind == kind and a <= t < b]

    def take(self, table: dict, brick: str | None) -> bool:
        for key in (brick, None):
            if table.get(key, 0) > 0:
                table[key] -= 1
                return True
        return False


def _segment_hits_box(p0, p1, box, height: float) -> bool:
    xmin, ymin, xmax, ymax = box
    for s in np.linspace(0.0, 1.0, 25):
        q = p0 + s * (p1 - p0)
        if xmin <= q[0] <= xmax and ymin <= q[1] <= ymax and q[2] <= height:
            return True
    return False


class Simulator:
    """One simulated mission (see the module docstring)."""

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
        self.latency_s = ap.latency_ms / 1e3
        self.plnd_lag_s = (ap.latency_ms if ap.plnd_lag_ms is None else ap.plnd_lag_ms) / 1e3
        self.blind_m: dict[str, float | None] = {}
        machine_scn = scenario
        if self.precland:
            self.blind_m = landing_blind_heights(scenario, self.camera, self.mount)
            highest = max((b for b in self.blind_m.values() if b is not None), default=0.0)
            alt = scenario.altitudes
            if highest + 0.02 > alt.blind_below_m:
                # vision is lost above the scenario's blind height: the descent goes blind there
                machine_scn = scenario.model_copy(update={"altitudes": alt.model_copy(
                    update={"blind_below_m": highest + 0.02})})
        self.machine = Machine(machine_scn)
        self.estimator: PrecLandEstimator | None = None
        self.estimator_brick: str | None = None
        self.last_sent_h: float | None = None
        self.landing: dict | None = None
        self.landings: list[dict] = []
        self.wind = np.zeros(2)
        if ap.wind_mps > 0:
            a = self.ap_rng.uniform(0.0, 2 * math.pi)
            self.wind = np.array([math.cos(a), math.sin(a)]) * ap.wind_mps
        self.air_gust = np.zeros(2)
        self.v_wind = np.zeros(2)
        self.render = None
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
        self.bricks: dict[str, np.ndarray] = {}
        for b in scenario.bricks:
            pp = scenario.pick_pose(b.id)
            dxy = np.clip(self.rng.normal(0.0, self.p.pick_sigma_m, 2), -2 * self.p.pick_sigma_m,
                          2 * self.p.pick_sigma_m)
            dyaw = math.radians(float(np.clip(self.rng.normal(0.0, self.p.pick_yaw_sigma_deg),
                                              -2 * self.p.pick_yaw_sigma_deg,
                                              2 * self.p.pick_yaw_sigma_deg)))
            self.bricks[b.id] = site_from_brick((pp.x + dxy[0], pp.y + dxy[1], pp.z),
                                                pp.yaw + dyaw)
        self._inv: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.held: str | None = None
        self.held_T: np.ndarray | None = None
        self.picker = "open"
        self.fs = _FaultState(self.faults)
        self.last_state: str | None = None
        self.vision_frames = 0

    # ------------------------------------------------------------------ geometry helpers
    def _dims(self, bid: str) -> np.ndarray:
        return np.asarray(self.scn.layout_of(bid).dimensions_m, float)

    def _world_bricks(self) -> list[WorldBrick]:
        return [WorldBrick(bid, self.scn.layout_of(bid), self.scn.brick_by_id[bid].instance, T)
                for bid, T in self.bricks.items() if bid != self.held]

    def _inverse(self, bid: str) -> np.ndarray:
        T = self.bricks[bid]
        cached = self._inv.get(bid)
        if cached is None or cached[0] is not T:
            cached = (T, np.linalg.inv(T))
            self._inv[bid] = cached
        return cached[1]

    def _under(self, xy, exclude: str | None = None) -> list[str]:
        out = []
        for bid in self.bricks:
            if bid in (exclude, self.held):
                continue
            d = self._dims(bid)
            inv = self._inverse(bid)
            q = inv[:2, :2] @ np.asarray(xy) + inv[:2, 3]
            if abs(q[0]) <= d[0] / 2 and abs(q[1]) <= d[1] / 2:
                out.append(bid)
        return out

    def _floor(self) -> float:
        """Lowest body height here: landing gear on the ground, picker on a brick, or the held
        brick resting on what is below it."""
        scn = self.scn
        depth = scn.drone.picker_depth_m
        if self.held is None:
            z = scn.drone.gear_height_m
            for bid in self._under(self.pos[:2]):
                z = max(z, self.bricks[bid][2, 3] + depth - 0.005)
            return z
        T = site_from_body(self.pos, self.yaw) @ self.held_T
        h = scn.wall.course_height_m
        z = depth + h  # held brick on the ground
        top_off = self.pos[2] - T[2, 3]
        support = self._support_top(T)
        if support is not None:
            z = max(z, support + h + top_off)
        return max(z, depth + self._dims(self.held)[2] - 0.02)

    def _support_top(self, T: np.ndarray) -> float | None:
        tops = []
        for sx in (-0.075, 0.075):
            pt = T[:2, :2] @ np.array([sx, 0.0]) + T[:2, 3]
            for bid in self._under(pt, exclude=self.held):
                tops.append(self.bricks[bid][2, 3])
        return max(tops) if tops else None

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
            if f.box and _segment_hits_box(np.asarray(p.ts_position), self.pos, f.box,
                                           f.magnitude):
                return None
        r = self.pos + self.rng.normal(0.0, p.ts_sigma_m, 3)
        for _, v in self.fs.get("ts_offset", t):
            r = r + v
        return tuple(float(x) for x in r)

    def _vision(self, t: float, state: str, brick: str | None) -> tuple[Sighting, ...] | None:
        p = self.p
        k = int(round(t / p.dt))
        use_render = self.render is not None and state in {s.value for s in VISION_STATES} and (
            p.render_bricks is None or brick in p.render_bricks)
        rate = p.render_rate_hz if use_render else self.vision_params.rate_hz
        if self.scn.autopilot.rate_hz is not None and not use_render:
            # a rate the tick does not divide: frames on the ticks nearest to it
            if t + 1e-9 < self._next_frame:
                return None
            self._next_frame += 1.0 / rate
        else:
            every = max(1, int(round(1.0 / (rate * p.dt))))
            if k % every:
                return None
        self.vision_frames += 1
        if self.fs.get("vision_loss", t):
            return ()
        wfb = site_from_body(self.pos, self.yaw)
        wfc = wfb @ self.mount
        source = self.render if use_render else self.model
        seen = source.observe(wfc, self._world_bricks(), self.rng)
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

    # ------------------------------------------------------------------ precision landing
    def _target_vector(self, vis, brick: str) -> np.ndarray | None:
        """The current brick's centre in the body frame (FRD, m) in this frame's sightings:
        what Drovisio sends as its ``LANDING_TARGET``."""
        b = self.scn.brick_by_id[brick]
        has_ids = self.scn.layout_of(brick).has_codes
        best: np.ndarray | None = None
        for sgt in vis:
            if sgt.layout != b.layout or (has_ids and sgt.instance != b.instance):
                continue
            v = np.asarray(sgt.body_from_brick, float)[:3, 3]
            if best is None or math.hypot(v[0], v[1]) < math.hypot(best[0], best[1]):
                best = v   # without ids: the one nearest below the drone
        return best

    def _precland_tick(self, t: float, state: str, brick: str | None, vis) -> None:
        """The autopilot's side of one tick: its state into the lag buffer, the target seen in
        this frame sent, the filter updated."""
        if state in _PICK_FEED and brick is not None and (
                self.estimator is None or self.estimator_brick != brick):
            self.estimator = PrecLandEstimator(self.plnd_lag_s, self.p.dt)
            self.estimator_brick = brick
            self.last_sent_h = None
        est = self.estimator
        if est is None:
            return
        nav = self.pos + self.est_err
        yaw_est = self.yaw + self.bias   # the autopilot rotates by its own heading
        est.record(np.array([nav[1], nav[0]]),
                   _NED_FROM_SITE @ site_from_body(nav, yaw_est)[:3, :3])
        if vis and state in _PICK_FEED and brick == self.estimator_brick:
            v = self._target_vector(vis, brick)
            if v is not None:
                # on the simulator's clock (rounded like its ticks): a message due at a tick
                # is taken at that tick, paired with the state PLND_LAG before it
                est.send(round(t + self.latency_s, 6), v)
                cam = site_from_body(self.pos, self.yaw) @ self.mount[:, 3]
                self.last_sent_h = float(cam[2] - self.bricks[brick][2, 3])
        est.update(t)

    def _precland_xy(self) -> np.ndarray | None:
        """Where the autopilot flies in a pick descent: the estimate, else the last one."""
        est = self.estimator
        if est is None:
            return None
        e = est.estimate if est.estimate is not None else est.last_estimate
        return None if e is None else np.array([e[1], e[0]])

    def _landing_record(self, t: float, before: str, after: str) -> None:
        """Open a record when a pick descent starts, close it when it ends."""
        brick = self._brick()
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
        if after in _PICK_DESCENT:
            return
        b = self.landing["brick"]
        T = self.bricks[b]
        rec = dict(self.landing, t_end=round(t, 3), outcome=after,
                   error_m=round(math.dist(self.pos[:2], T[:2, 3]), 4))
        est = self.estimator
        if self.precland and est is not None and self.estimator_brick == b:
            xy = self._precland_xy()
            rec.update(initialised=bool(self.landing.get("initialised")),
                       init_failures=est.init_fail,
                       measurements=est.n_meas,
                       last_seen_camera_height_m=None if self.last_sent_h is None
                       else round(self.last_sent_h, 3),
                       blind_height_m=self.blind_m.get(self.scn.brick_by_id[b].layout),
                       estimate_error_m=None if xy is None
                       else round(math.dist(xy, T[:2, 3]), 4))
        elif self.precland:
            rec.update(initialised=False, init_failures=0, measurements=0,
                       last_seen_camera_height_m=None,
                       blind_height_m=self.blind_m.get(self.scn.brick_by_id[b].layout),
                       estimate_error_m=None)
        self.landings.append(rec)
        self.landing = None

    # ------------------------------------------------------------------ picker
    def _picker(self, cmd: str, t: float, brick: str | None) -> None:
        p, scn = self.p, self.scn
        if cmd == self.picker:
            return
        self.picker = cmd
        if cmd == "closed" and self.held is None:
            if self.fs.take(self.fs.grab_fail, brick):
                return
            for bid, T in self.bricks.items():
                d = math.dist(T[:2, 3], self.pos[:2])
                dz = abs(self.pos[2] - (T[2, 3] + scn.drone.picker_depth_m))
                dyaw = abs(wrap_half(yaw_of(T) - self.yaw))
                covered = any(self.bricks[o][2, 3] > T[2, 3] + 0.01 for o in self._under(T[:2, 3],
                                                                                       exclude=bid))
                if (d <= p.capture_radius_m and dz <= p.contact_tol_m
                        and dyaw <= math.radians(p.capture_yaw_deg) and not covered):
                    self.held = bid
                    self.held_T = np.linalg.inv(site_from_body(self.pos, self.yaw)) @ T
                    return
        elif cmd == "open" and self.held is not None:
            if self.fs.take(self.fs.release_fail, brick):
                return  # jammed: the brick stays in the picker, the sensor reads "holding"
            T = site_from_body(self.pos, self.yaw) @ self.held_T
            support = self._support_top(T)
            h = self.scn.wall.course_height_m
            z = (support + h) if support is not None else h
            self.bricks[self.held] = site_from_brick((T[0, 3], T[1, 3], z), yaw_of(T))
            self.held, self.held_T = None, None

    # ------------------------------------------------------------------ dynamics
    def _move(self, out: Output, t: float, has_ts: bool, ts,
              xy: np.ndarray | None = None) -> None:
        """``xy``: the autopilot's own horizontal target (precision landing) instead of the
        setpoint's."""
        p = self.p
        dt = p.dt
        # autopilot estimate error: the total station resets it, else it drifts
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
            self.yaw = wrap_pi(self.yaw + float(np.clip(dyaw, -rate, rate)) * dt
                               + self.rng.normal(0.0, math.radians(p.yaw_noise_deg)) * math.sqrt(dt))
        self.pos[2] = max(self.pos[2], self._floor())

    def _wind_push(self, dt: float) -> np.ndarray:
        """The drift velocity (m/s) the wind's gusts leave: the steady wind's drag is held by
        the autopilot (as in :mod:`drovisio.autopilot.precland`, whose constants these are);
        the gusts' extra drag accelerates the drone until its position loop
        (``settle_tau_s``) takes it back."""
        from drovisio.autopilot.precland import LandingParams

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
    def run(self) -> Trace:
        p, scn = self.p, self.scn
        ticks: list[Tick] = []
        n_max = int(p.max_time_s / p.dt)
        for k in range(n_max):
            t = round(k * p.dt, 6)
            state = self.machine.state.value
            brick = self._brick()
            self.fs.on_time(t, self.rng)
            ts = self._ts_reading(t)
            vis = self._vision(t, state, brick)
            yaw_est = wrap_pi(self.yaw + self.bias + self.rng.normal(0.0, math.radians(0.05)))
            readings = Readings(t=t, ts_position=ts, nav_position=tuple(self.pos + self.est_err),
                                nav_yaw=yaw_est, vision=vis, holding=self.held is not None)
            if self.precland:
                self._precland_tick(t, state, brick, vis)
            out = self.machine.step(readings)
            self._landing_record(t, state, out.state.value)
            if out.state.value != state:
                self.fs.on_state(t, out.state.value, self._brick(), self.rng)
            self._picker(out.picker, t, self._brick())
            ticks.append(Tick(
                t=t, state=out.state.value, position=tuple(float(v) for v in self.pos),
                yaw=float(self.yaw), setpoint=out.setpoint.to_json() if out.setpoint else None,
                picker=out.picker, holding=self.held, events=[e.to_json() for e in out.events],
                telemetry=out.telemetry, ts=ts,
                vision=None if vis is None else [f"{s.layout}#{s.instance}" for s in vis],
                bricks=self._brick_poses()))
            if self.progress and any(e["kind"] in ("placed", "safe_zone", "phase_failed")
                                     for e in ticks[-1].events):
                for e in ticks[-1].events:
                    if e["kind"] in ("placed", "safe_zone", "phase_failed"):
                        self.progress(f"t={t:7.1f} s  {e}")
            if out.state in TERMINAL_STATES:
                break
            xy = self._precland_xy() if self.precland and out.state.value in _PICK_DESCENT \
                else None
            self._move(out, t, ts is not None, ts, xy)
        final = ticks[-1].state if ticks else State.IDLE.value
        return Trace(scn, p, ticks, self.faults, final, self._placements(),
                     self._brick_poses(), self.vision_frames,
                     self.render.seconds if self.render else 0.0,
                     ", ".join(self.render.detector_names) if self.render else "model",
                     self.render.frames if self.render else 0, self.landings)

    def _brick(self) -> str | None:
        i = self.machine.memory.brick_index
        order = self.machine.plan.order
        return order[i] if i < len(order) else None

    def _brick_poses(self) -> dict[str, tuple[float, float, float, float]]:
        out = {}
        for bid, T in self.bricks.items():
            if bid == self.held:
                T = site_from_body(self.pos, self.yaw) @ self.held_T
            out[bid] = (float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), yaw_of(T))
        return out

    def _placements(self) -> dict[str, dict]:
        out = {}
        placed = set(self.machine.memory.placed)
        for bid in self.scn.order:
            if bid == self.held:
                continue
            T = self.bricks[bid]
            plan = self.scn.slot_pose(bid)
            moved = math.dist(T[:2, 3], self.scn.pick_pose(bid).xy) > 0.5
            if bid not in placed and not moved:
                continue
            exy = math.dist(T[:2, 3], (plan.x, plan.y))
            ez = float(T[2, 3] - plan.z)
            out[bid] = {"error_m": round(exy, 5), "error_z_m": round(ez, 5),
                        "error_along_m": round(float(np.dot(T[:2, 3] - plan.xy,
                                                            [math.cos(plan.yaw),
                                                             math.sin(plan.yaw)])), 5),
                        "yaw_error_deg": round(math.degrees(abs(wrap_half(yaw_of(T) - plan.yaw))),
                                               4),
                        "verified": bid in placed}
        return out


def simulate(scenario: Scenario, faults=(), params: SimParams | None = None,
             progress: Callable[[str], None] | None = None) -> Trace:
    """Run one simulated mission; see :class:`Simulator`."""
    return Simulator(scenario, tuple(faults), params, progress).run()
