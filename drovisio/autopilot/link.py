"""What Drovisio asks the autopilot for over MAVLink: the vehicle, its streams, its parameters.

Autopilots stream nothing to a companion computer unless asked (ArduCopter's default
``MAVn_EXTRA1`` / ``MAVn_POSITION`` rates are 0). :class:`StreamKeeper` finds the vehicle (the
first ``HEARTBEAT`` of an autopilot from the expected system id), asks it for ``ATTITUDE`` and
``LOCAL_POSITION_NED`` with ``MAV_CMD_SET_MESSAGE_INTERVAL`` (``COMMAND_LONG`` addressed to that
system and component), falls back to ``REQUEST_DATA_STREAM`` when the command is refused or
not acknowledged, asks again when a stream stops (an autopilot reboot forgets the
intervals), and says, once, when a stream still does not arrive.
:class:`ParamReader` reads named parameters (``PARAM_REQUEST_READ``, retried).

Both are driven by the caller's receive loop (``on_message(msg, now)``, ``poll(now)``) and send
through a callable taking pymavlink's ``MAVLink`` object, so the sink's reader thread and the
``drovisio autopilot check`` command share them. Times are ``time.monotonic()`` seconds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

__all__ = ["AUTOPILOT_NAMES", "ParamReader", "StreamKeeper", "Vehicle", "is_autopilot_heartbeat"]

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_ACCEPTED = 0
MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_TYPE_GIMBAL = 26
MAV_TYPE_ADSB = 27
MAV_TYPE_CAMERA = 30
MSG_ATTITUDE = 30
MSG_LOCAL_POSITION_NED = 32
MAV_DATA_STREAM_POSITION = 6
MAV_DATA_STREAM_EXTRA1 = 10
AUTOPILOT_NAMES = {3: "ArduPilot", 12: "PX4"}
"""HEARTBEAT ``autopilot`` field → name (MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4)."""

_NOT_VEHICLES = {MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER, MAV_TYPE_GIMBAL, MAV_TYPE_ADSB,
                 MAV_TYPE_CAMERA}


def is_autopilot_heartbeat(msg) -> bool:
    """A HEARTBEAT sent by a flight controller (not a GCS, companion, gimbal or camera)."""
    return (msg.get_type() == "HEARTBEAT" and msg.autopilot != MAV_AUTOPILOT_INVALID
            and msg.type not in _NOT_VEHICLES)


@dataclass
class Vehicle:
    """The flight controller we serve: its ids and what its HEARTBEAT says."""

    system: int
    component: int
    autopilot: int
    """HEARTBEAT ``autopilot`` (3: ArduPilot, 12: PX4)."""
    vehicle_type: int

    @property
    def autopilot_name(self) -> str:
        return AUTOPILOT_NAMES.get(self.autopilot, f"MAV_AUTOPILOT {self.autopilot}")


@dataclass
class _Stream:
    name: str
    msg_id: int
    rate_hz: float
    data_stream: int
    needed_for: str
    mode: str = "waiting"       # waiting → requested → acked | fallback
    sent_at: float = -math.inf
    attempts: int = 0
    first_request: float | None = None
    arrivals: deque = field(default_factory=lambda: deque(maxlen=64))

    def rate(self, now: float, window: float = 2.0) -> float:
        recent = [t for t in self.arrivals if now - t <= window]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)

    def last(self) -> float | None:
        return self.arrivals[-1] if self.arrivals else None


class StreamKeeper:
    """Finds the vehicle and keeps its ``ATTITUDE`` / ``LOCAL_POSITION_NED`` streams coming.

    Args:
        send: ``send(fn)`` calls ``fn(mav)`` with pymavlink's ``MAVLink`` object (under the
            caller's lock).
        system: The vehicle's system id to follow; None: the first autopilot heard.
        needs_position: Whether a missing ``LOCAL_POSITION_NED`` deserves a note (PX4 mode).
        attitude_hz, position_hz: Rates asked for.
        ack_timeout: Seconds to wait for ``COMMAND_ACK`` before asking again.
        attempts: ``SET_MESSAGE_INTERVAL`` attempts before ``REQUEST_DATA_STREAM``.
        missing_after: Seconds after the first request (or after start, with no vehicle
            heard) before a missing stream is reported; also the silence that makes it ask
            again.
    """

    def __init__(self, send: Callable[[Callable[[Any], None]], None], system: int | None,
                 needs_position: bool = False, attitude_hz: float = 50.0,
                 position_hz: float = 20.0, ack_timeout: float = 1.0, attempts: int = 2,
                 missing_after: float = 3.0, start: float = 0.0):
        self._send = send
        self.system = system
        self.needs_position = needs_position
        self.ack_timeout = ack_timeout
        self.max_attempts = attempts
        self.missing_after = missing_after
        self.started = start
        self.vehicle: Vehicle | None = None
        self.streams = {
            MSG_ATTITUDE: _Stream("ATTITUDE", MSG_ATTITUDE, attitude_hz, MAV_DATA_STREAM_EXTRA1,
                                  "roll and pitch for the gravity prior"),
            MSG_LOCAL_POSITION_NED: _Stream("LOCAL_POSITION_NED", MSG_LOCAL_POSITION_NED,
                                            position_hz, MAV_DATA_STREAM_POSITION,
                                            "PX4's absolute target position"),
        }
        self._pending: int | None = None     # the stream whose SET_MESSAGE_INTERVAL awaits its ACK
        self.note: str | None = None
        """Why a stream does not arrive, and what the pose assumes meanwhile (None: all well)."""
        self.notes: list[str] = []
        """Every note given, in order, each once."""
        self.acks: list[int] = []
        """Results of the SET_MESSAGE_INTERVAL acknowledgements received."""
        self.fallbacks = 0

    # ------------------------------------------------------------------ input
    def from_vehicle(self, msg) -> bool:
        """Whether ``msg`` comes from the vehicle we follow (its system; its autopilot
        component, or component 1 before its HEARTBEAT was heard)."""
        src, comp = msg.get_srcSystem(), msg.get_srcComponent()
        if self.vehicle is not None:
            return src == self.vehicle.system and comp == self.vehicle.component
        return (self.system is None or src == self.system) and comp == 1

    def on_message(self, msg, now: float) -> None:
        t = msg.get_type()
        if t == "HEARTBEAT":
            if self.vehicle is None and is_autopilot_heartbeat(msg) and (
                    self.system is None or msg.get_srcSystem() == self.system):
                self.vehicle = Vehicle(msg.get_srcSystem(), msg.get_srcComponent(),
                                       int(msg.autopilot), int(msg.type))
            return
        if not self.from_vehicle(msg):
            return
        if t == "ATTITUDE":
            self.streams[MSG_ATTITUDE].arrivals.append(now)
        elif t == "LOCAL_POSITION_NED":
            self.streams[MSG_LOCAL_POSITION_NED].arrivals.append(now)
        elif t == "COMMAND_ACK" and msg.command == MAV_CMD_SET_MESSAGE_INTERVAL:
            self.acks.append(int(msg.result))
            if self._pending is not None:
                s = self.streams[self._pending]
                if int(msg.result) == MAV_RESULT_ACCEPTED:
                    s.mode = "acked"
                else:     # refused (an older firmware): the old way
                    self._fallback(s)
                self._pending = None

    # ------------------------------------------------------------------ output
    def _request(self, s: _Stream, now: float) -> None:
        v = self.vehicle
        assert v is not None
        interval_us = 1e6 / s.rate_hz
        self._send(lambda mav: mav.command_long_send(
            v.system, v.component, MAV_CMD_SET_MESSAGE_INTERVAL, min(s.attempts, 255),
            float(s.msg_id), interval_us, 0.0, 0.0, 0.0, 0.0, 0.0))
        s.mode, s.sent_at = "requested", now
        s.attempts += 1
        if s.first_request is None:
            s.first_request = now
        self._pending = s.msg_id

    def _fallback(self, s: _Stream) -> None:
        v = self.vehicle
        assert v is not None
        self._send(lambda mav: mav.request_data_stream_send(
            v.system, v.component, s.data_stream, int(round(s.rate_hz)), 1))
        s.mode = "fallback"
        self.fallbacks += 1

    def poll(self, now: float) -> None:
        """Send what is due: requests, retries, fallbacks; update the note."""
        if self.vehicle is not None:
            if self._pending is not None:
                s = self.streams[self._pending]
                if now - s.sent_at >= self.ack_timeout:
                    self._pending = None
                    if s.attempts >= self.max_attempts:
                        self._fallback(s)
                    else:
                        self._request(s, now)
            if self._pending is None:
                for s in self.streams.values():
                    last = s.last()
                    stopped = last is not None and now - last > self.missing_after
                    if s.mode == "waiting" or (stopped and now - s.sent_at > self.missing_after):
                        if stopped:
                            s.attempts = 0
                        self._request(s, now)
                        break
        self._update_note(now)

    def _say(self, text: str | None) -> None:
        self.note = text
        if text is not None and text not in self.notes:
            self.notes.append(text)

    def _update_note(self, now: float) -> None:
        if self.vehicle is None:
            if now - self.started >= self.missing_after:
                who = "" if self.system is None else f" from system {self.system}"
                self._say(f"no autopilot HEARTBEAT{who} after {self.missing_after:g} s: no "
                          "attitude; poses assume level flight (gravity prior)")
            return
        missing = []
        for s in self.streams.values():
            if s.msg_id == MSG_LOCAL_POSITION_NED and not self.needs_position:
                continue
            last = s.last()
            asked = s.first_request is not None and now - s.first_request >= self.missing_after
            if asked and (last is None or now - last > self.missing_after):
                if s.mode == "requested":
                    # still being asked (its ACK, a retry or the fallback is due): the note
                    # waits for the answer, so that it is said once, naming the last way
                    # tried, however late a busy machine polls
                    return
                missing.append(s)
        if not missing:
            self._say(None)
            return
        v = self.vehicle
        names = " and ".join(s.name for s in missing)
        assume = []
        if any(s.msg_id == MSG_ATTITUDE for s in missing):
            assume.append("poses assume level flight (gravity prior)")
        if any(s.msg_id == MSG_LOCAL_POSITION_NED for s in missing):
            assume.append("PX4 targets are sent with position_valid=0")
        how = "REQUEST_DATA_STREAM" if any(s.mode == "fallback" for s in missing) \
            else "SET_MESSAGE_INTERVAL"
        self._say(f"no {names} from {v.autopilot_name} (system {v.system}) although asked "
                  f"({how}): {'; '.join(assume)}")

    def status(self, now: float) -> dict:
        return {s.name: {"mode": s.mode, "rate_hz": round(s.rate(now), 1)}
                for s in self.streams.values()}


class ParamReader:
    """Reads named parameters from the vehicle (``PARAM_REQUEST_READ`` by name, retried).

    Args:
        send: As :class:`StreamKeeper`'s.
        names: Parameter names to read.
        retry: Seconds between requests of a parameter not yet answered.
        attempts: Requests per parameter before it counts as absent.
    """

    def __init__(self, send: Callable[[Callable[[Any], None]], None], names: Iterable[str],
                 retry: float = 0.5, attempts: int = 4):
        self._send = send
        self.names = list(dict.fromkeys(names))
        self.values: dict[str, float] = {}
        self._asked: dict[str, tuple[int, float]] = {}
        self._stale: set[str] = set()
        self.retry = retry
        self.attempts = attempts

    def on_message(self, msg, vehicle: Vehicle | None) -> None:
        if msg.get_type() != "PARAM_VALUE" or vehicle is None or \
                msg.get_srcSystem() != vehicle.system:
            return
        name = msg.param_id
        if isinstance(name, bytes):
            name = name.decode("ascii", "replace")
        name = name.rstrip("\x00")
        if name in self.names:
            self.values[name] = float(msg.param_value)
            self._stale.discard(name)

    def poll(self, now: float, vehicle: Vehicle | None, burst: int = 8) -> None:
        """Ask for up to ``burst`` parameters that are due (a serial link is slow)."""
        if vehicle is None:
            return
        n = 0
        for name in self.names:
            if name in self.values and name not in self._stale:
                continue
            k, t = self._asked.get(name, (0, -math.inf))
            if k >= self.attempts and now - t >= self.retry and name in self._stale:
                self.values.pop(name, None)     # gone since (hidden, or another firmware)
                self._stale.discard(name)
            if k >= self.attempts or now - t < self.retry:
                continue
            self._send(self._reader_for(vehicle, name))
            self._asked[name] = (k + 1, now)
            n += 1
            if n >= burst:
                break

    @staticmethod
    def _reader_for(vehicle: Vehicle, name: str) -> Callable[[Any], None]:
        def ask(mav) -> None:
            mav.param_request_read_send(vehicle.system, vehicle.component,
                                        name.encode("ascii"), -1)
        return ask

    def refresh(self) -> None:
        """Ask for every parameter again (values kept until answered anew)."""
        self._asked.clear()
        self._stale = set(self.values)

    def done(self, now: float) -> bool:
        """Every parameter answered, or asked ``attempts`` times and not answered since."""
        for n in self.names:
            if n in self.values and n not in self._stale:
                continue
            k, t = self._asked.get(n, (0, now))
            if k < self.attempts or now - t < self.retry:
                return False
        return True

    def absent(self) -> list[str]:
        return [n for n in self.names if n not in self.values]
