"""The simulator's parameters, one simulated tick, and the trace of a run."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio.mission.faults import Fault
from drovisio.mission.machine import State
from drovisio.mission.scenario import Scenario
from drovisio.mission.vision import DetectorModelParams

__all__ = ["SimParams", "Tick", "Trace"]


@dataclass
class SimParams:
    """How the simulated world behaves (SI units: s, m, m/s; angles in degrees; rates in Hz;
    see :mod:`drovisio.mission.sim` for each part)."""

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
    """One simulated tick: the truth (position (x, y, z), site frame, m; yaw, rad; the
    bricks), what the sensors gave (``ts``, ``vision``) and what the machine output."""

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
    """A simulated run: every tick, the outcome, the placements and landings (truth)."""

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
    the brick was first looked for), ``last_seen_camera_height_m`` (camera above the brick's
    top at the last LANDING_TARGET sent), ``blind_height_m`` (where the brick leaves the
    picture, this lens and mount), ``estimate_error_m`` (the estimate flown to, against the
    truth)."""

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
