"""``mavlink:CONNECTION``: the target brick as MAVLink ``LANDING_TARGET``, for ArduPilot or PX4.

One message per processed frame in which the target (see :mod:`drovisio.sinks.target`) was
**measured** — seen by the camera in that very frame — stamped with that frame's capture time
and carrying that measurement (what the camera saw, not the tracker's filtered or predicted
pose). A frame that does not show the target sends nothing: ArduPilot's and PX4's own filters
expect line-of-sight measurements, and a held-over pose sent as a new one would be counted
again as evidence (and is wrong as soon as the drone moves: 0.4 s at 0.5 m/s is 20 cm). The
autopilots handle a lost target themselves (ArduPilot waits ~2 s before giving up).

``send_held=True`` (``--send-held-targets``: off by default, for a camera with long dropouts
and an autopilot that needs a steady stream, at the risk above) also sends a held-over
target, with its last measurement stamped with the time of that measurement. MAVLink 2 (the
position fields are extensions).

ArduPilot (``autopilot="ardupilot"``, default; ``PLND_TYPE=1`` companion computer,
``PLND_ORIENT`` down, ``PLND_CAM_POS_*`` = 0 because the mount offset is applied here):
``position_valid=1``, ``frame=MAV_FRAME_BODY_FRD``, ``x, y, z`` = the brick origin in the drone
body frame (camera mount applied, tilt included), ``distance = |(x, y, z)|`` (> 0; ArduPilot
divides by it to get the line of sight), ``q`` = ``body_from_brick`` rotation (ArduPilot
ignores it).

PX4 (``autopilot="px4"``): PX4 takes ``position_valid=1`` only in ``MAV_FRAME_LOCAL_NED``, as
the target's *absolute* local position (``landing_target_pose.x_abs``). That needs the
vehicle's attitude and local position at the capture time: both are read from the same link
(``ATTITUDE``, ``LOCAL_POSITION_NED``; interpolated at the frame's capture time, refused
when older than ``max_state_age``). ``x, y, z = p_vehicle + R_ned_from_body · p_body``,
``q = R_ned_from_body · R_body_from_brick``. Until both are known the message is sent with
``position_valid=0`` and the angles only (PX4's IR-lock path).

Both modes fill the image fields as the MAVLink spec defines them: ``angle_x = atan2(x_c,
z_c)``, ``angle_y = atan2(y_c, z_c)`` (offsets of the target from the image centre, camera
frame), ``size_x``/``size_y`` = the angles the brick's length and width subtend,
``time_usec`` = the frame's capture time (UNIX µs), ``target_num`` = the brick's instance
(its track number for bricks without id), ``type = LANDING_TARGET_TYPE_VISION_FIDUCIAL``.

The sink also sends a ``HEARTBEAT`` (``MAV_TYPE_ONBOARD_CONTROLLER``) every second, so that
routers and the autopilot know the component and stream its data back, and asks the vehicle
for ``ATTITUDE`` and ``LOCAL_POSITION_NED`` (:class:`drovisio.autopilot.link.StreamKeeper`:
``SET_MESSAGE_INTERVAL``, falling back to ``REQUEST_DATA_STREAM``): autopilots stream nothing
to a companion unless asked. When a stream still does not arrive, :meth:`MavlinkSink.status`
carries a ``note`` saying so and what the pose assumes. It also reads the vehicle's
precision-landing parameters and compares them (``check``, :mod:`drovisio.autopilot.check`).

Ids: ``mavlink:CONNECTION?sysid=N&compid=M``. ``sysid`` is our system id and, as MAVLink has
it for a companion computer, the vehicle's: the sink then takes ``ATTITUDE``,
``LOCAL_POSITION_NED`` and ``HEARTBEAT`` only from that system's autopilot (several vehicles
on one router). Without it the sink speaks as system 1 and follows the first autopilot it
hears. ``compid`` is our component id (default 191, ``MAV_COMP_ID_ONBOARD_COMPUTER``).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from drovisio._threads import join_thread
from drovisio.autopilot.check import Facts, evaluate, param_names
from drovisio.autopilot.connection import (
    AddressError,
    LinkDown,
    mavutil2,
    open_link,
    parse_connection,
    split_connection,
)
from drovisio.autopilot.link import MSG_ATTITUDE, MSG_LOCAL_POSITION_NED, ParamReader, StreamKeeper
from drovisio.geometry import ned_from_body, quat_wxyz
from drovisio.mount import Mount, down_camera_mount
from drovisio.sinks.base import Delivery, SinkError
from drovisio.sinks.target import TargetSelector

__all__ = [
    "MAV_FRAME_BODY_FRD",
    "MAV_FRAME_LOCAL_NED",
    "MavlinkSink",
    "VehicleState",
    "landing_target_fields",
    "mavutil2",
    "parse_mavlink_spec",
]

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
LANDING_TARGET_TYPE_VISION_FIDUCIAL = 2
MAV_COMP_ID_ONBOARD_COMPUTER = 191


@contextmanager
def _as_sink_error() -> Iterator[None]:
    """A connection string the link cannot use is a sink that cannot be opened (its why:
    the spec is said by ``open_sink``)."""
    try:
        yield
    except AddressError as e:
        raise SinkError(e.why) from None


def parse_mavlink_spec(spec: str) -> tuple[str, dict[str, int]]:
    """``udpout:127.0.0.1:14550?sysid=2&compid=191`` → (connection, {"sysid": 2, ...}).

    Raises:
        SinkError: an unknown option or an id outside 1-255 (named).
    """
    with _as_sink_error():
        return parse_connection(spec)


@dataclass
class _Sample:
    t: float
    values: tuple[float, ...]


class VehicleState:
    """The vehicle's attitude and local position as the link reports them (thread-safe)."""

    def __init__(self, keep_s: float = 2.0):
        self._lock = threading.Lock()
        self.attitude: deque[_Sample] = deque(maxlen=400)
        self.position: deque[_Sample] = deque(maxlen=400)
        self.keep_s = keep_s
        self.autopilot_sysid: int | None = None

    def add_attitude(self, t_mono: float, roll: float, pitch: float, yaw: float) -> None:
        with self._lock:
            self.attitude.append(_Sample(t_mono, (roll, pitch, yaw)))

    def add_position(self, t_mono: float, x: float, y: float, z: float) -> None:
        with self._lock:
            self.position.append(_Sample(t_mono, (x, y, z)))

    @staticmethod
    def _at(samples: deque, t: float, max_age: float, angles: bool) -> tuple | None:
        if not samples:
            return None
        s = list(samples)
        if t <= s[0].t:
            return s[0].values if s[0].t - t <= max_age else None
        if t >= s[-1].t:
            return s[-1].values if t - s[-1].t <= max_age else None
        for a, b in zip(s, s[1:]):
            if a.t <= t <= b.t:
                if b.t - a.t > 2 * max_age:
                    return None
                f = (t - a.t) / (b.t - a.t) if b.t > a.t else 0.0
                out = []
                for va, vb in zip(a.values, b.values):
                    d = vb - va
                    if angles:
                        d = (d + math.pi) % (2 * math.pi) - math.pi
                    out.append(va + f * d)
                return tuple(out)
        return None

    def attitude_at(self, t_mono: float, max_age: float = 0.3) -> tuple | None:
        """(roll, pitch, yaw) rad at ``t_mono`` (interpolated), or None if not known then."""
        with self._lock:
            return self._at(self.attitude, t_mono, max_age, True)

    def position_at(self, t_mono: float, max_age: float = 0.3) -> tuple | None:
        """Local NED position (m) at ``t_mono``, or None."""
        with self._lock:
            return self._at(self.position, t_mono, max_age, False)


