"""A model of ArduPilot's precision landing fed by Drovisio, to see landing errors before flying.

What it reproduces of ArduPilot's ``AC_PrecLand`` (Kalman-filter estimator, ``PLND_EST_TYPE``
1) where it decides where the drone lands:

* **Lag buffer** (``PLND_LAG``): a ``LANDING_TARGET`` is paired with the attitude and the
  vehicle position of ``PLND_LAG`` seconds before it *arrived* (ArduPilot ignores
  ``time_usec``); a lag that differs from the real capture-to-send latency pairs it with the
  wrong attitude and position.
* **Initialisation**: the first measurement starts the filter; it is used only once updates
  kept coming at most 0.5 s apart for 2 s ("Init Complete"); a longer gap meanwhile is
  "Init Failed" and the next measurement starts again.
* **Target timeout**: 2 s without an update drops the target; the filter must initialise
  again.
* **Filter**: per horizontal axis a position/velocity Kalman filter, measurement standard
  deviation ``0.01·height + 0.02`` m (ArduPilot's), process noise ``PLND_ACC_P_NSE``, the
  normalised-innovation gate of 3 (three rejections in a row force the fourth in).
* **Descent** (LAND mode): ``LAND_SPEED`` down; the horizontal setpoint is the estimate while
  the target is acquired, the **last estimate** once it is lost (the drone lands on it); a
  target never acquired leaves the drone landing where it is.

The world: the brick's origin at the NED origin (its top face at height 0, x north), the
drone above it, heading north, level but for the tilt its position controller commands; wind
is a steady drag toward the wind's direction with Ornstein–Uhlenbeck gusts; the vehicle's own
position estimate (GPS) wanders slowly. The camera sees the brick when one of its codes is
wholly in the picture (the camera file's lens, the mount, the attitude), at ``rate_hz`` with
``detect_prob``, with a Gaussian position error growing with range, and its message reaches
the autopilot ``latency_s`` after the capture.

All lengths in metres, times in seconds, angles in radians unless named ``_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from drovisio.autopilot.blind import blind_height
from drovisio.autopilot.check import REQUIRED_RATE_HZ
from drovisio.camera import Camera
from drovisio.layout import MarkerLayout
from drovisio.mount import BODY_FROM_ALIGNED_BRICK, Mount

__all__ = ["LandingParams", "LandingResult", "PrecLandEstimator", "landing_report",
           "landing_summary", "simulate_landing"]

G = 9.80665
INIT_TIME_S = 2.0
INIT_MAX_GAP_S = 0.5
TARGET_TIMEOUT_S = 2.0
MODEL_DT_S = 0.01
"""The step the filter's process noise ``PLND_ACC_P_NSE`` is applied at (the step of
:func:`simulate_landing`, whose figures match the autopilot's); a coarser tick adds the same
velocity variance per second."""


@dataclass
class LandingParams:
    # the pipeline
    rate_hz: float = 15.0
    """Frames a second the pipeline processes (a detection chance each)."""
    detect_prob: float = 0.95
    latency_s: float = 0.05
    """Capture to LANDING_TARGET arriving at the autopilot."""
    noise_m: float = 0.002
    noise_per_m: float = 0.004
    """Measurement error: ``noise_m + noise_per_m · range`` per axis (standard deviation)."""
    # the autopilot
    plnd_lag_s: float | None = None
    """PLND_LAG; None: equal to ``latency_s`` (set as ``drovisio autopilot check`` says)."""
    acc_noise: float = 2.5
    """PLND_ACC_P_NSE, m/s²."""
    land_speed: float = 0.5
    """LAND_SPEED, m/s."""
    pos_p: float = 1.0
    """PSC_POSXY_P."""
    vel_p: float = 2.0
    """PSC_VELXY_P."""
    vel_i: float = 1.0
    """PSC_VELXY_I: it takes up the wind."""
    max_speed: float = 1.0
    max_tilt_deg: float = 30.0
    # the world
    start_height_m: float = 5.0
    """Body origin above the brick's top face at the start of LAND."""
    start_offset_m: float = 0.1
    """Horizontal distance from the brick at the start (random direction)."""
    touchdown_height_m: float = 0.15
    """Body origin above the brick's top face when the gear touches."""
    wind_mps: float = 3.0
    gust_ratio: float = 0.05
    """Gust standard deviation as a share of the wind speed."""
    gust_tau_s: float = 2.0
    drag_per_m: float = 0.04
    """Drag acceleration per (m/s)² of air speed."""
    nav_sigma_m: float = 0.01
    nav_tau_s: float = 5.0
    dt: float = 0.01
    seed: int = 0


