"""Is the autopilot set up for what Drovisio sends? Each precision-landing parameter, compared.

Drovisio sends ``LANDING_TARGET`` with the camera mount already applied: for ArduPilot the
brick's position in the body frame (``MAV_FRAME_BODY_FRD``, from the body origin), for PX4 its
absolute position in ``MAV_FRAME_LOCAL_NED``. The autopilot must therefore not apply a camera
pose of its own, must pair each measurement with the attitude of the right moment, and must
hear the target often enough for its filter. :func:`evaluate` turns what was read from the
vehicle (:class:`Facts`) into one :class:`Finding` per item: ``ok``, ``wrong`` (with the value
to set and why), ``warn`` or ``unknown``.

The parameter tables (:data:`ARDUPILOT`, :data:`PX4`) are the documentation's source too
(``docs/field-guide.md``, the README).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["ARDUPILOT", "PX4", "Expected", "Facts", "Finding", "evaluate", "param_names",
           "plnd_lag_for", "REQUIRED_RATE_HZ"]

REQUIRED_RATE_HZ = 2.0
"""ArduPilot's precision-landing filter initialises only after updates at least every 0.5 s
for 2 s, and drops the target after 2 s without one."""
PLND_LAG_RANGE = (0.02, 0.25)
"""ArduPilot's accepted PLND_LAG, seconds."""


@dataclass(frozen=True)
class Expected:
    name: str
    value: float | None
    """The value to set (None: computed from a measurement, see :func:`evaluate`)."""
    why: str
    tol: float = 1e-6


ARDUPILOT: tuple[Expected, ...] = (
    Expected("PLND_ENABLED", 1, "precision landing on (the other PLND_* parameters appear "
             "only once it is 1: refresh the parameters after setting it)"),
    Expected("PLND_TYPE", 1, "MAVLink: the target comes as LANDING_TARGET from the companion "
             "computer (Drovisio)"),
    Expected("PLND_EST_TYPE", 1, "Kalman filter (the default): it fuses Drovisio's "
             "measurements with the vehicle's motion and bridges short gaps"),
    Expected("PLND_ORIENT", 25, "down: Drovisio already turned the measurement into the body "
             "frame with the mount file; any other value rotates it a second time"),
    Expected("PLND_YAW_ALIGN", 0, "Drovisio already applied the mount's pan; ArduPilot would "
             "turn the target by it again"),
    Expected("PLND_CAM_POS_X", 0, "Drovisio sends the target from the body origin (the "
             "camera's offset is in the mount file); ArduPilot would add it again"),
    Expected("PLND_CAM_POS_Y", 0, "as PLND_CAM_POS_X"),
    Expected("PLND_CAM_POS_Z", 0, "as PLND_CAM_POS_X"),
    Expected("PLND_LAG", None, "ArduPilot ignores LANDING_TARGET's time stamp and pairs each "
             "measurement with the attitude this many seconds old: set it to Drovisio's "
             "capture-to-send latency (0.02-0.25 s; reboot after changing it)", tol=0.0),
)
PX4: tuple[Expected, ...] = (
    Expected("LTEST_MODE", 1, "stationary: a brick on the ground does not move, the "
             "estimator keeps it fixed in the local frame (used while Drovisio can only send "
             "angles, position_valid=0)"),
    Expected("LTEST_SCALE_X", 1, "Drovisio's angles are true angles (no IR-LOCK lens scale)"),
    Expected("LTEST_SCALE_Y", 1, "as LTEST_SCALE_X"),
    Expected("PLD_HACC_RAD", 0.05, "PX4 starts the final descent once within this horizontal "
             "distance of the target; its default 0.2 m is four times the 5 cm placement "
             "tolerance", tol=0.05 + 1e-6),
    Expected("PLD_FAPPR_ALT", None, "below this height PX4 descends without the target; "
             "above it a lost target makes it search: set it to at least the height at which "
             "the brick leaves the picture with this mount", tol=0.0),
)
SERIAL_PORTS = tuple(f"SERIAL{n}_PROTOCOL" for n in range(1, 9))
MAVLINK2 = 2


def plnd_lag_for(latency_s: float) -> float:
    """The PLND_LAG for a measured capture-to-send latency: rounded to 10 ms, in range."""
    lo, hi = PLND_LAG_RANGE
    return round(min(hi, max(lo, latency_s)), 2)


def param_names(flavour: str, serial: bool) -> list[str]:
    """The parameters :func:`evaluate` needs."""
    table = ARDUPILOT if flavour == "ardupilot" else PX4
    names = [e.name for e in table]
    if flavour == "ardupilot" and serial:
        names += list(SERIAL_PORTS)
    return names