def landing_target_fields(brick, t_wall: float, mount: Mount | None, autopilot: str = "ardupilot",
                          attitude: tuple | None = None, position: tuple | None = None,
                          size_m: tuple[float, float] | None = None,
                          camera_from_brick: np.ndarray | None = None) -> dict:
    """The ``LANDING_TARGET`` fields (pymavlink ``landing_target_send`` keywords) for a tracked
    brick (a :class:`drovisio.tracking.TrackedBrick`). See the module doc for the conventions.

    Args:
        brick: The target (its instance or track number becomes ``target_num``).
        t_wall: Capture time of the pose (UNIX s): ``time_usec``.
        camera_from_brick: The pose to send (default: the brick's own pose).
    """
    mount = mount if mount is not None else down_camera_mount()
    T_cb = camera_from_brick if camera_from_brick is not None else brick.camera_from_brick()
    p_cam = T_cb[:3, 3]
    T_bb = mount.body_from(T_cb)
    p_body = T_bb[:3, 3]
    dist = float(np.linalg.norm(p_body))
    angle_x = math.atan2(p_cam[0], p_cam[2])
    angle_y = math.atan2(p_cam[1], p_cam[2])
    d_cam = float(np.linalg.norm(p_cam))
    if size_m and d_cam > 0:
        size_x = 2 * math.atan2(0.5 * size_m[0], d_cam)
        size_y = 2 * math.atan2(0.5 * size_m[1], d_cam)
    else:
        size_x = size_y = 0.0
    num = brick.instance if brick.instance is not None else brick.track
    fields: dict[str, Any] = dict(time_usec=int(round(t_wall * 1e6)), target_num=int(num) % 256,
                  angle_x=angle_x, angle_y=angle_y, distance=dist, size_x=size_x,
                  size_y=size_y, type=LANDING_TARGET_TYPE_VISION_FIDUCIAL)
    if autopilot == "ardupilot":
        fields.update(frame=MAV_FRAME_BODY_FRD, x=float(p_body[0]), y=float(p_body[1]),
                      z=float(p_body[2]), q=quat_wxyz(T_bb[:3, :3]), position_valid=1)
    elif autopilot == "px4":
        if attitude is not None and position is not None:
            R_nb = ned_from_body(*attitude)
            p_ned = np.asarray(position, np.float64) + R_nb @ p_body
            fields.update(frame=MAV_FRAME_LOCAL_NED, x=float(p_ned[0]), y=float(p_ned[1]),
                          z=float(p_ned[2]), q=quat_wxyz(R_nb @ T_bb[:3, :3]),
                          position_valid=1)
        else:
            fields.update(frame=MAV_FRAME_LOCAL_NED, x=0.0, y=0.0, z=0.0,
                          q=[1.0, 0.0, 0.0, 0.0], position_valid=0)
    else:
        raise ValueError(f"unknown autopilot {autopilot!r}: ardupilot or px4")
    return fields