@dataclass
class LandingResult:
    error_m: float
    """Horizontal distance body origin → brick origin at touchdown."""
    initialised: bool
    """The filter completed its initialisation at least once."""
    init_time_s: float | None
    blind_camera_height_m: float | None
    """Camera height above the brick at the last detection (None: never seen)."""
    measurements: int
    init_failures: int
    last_estimate_error_m: float | None
    """Error of the estimate the drone landed on, at the moment the target was lost."""
    last_update_s: float | None = None
    """When the filter last took a measurement (s from the start of LAND)."""
    estimate_rms_m: float | None = None
    """RMS horizontal error of the target estimate while acquired."""
    events: list[tuple[float, str]] = field(default_factory=list)


class _PosVelKF:
    """One axis: position and velocity of the target (NE, nav frame)."""

    def __init__(self, pos: float, pos_var: float, vel: float, vel_var: float):
        self.x = np.array([pos, vel])
        self.P = np.diag([pos_var, vel_var])

    def predict(self, dt: float, dvel_noise: float) -> None:
        F = np.array([[1.0, dt], [0.0, 1.0]])
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + np.diag([0.0, dvel_noise ** 2])

    def nis(self, z: float, r: float) -> float:
        return (z - self.x[0]) ** 2 / (self.P[0, 0] + r)

    def fuse(self, z: float, r: float) -> None:
        s = self.P[0, 0] + r
        k = self.P[:, 0] / s
        self.x = self.x + k * (z - self.x[0])
        self.P = self.P - np.outer(k, self.P[0, :])