@dataclass
class Facts:
    """What is known about the vehicle and about Drovisio's side."""

    flavour: str
    """What Drovisio sends: ``ardupilot`` (BODY_FRD) or ``px4`` (LOCAL_NED)."""
    autopilot: int | None = None
    """The vehicle's HEARTBEAT ``autopilot`` (3 ArduPilot, 12 PX4); None: not heard."""
    system: int | None = None
    params: dict[str, float] = field(default_factory=dict)
    params_asked: bool = False
    serial: bool = False
    """Drovisio's link is a serial port (its SERIALn_PROTOCOL matters)."""
    attitude_hz: float | None = None
    position_hz: float | None = None
    latency_s: float | None = None
    """Measured capture-to-send latency (median)."""
    detection_hz: float | None = None
    """How often the target is measured on the current scene."""
    blind_height_m: float | None = None
    """Camera height above the brick at which it leaves the picture (this mount)."""


@dataclass(frozen=True)
class Finding:
    item: str
    status: str
    """``ok``, ``wrong``, ``warn`` or ``unknown``."""
    text: str

    def line(self) -> str:
        return f"{self.status:7s} {self.item}: {self.text}"

    def to_json(self) -> dict:
        return {"item": self.item, "status": self.status, "text": self.text}


def _fmt(v: float) -> str:
    return f"{v:g}"


def _param(f: Facts, e: Expected, want: float | None, out: list[Finding]) -> None:
    have = f.params.get(e.name)
    if have is None:
        out.append(Finding(e.name, "unknown" if not f.params_asked else "wrong",
                           "not read" if not f.params_asked else
                           f"not found on the vehicle → set it to "
                           f"{_fmt(want) if want is not None else 'see below'} ({e.why})"))
        return
    if want is None:
        out.append(Finding(e.name, "unknown", f"{_fmt(have)}: nothing measured to compare "
                           f"with ({e.why})"))
        return
    if abs(have - want) <= e.tol:
        out.append(Finding(e.name, "ok", f"{_fmt(have)}"))
    else:
        out.append(Finding(e.name, "wrong", f"{_fmt(have)} → set {_fmt(want)}: {e.why}"))


def evaluate(f: Facts) -> list[Finding]:
    """One finding per item (see the module doc), in a fixed order: the autopilot, its
    parameters (and serial ports), the streams Drovisio asked for, latency, detection rate."""
    out = [_autopilot_finding(f)]
    lag = plnd_lag_for(f.latency_s) if f.latency_s is not None else None
    if f.flavour == "ardupilot":
        out += _ardupilot_params(f, lag)
        if f.serial and f.params_asked:
            out.append(_serial_ports(f))
    else:
        out += _px4_params(f)
    out += _streams(f)
    out.append(_latency(f, lag))
    out.append(_detection_rate(f))
    return out


def _autopilot_finding(f: Facts) -> Finding:
    """Is there a flight controller, and of the flavour Drovisio sends?"""
    if f.autopilot is None:
        return Finding("autopilot", "unknown", "no HEARTBEAT from a flight controller")
    names = {3: "ArduPilot", 12: "PX4"}
    kind = names.get(f.autopilot, f"MAV_AUTOPILOT {f.autopilot}")
    sends = "ardupilot" if f.autopilot == 3 else "px4" if f.autopilot == 12 else None
    if sends == f.flavour:
        return Finding("autopilot", "ok", f"{kind} (system {f.system}); Drovisio sends "
                       + ("BODY_FRD targets, mount applied" if f.flavour == "ardupilot"
                          else "LOCAL_NED targets, mount and attitude applied"))
    fix = f"--autopilot {sends}" if sends else "a PX4 or ArduPilot flight controller"
    return Finding("autopilot", "wrong",
                   f"{kind} (system {f.system}) but Drovisio sends the {f.flavour} "
                   f"flavour → run with {fix}: the other flavour's frame is "
                   "ignored or misread")


def _ardupilot_params(f: Facts, lag: float | None) -> list[Finding]:
    """ArduPilot's precision-landing parameters, PLND_LAG against the measured latency."""
    out: list[Finding] = []
    enabled = f.params.get("PLND_ENABLED")
    for e in ARDUPILOT:
        if e.name != "PLND_ENABLED" and enabled is not None and enabled != 1 \
                and e.name not in f.params:
            out.append(Finding(e.name, "unknown", "hidden while PLND_ENABLED is 0: set "
                               "PLND_ENABLED=1, refresh the parameters and check again"))
        elif e.name == "PLND_LAG":
            _plnd_lag(f, e, lag, out)
        else:
            _param(f, e, e.value, out)
    return out


def _plnd_lag(f: Facts, e: Expected, lag: float | None, out: list[Finding]) -> None:
    """PLND_LAG within one rounding step or a quarter of the lag the latency asks for."""
    have = f.params.get(e.name)
    if lag is None or have is None:
        _param(f, e, lag, out)
        return
    lat_ms = (f.latency_s or 0.0) * 1e3
    tol = max(0.01, 0.25 * lag)   # ArduPilot's 10 ms grain
    if abs(have - lag) <= tol:
        out.append(Finding(e.name, "ok", f"{_fmt(have)} s for a measured "
                           f"{lat_ms:.0f} ms"))
    else:
        out.append(Finding(e.name, "wrong", f"{_fmt(have)} → set {lag:.2f}: "
                           f"measured capture-to-send latency "
                           f"{lat_ms:.0f} ms. {e.why}"))