class MavlinkSink:
    """Sends the target brick as ``LANDING_TARGET`` and reads the vehicle state back.

    Args:
        connection: pymavlink connection string (``udpout:127.0.0.1:14550``,
            ``tcp:127.0.0.1:5760``, ``/dev/ttyAMA0,921600``).
        autopilot: ``"ardupilot"`` or ``"px4"``.
        target: The shared target selector (used when the output carries no target).
        mount: Camera mount (without one: camera looking straight down, image top forward).
        layouts: Layouts (their dimensions give ``size_x``/``size_y``).
        source_system, source_component: Our MAVLink ids (``?sysid=``/``?compid=`` in the
            connection override them). A given system id is also the vehicle's: only its
            autopilot's messages are read. None: system 1, following the first autopilot
            heard.
        max_state_age: Oldest attitude/position (s) used for a frame (PX4 mode).
        blind_height_m: The camera height at which the target leaves the picture with this
            mount (for the PX4 check), if known.
    """

    def __init__(self, connection: str, autopilot: str = "ardupilot",
                 target: TargetSelector | None = None, mount: Mount | None = None,
                 layouts=None, source_system: int | None = None,
                 source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
                 max_state_age: float = 0.3, heartbeat_period: float = 1.0,
                 send_held: bool = False, blind_height_m: float | None = None):
        if autopilot not in ("ardupilot", "px4"):
            raise SinkError(f"unknown autopilot {autopilot!r}: ardupilot or px4")
        self.name = f"mavlink:{connection}"
        connection, ids = parse_mavlink_spec(connection)
        follow = ids.get("sysid", source_system)    # None: the first autopilot heard
        source_system = follow or 1
        source_component = ids.get("compid", source_component)
        self.autopilot = autopilot
        self.target = target or TargetSelector()
        self.mount = mount
        self.sizes: dict[str, tuple[float, float]] = {
            lay.name: (float(lay.dimensions_m[0]), float(lay.dimensions_m[1]))
            for lay in (layouts or [])}
        self.max_state_age = max_state_age
        self.heartbeat_period = heartbeat_period
        self.vehicle = VehicleState()
        self.blind_height_m = blind_height_m
        self._latency: deque[float] = deque(maxlen=90)
        self._measured_at: deque[float] = deque(maxlen=64)
        self.send_held = send_held
        self.held_not_sent = 0
        """Frames whose target was held over (not measured): nothing sent for them."""
        self.delivery = Delivery()
        """LANDING_TARGETs sent, and lost while the link was down (never counted as sent)."""
        self.sent_position_valid = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._mavutil = mavutil2()
        dev, baud = split_connection(connection)
        with _as_sink_error():
            self.conn = open_link(self.name, connection, source_system=source_system,
                                  source_component=source_component, reconnect=True)
        self._serial = baud is not None or dev.startswith(("/dev/", "COM"))
        self.streams = StreamKeeper(self._send_with, follow,
                                    needs_position=autopilot == "px4", start=time.monotonic())
        self.params = ParamReader(self._send_with, param_names(autopilot, self._serial))
        self.param_refresh_s = 15.0
        self._params_since = time.monotonic()
        self._send_heartbeat()
        self._thread = threading.Thread(target=self._reader, daemon=True, name="mavlink-rx")
        self._thread.start()

    # ------------------------------------------------------------------ link
    def _write(self, what: str, fn, target: bool = False) -> bool:
        """Write one message through the shared connection: counted (``target``: a
        LANDING_TARGET) as sent only once the link took it, as lost when the link is down.
        A heartbeat or request the link drops says the link is down but counts nothing."""
        try:
            with self._lock:
                fn(self.conn.mav)
        except LinkDown as e:             # closed, or its device gone: said once, counted
            self.delivery.dropped(str(e), count=target)
            return False
        except Exception as e:  # noqa: BLE001 - never let the link stop the pipeline
            self.delivery.failed(f"{what}: {e}")
            return False
        self.delivery.delivered(count=target)
        return True

    def _send_heartbeat(self) -> None:
        m = self._mavutil.mavlink
        self._write("heartbeat", lambda mav: mav.heartbeat_send(
            m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE))

    def _send_with(self, fn) -> None:
        """Send one request (stream, parameter) through the shared connection (a request
        that fails is asked again)."""
        self._write("request", fn)

    def _reader(self) -> None:
        next_hb = time.monotonic() + self.heartbeat_period
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except Exception as e:  # noqa: BLE001 - link hiccup: note it, keep reading
                self.delivery.note(f"receive: {e}")
                self._stop.wait(0.2)
                msg = None
            now = time.monotonic()
            if msg is not None and msg.get_type() != "BAD_DATA":
                self.streams.on_message(msg, now)
                self.params.on_message(msg, self.streams.vehicle)
                t = msg.get_type()
                # only our vehicle's state: several vehicles may share a router
                if t == "ATTITUDE" and self.streams.from_vehicle(msg):
                    self.vehicle.add_attitude(now, msg.roll, msg.pitch, msg.yaw)
                elif t == "LOCAL_POSITION_NED" and self.streams.from_vehicle(msg):
                    self.vehicle.add_position(now, msg.x, msg.y, msg.z)
                elif t == "HEARTBEAT" and self.streams.vehicle is not None:
                    self.vehicle.autopilot_sysid = self.streams.vehicle.system
            self.streams.poll(now)
            if self.params.done(now) and now - self._params_since > self.param_refresh_s:
                self.params.refresh()         # someone may have fixed a parameter since
                self._params_since = now
            self.params.poll(now, self.streams.vehicle, burst=2)
            if now >= next_hb:
                self._send_heartbeat()
                next_hb = now + self.heartbeat_period

    def attitude_at(self, t_mono: float) -> tuple | None:
        return self.vehicle.attitude_at(t_mono, self.max_state_age)

    # ------------------------------------------------------------------ sink API
    def send(self, output) -> None:
        brick = output.target if getattr(output, "target", None) is not None \
            else self.target.choose(output.bricks)
        if brick is None:
            return
        T_cb = brick.measured_camera_from_brick()
        t_wall, t_mono = output.t, output.t_mono
        if T_cb is not None:
            self._measured_at.append(t_mono)
        if T_cb is None:                 # held over: not seen in this frame
            if not self.send_held or brick.last_measured is None:
                self.held_not_sent += 1
                return
            T_cb = brick.last_measured
            t_wall, t_mono = brick.t_measured, output.t_mono - brick.age
        att = pos = None
        if self.autopilot == "px4":
            att = self.vehicle.attitude_at(t_mono, self.max_state_age)
            pos = self.vehicle.position_at(t_mono, self.max_state_age)
        try:
            f = landing_target_fields(brick, t_wall, self.mount, self.autopilot, att, pos,
                                      self.sizes.get(brick.layout), camera_from_brick=T_cb)
        except Exception as e:  # noqa: BLE001 - never let one pose stop the pipeline
            self.delivery.failed(str(e))
            return
        if not self._write("landing target", lambda mav: mav.landing_target_send(
                f["time_usec"], f["target_num"], f["frame"], f["angle_x"], f["angle_y"],
                f["distance"], f["size_x"], f["size_y"], f["x"], f["y"], f["z"], f["q"],
                f["type"], f["position_valid"]), target=True):
            return
        self.sent_position_valid += int(f["position_valid"])
        if brick.measured:
            self._latency.append(time.monotonic() - t_mono)

    def close(self) -> None:
        self._stop.set()
        join_thread(self._thread, f"reading {self.name}")   # each read waits 0.05 s at most
        try:
            # a TCP link's attempt to connect again is ended and waited for here
            self.conn.close()
        except Exception:  # noqa: BLE001
            pass

    def detection_hz(self, now: float, window: float = 5.0) -> float | None:
        """How often the target was measured over the last ``window`` s (None: too soon)."""
        recent = [t for t in self._measured_at if now - t <= window]
        if len(recent) >= 2:
            return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)
        return 0.0 if now - self.streams.started >= window else None

    def facts(self) -> Facts:
        """What the sink knows for :func:`drovisio.autopilot.check.evaluate`."""
        now = time.monotonic()
        v = self.streams.vehicle
        asked = v is not None and self.params.done(now)
        att = self.streams.streams[MSG_ATTITUDE]
        pos = self.streams.streams[MSG_LOCAL_POSITION_NED]
        return Facts(flavour=self.autopilot, autopilot=None if v is None else v.autopilot,
                     system=None if v is None else v.system, params=dict(self.params.values),
                     params_asked=asked, serial=self._serial,
                     attitude_hz=att.rate(now) if att.first_request is not None else None,
                     position_hz=pos.rate(now) if pos.first_request is not None else None,
                     latency_s=float(np.median(self._latency)) if self._latency else None,
                     detection_hz=self.detection_hz(now), blind_height_m=self.blind_height_m)

    def check(self) -> list[dict]:
        """The autopilot check on what this link saw (the live page shows it)."""
        return [f.to_json() for f in evaluate(self.facts())]

    def status(self) -> dict:
        now = time.monotonic()
        v = self.streams.vehicle
        return {"sink": self.name, "autopilot": self.autopilot, **self.delivery.status(),
                "position_valid": self.sent_position_valid,
                "held_not_sent": self.held_not_sent,
                "attitude": self.vehicle.attitude_at(now, 1.0) is not None,
                "vehicle": None if v is None else {"system": v.system,
                                                   "component": v.component,
                                                   "autopilot": v.autopilot_name},
                "streams": self.streams.status(now),
                "note": self.streams.note,
                "check": self.check()}