def _ned_from_body(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def _code_groups(layout: MarkerLayout) -> list[np.ndarray]:
    codes = [BODY_FROM_ALIGNED_BRICK @ m.corners_array().T for m in layout.markers
             if m.kind == "aruco"]
    if not codes:
        codes = [BODY_FROM_ALIGNED_BRICK @ np.array([m.center_array() for m in layout.markers]).T]
    return codes   # brick points in a NED frame at the brick origin (brick x north)


class PrecLandEstimator:
    """ArduPilot's ``AC_PrecLand`` target estimator alone (see the module doc), on a fixed
    tick: the lag buffer, the initialisation, the target timeout and the per-axis filter.

    One tick: :meth:`record` the vehicle's state, :meth:`send` the messages captured this tick,
    then :meth:`update`. Frames: a local NED frame (its origin anywhere, its x north);
    ``R_ned_from_body`` the body's attitude; measurements are the target's position in the FRD
    body frame (metres), as a ``LANDING_TARGET`` carries them once the mount is applied. Used by
    :func:`simulate_landing` and by the mission simulator's autopilot.
    """

    def __init__(self, lag_s: float, dt: float, acc_noise: float = 2.5):
        self.dt = dt
        self.n_lag = max(0, int(round(lag_s / dt)))
        self.acc_noise = acc_noise
        self.history: list[tuple[np.ndarray, np.ndarray]] = []  # (nav NE, R_ned_from_body)
        self.in_flight: list[tuple[float, np.ndarray]] = []     # (arrival time, body vector)
        self.kf: list[_PosVelKF] | None = None
        self.initialised_at: float | None = None
        self.last_update = -math.inf
        self.init_start = 0.0
        self.acquired = self.ever_acquired = False
        self.rejects = 0
        self.n_meas = self.init_fail = 0
        self.last_fused: float | None = None
        self.last_estimate: np.ndarray | None = None
        """The estimate (NE) at the last tick the target was acquired: what the drone lands
        on once it is lost."""
        self.events: list[tuple[float, str]] = []

    def record(self, nav_ne: np.ndarray, R_ned_from_body: np.ndarray) -> None:
        """The vehicle's own position estimate (NE, m) and attitude this tick."""
        self.history.append((np.array(nav_ne[:2], float), R_ned_from_body))
        if len(self.history) > self.n_lag + 1:
            self.history.pop(0)

    def send(self, arrival_t: float, meas_body: np.ndarray) -> None:
        """A ``LANDING_TARGET`` arriving at ``arrival_t`` (s): the target in the body frame."""
        self.in_flight.append((arrival_t, np.asarray(meas_body, float)))

    @property
    def estimate(self) -> np.ndarray | None:
        """The target's NE position while acquired (None otherwise)."""
        if self.acquired and self.kf is not None:
            return np.array([self.kf[0].x[0], self.kf[1].x[0]])
        return None

    def update(self, t: float) -> None:
        """Predict, take the messages that arrived by ``t`` (s) paired with the state
        ``PLND_LAG`` old, then the initialisation and timeout rules."""
        dt = self.dt
        nav_lag, R_lag = self.history[0]
        if self.kf is not None:
            # the process noise per second does not depend on the tick: a tick of k model
            # steps adds k steps' velocity variance
            dvel = self.acc_noise * math.sqrt(dt * MODEL_DT_S)
            for f in self.kf:
                f.predict(dt, dvel)
        while self.in_flight and self.in_flight[0][0] <= t:
            _, meas = self.in_flight.pop(0)
            # the gap rules before the message is taken (ArduPilot checks them at 400 Hz: a
            # coarse tick must not let a late message hide the gap it ends)
            self._gap_rules(t)
            rel = R_lag @ meas
            z_ne = nav_lag + rel[:2]
            r = (max(rel[2], 0.0) * 0.01 + 0.02) ** 2
            self.n_meas += 1
            if self.kf is None:
                self.kf = [_PosVelKF(z_ne[i], r, 0.0, 4.0) for i in range(2)]
                self.init_start = self.last_update = self.last_fused = t
                self.events.append((t, "Target Found"))
                continue
            nis = max(self.kf[i].nis(z_ne[i], r) for i in range(2))
            if nis < 3.0 or self.rejects >= 3:
                self.rejects = 0
                for i in range(2):
                    self.kf[i].fuse(z_ne[i], r)
                self.last_update = self.last_fused = t
            else:
                self.rejects += 1
        self._gap_rules(t)
        est = self.estimate
        if est is not None:
            self.last_estimate = est

    def _gap_rules(self, t: float) -> None:
        """Initialisation (updates at most 0.5 s apart for 2 s) and the 2 s target timeout."""
        if self.kf is not None and not self.acquired:
            if t - self.last_update > INIT_MAX_GAP_S:
                self.kf = None
                self.init_fail += 1
                self.events.append((t, "Init Failed"))
            elif t - self.init_start > INIT_TIME_S:
                self.acquired = self.ever_acquired = True
                if self.initialised_at is None:
                    self.initialised_at = t
                self.events.append((t, "Init Complete"))
        if self.acquired and t - self.last_update > TARGET_TIMEOUT_S:
            self.acquired = False
            self.kf = None
            self.events.append((t, "Target Lost"))


def simulate_landing(camera: Camera, mount: Mount, layout: MarkerLayout,
                     params: LandingParams | None = None) -> LandingResult:
    """One LAND-mode descent onto the brick (see the module doc)."""
    p = params or LandingParams()
    rng = np.random.default_rng(p.seed)
    dt = p.dt
    lag = p.latency_s if p.plnd_lag_s is None else p.plnd_lag_s
    est = PrecLandEstimator(lag, dt, p.acc_noise)
    w, h = camera.size
    groups = _code_groups(layout)
    cam_from_body = mount.camera_from_body
    border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], np.float64)
    r_max = float(np.max(np.linalg.norm(camera.normalize(border), axis=1))) * 1.02

    a0 = rng.uniform(0, 2 * math.pi)
    pos = np.array([p.start_offset_m * math.cos(a0), p.start_offset_m * math.sin(a0),
                    -p.start_height_m])
    vel = np.zeros(3)
    wind_dir = rng.uniform(0, 2 * math.pi)
    wind = np.array([math.cos(wind_dir), math.sin(wind_dir), 0.0]) * p.wind_mps
    gust = np.zeros(3)
    nav_err = np.zeros(2)
    roll = pitch = 0.0
    vel_int = -p.drag_per_m * wind[:2] * np.linalg.norm(wind) / max(p.vel_i, 1e-9)
    # the drag of the steady wind is balanced from the start (the drone was hovering)
    next_frame = rng.uniform(0, 1.0 / p.rate_hz)
    setpoint = pos[:2].copy()
    last_seen_cam_h: float | None = None
    lost_estimate_err: float | None = None
    sq_err: list[float] = []
    t = 0.0
    while -pos[2] > p.touchdown_height_m and t < 120.0:
        R = _ned_from_body(roll, pitch, 0.0)
        nav = pos[:2] + nav_err
        est.record(nav, R)
        # the camera
        if t >= next_frame:
            next_frame += 1.0 / p.rate_hz
            body_from_ned = R.T
            best = None
            for g in groups:
                p_body = body_from_ned @ (g - pos[:, None])
                p_cam = cam_from_body[:3, :3] @ p_body + cam_from_body[:3, 3:4]
                z = p_cam[2]
                if np.any(z <= 1e-6):
                    continue
                if np.any(np.hypot(p_cam[0], p_cam[1]) / z > r_max):
                    continue
                px = camera.project(p_cam.T)
                if np.all((px[:, 0] >= 1) & (px[:, 0] <= w - 2) & (px[:, 1] >= 1)
                          & (px[:, 1] <= h - 2)):
                    best = p_body
                    break
            if best is not None and rng.random() < p.detect_prob:
                p_body_true = body_from_ned @ (-pos)          # brick origin in the body frame
                rng_m = float(np.linalg.norm(p_body_true))
                meas = p_body_true + rng.normal(0.0, p.noise_m + p.noise_per_m * rng_m, 3)
                est.send(t + p.latency_s, meas)
                cam_pos = pos + R @ mount.body_from_camera[:3, 3]
                last_seen_cam_h = float(-cam_pos[2])
        # the autopilot: a message that arrived is paired with the state PLND_LAG old
        est.update(t)
        e = est.estimate
        if e is not None:
            setpoint = e
            lost_estimate_err = float(np.hypot(*setpoint))
            sq_err.append(lost_estimate_err ** 2)
        # the position controller flies its nav estimate to the setpoint (last estimate when
        # lost, where it was when never acquired)
        v_des = p.pos_p * (setpoint - nav)
        sp = float(np.hypot(*v_des))
        if sp > p.max_speed:
            v_des *= p.max_speed / sp
        air = wind + gust - vel
        drag = p.drag_per_m * air * np.linalg.norm(air)
        # velocity loop: P + I (the integrator holds the steady wind, hovering at the start)
        e_v = v_des - vel[:2]
        vel_int = vel_int + e_v * dt
        a_cmd = p.vel_p * e_v + p.vel_i * vel_int
        tilt_max = math.tan(math.radians(p.max_tilt_deg)) * G
        n = float(np.hypot(*a_cmd))
        if n > tilt_max:
            a_cmd *= tilt_max / n
        # heading north: +north accel = nose down (negative pitch), +east accel = roll right
        pitch, roll = -math.atan2(a_cmd[0], G), math.atan2(a_cmd[1], G)
        acc = np.array([a_cmd[0] + drag[0], a_cmd[1] + drag[1], 0.0])
        vel[:2] += acc[:2] * dt
        vel[2] = p.land_speed
        pos = pos + vel * dt
        a = math.exp(-dt / p.gust_tau_s)
        gust = a * gust + math.sqrt(1 - a * a) * rng.normal(0.0, p.gust_ratio * p.wind_mps, 3) \
            * np.array([1.0, 1.0, 0.0])
        b = math.exp(-dt / p.nav_tau_s)
        nav_err = b * nav_err + math.sqrt(1 - b * b) * rng.normal(0.0, p.nav_sigma_m, 2)
        t += dt
    return LandingResult(error_m=float(np.hypot(pos[0], pos[1])),
                         initialised=est.ever_acquired, init_time_s=est.initialised_at,
                         blind_camera_height_m=last_seen_cam_h, measurements=est.n_meas,
                         init_failures=est.init_fail, last_estimate_error_m=lost_estimate_err,
                         events=est.events,
                         last_update_s=None if est.kf is None and not est.ever_acquired
                         and est.n_meas == 0 else est.last_fused,
                         estimate_rms_m=float(np.sqrt(np.mean(sq_err))) if sq_err else None)