def _serial_ports(f: Facts) -> Finding:
    """A serial link needs MAVLink 2 on its port (LANDING_TARGET's extension fields)."""
    ports = {p: f.params[p] for p in SERIAL_PORTS if p in f.params}
    mav2 = [p for p, v in ports.items() if v == MAVLINK2]
    mav1 = [p for p, v in ports.items() if v == 1]
    if mav2 and not mav1:
        return Finding("SERIALn_PROTOCOL", "ok", ", ".join(mav2) + " = 2 (MAVLink 2)")
    if mav1:
        return Finding("SERIALn_PROTOCOL", "wrong" if not mav2 else "warn",
                       ", ".join(f"{p} = 1" for p in mav1) + " → set 2 on the port "
                       "Drovisio is wired to: LANDING_TARGET's x, y, z and q are "
                       "MAVLink 2 fields")
    return Finding("SERIALn_PROTOCOL", "wrong", "no serial port speaks MAVLink "
                   "2 → set SERIALn_PROTOCOL = 2 on Drovisio's port")


def _px4_params(f: Facts) -> list[Finding]:
    """PX4's precision-landing parameters; the final-approach altitude against the height
    at which the brick leaves the picture, the horizontal acceptance radius as a bound."""
    out: list[Finding] = []
    for e in PX4:
        want: float | None = e.value
        have = f.params.get(e.name)
        if e.name == "PLD_FAPPR_ALT":
            want = None if f.blind_height_m is None else round(f.blind_height_m + 0.05, 2)
            if want is not None and have is not None:
                high_enough = have >= want - 1e-6
                out.append(Finding(e.name, "ok" if high_enough else "wrong",
                                   f"{_fmt(have)}" if high_enough else
                                   f"{_fmt(have)} → set {want:.2f}: the brick leaves the "
                                   f"picture {f.blind_height_m:.2f} m above it. {e.why}"))
                continue
        elif e.name == "PLD_HACC_RAD" and have is not None and want is not None:
            tight_enough = have <= want + 1e-6
            out.append(Finding(e.name, "ok" if tight_enough else "wrong",
                               _fmt(have) if tight_enough else
                               f"{_fmt(have)} → set {_fmt(want)}: {e.why}"))
            continue
        _param(f, e, want, out)
    return out


def _streams(f: Facts) -> list[Finding]:
    """The streams Drovisio asked for, at the rates its pose needs."""
    out: list[Finding] = []
    for name, hz, need, why in (
            ("ATTITUDE", f.attitude_hz, 5.0, "roll and pitch for the gravity prior (without "
             "them poses assume level flight)"),
            ("LOCAL_POSITION_NED", f.position_hz, 5.0 if f.flavour == "px4" else 0.0,
             "PX4's absolute target position (without it position_valid=0)")):
        if need == 0.0:
            continue
        if hz is None:
            out.append(Finding(name, "unknown", "not measured"))
        elif hz >= need:
            out.append(Finding(name, "ok", f"{hz:.0f} Hz after asking for it"))
        else:
            out.append(Finding(name, "wrong", f"{hz:.1f} Hz after asking for it (need "
                               f"≥ {need:.0f} Hz for {why}) → allow the companion's stream "
                               "requests, or set the port's stream rates (ArduPilot "
                               "MAVn_EXTRA1/MAVn_POSITION or SRn_*; PX4 MAV_n_MODE)"))
    return out


def _latency(f: Facts, lag: float | None) -> Finding:
    if f.latency_s is None:
        return Finding("latency", "unknown", "not measured: give --source, --camera and "
                       "--layout to measure it on the current scene")
    return Finding("latency", "ok", f"capture to send {f.latency_s * 1e3:.0f} ms → "
                   f"PLND_LAG {lag:.2f}")


def _detection_rate(f: Facts) -> Finding:
    """The filter initialises only on updates at least every 0.5 s for 2 s."""
    hz = f.detection_hz
    if hz is None:
        return Finding("detection rate", "unknown", "not measured: give --source, "
                       "--camera and --layout, the brick in view")
    if hz < REQUIRED_RATE_HZ:
        return Finding("detection rate", "wrong", f"target measured {hz:.1f} "
                       f"times a second: below {REQUIRED_RATE_HZ:g} Hz the autopilot's "
                       "precision-landing filter never initialises (it needs an update "
                       "at least every 0.5 s for 2 s) → a faster board, fewer layouts, "
                       "a lower resolution, or more light")
    if hz < 1.5 * REQUIRED_RATE_HZ:
        return Finding("detection rate", "warn", f"{hz:.1f} Hz: just above "
                       f"the filter's {REQUIRED_RATE_HZ:g} Hz need; one missed detection "
                       "breaks its 0.5 s chain")
    return Finding("detection rate", "ok", f"{hz:.1f} Hz (the filter "
                   f"needs {REQUIRED_RATE_HZ:g} Hz)")


def verdict(findings: list[Finding]) -> int:
    """0 when nothing is wrong or to watch, else 1."""
    return 1 if any(x.status in ("wrong", "warn") for x in findings) else 0


def finite(v: float | None) -> float | None:
    return v if v is not None and math.isfinite(v) else None