def landing_summary(camera: Camera, mount: Mount, layout: MarkerLayout,
                    params: LandingParams | None = None, runs: int = 20) -> dict:
    """``runs`` landings (seeds 0..runs-1): median and 90th percentile of the touchdown
    error, the share that initialised, the median blind height."""
    base = params or LandingParams()
    res = [simulate_landing(camera, mount, layout, replace(base, seed=base.seed + k))
           for k in range(runs)]
    err = np.array([r.error_m for r in res])
    blind = [r.blind_camera_height_m for r in res if r.blind_camera_height_m is not None]
    return {"runs": runs, "median_error_m": float(np.median(err)),
            "p90_error_m": float(np.percentile(err, 90)),
            "initialised": sum(r.initialised for r in res) / runs,
            "blind_camera_height_m": float(np.median(blind)) if blind else None,
            "rate_hz": base.rate_hz, "wind_mps": base.wind_mps, "latency_s": base.latency_s,
            "plnd_lag_s": base.latency_s if base.plnd_lag_s is None else base.plnd_lag_s}


def landing_report(camera: Camera, mount: Mount, layout: MarkerLayout,
                   params: LandingParams | None = None, runs: int = 20) -> list[str]:
    """Lines for people: the landing with this mount and with the camera straight down at the
    same place, the blind heights, and a warning below the filter's 2 Hz."""
    p = params or LandingParams()
    a = mount.angles()
    down = Mount.from_angles(0.0, 0.0, a["roll_deg"], a["offset_m"])
    lines = []
    for name, m in ((f"this mount (tilt {a['tilt_deg']:.0f}°)", mount), ("straight down", down)):
        s = landing_summary(camera, m, layout, p, runs)
        b = blind_height(camera, m, layout).leaves_at_m
        lines.append(
            f"precision landing on a {layout.name}, {name}: touchdown error median "
            f"{s['median_error_m'] * 100:.1f} cm, p90 {s['p90_error_m'] * 100:.1f} cm over "
            f"{runs} landings; filter initialised in {s['initialised'] * 100:.0f}% of them; "
            + (f"the brick leaves the picture {b:.2f} m above it (camera height; level)"
               if b is not None else "the brick stays in the picture down to touchdown"))
    lines.append(f"  (ArduPilot model: {p.rate_hz:g} Hz detection at {p.detect_prob:.0%}, "
                 f"latency {p.latency_s * 1e3:.0f} ms, PLND_LAG "
                 f"{(p.latency_s if p.plnd_lag_s is None else p.plnd_lag_s) * 1e3:.0f} ms, "
                 f"wind {p.wind_mps:g} m/s, LAND_SPEED {p.land_speed:g} m/s)")
    if p.rate_hz * p.detect_prob < REQUIRED_RATE_HZ:
        lines.append(f"  WARNING: {p.rate_hz * p.detect_prob:.1f} detections a second is below "
                     f"the {REQUIRED_RATE_HZ:g} Hz ArduPilot's precision-landing filter needs to "
                     "initialise (updates at most 0.5 s apart for 2 s): it lands without "
                     "the target")
    return lines
