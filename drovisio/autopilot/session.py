"""``drovisio autopilot check``'s conversation with the vehicle, every wait bounded.

Opens the link as Drovisio's sink would (same ids), sends its HEARTBEAT, waits for the
vehicle's, reads the parameters :func:`drovisio.autopilot.check.param_names` lists, asks for
the streams the sink needs and measures how fast they come, all within one deadline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drovisio.autopilot.check import Facts, param_names
from drovisio.autopilot.connection import (
    AddressError,
    LinkClosed,
    LinkDown,
    mavutil2,
    open_link,
    parse_connection,
    split_connection,
)
from drovisio.autopilot.link import MSG_ATTITUDE, MSG_LOCAL_POSITION_NED, ParamReader, StreamKeeper
from drovisio.errors import InputError

__all__ = ["NoVehicle", "read_vehicle"]


class NoVehicle(InputError):
    """Nothing answered on the connection within the deadline."""


@dataclass
class _Link:
    conn: Any
    """pymavlink's connection."""

    def send(self, fn: Callable[[Any], object]) -> None:
        try:
            fn(self.conn.mav)
        except LinkDown as e:
            if isinstance(e, LinkClosed):
                raise
            # a request not sent now (no peer yet on udpin:, a full buffer) is sent again
            # by the conversation; no answer in time is said as "no HEARTBEAT"


def read_vehicle(connection: str, flavour: str, *, timeout_s: float = 5.0,
                 stream_s: float = 2.0) -> Facts:
    """Read what :func:`drovisio.autopilot.check.evaluate` needs from the vehicle.

    Args:
        connection: ``mavlink:`` connection string, optionally ``?sysid=N&compid=M``.
        flavour: What Drovisio sends (``ardupilot`` or ``px4``).
        timeout_s: Deadline for the vehicle's HEARTBEAT, then again for its parameters.
        stream_s: Seconds over which the streams' rates are measured once they come.

    Raises:
        NoVehicle: no autopilot HEARTBEAT within ``timeout_s`` (one line naming the
            connection and what to look at).
        InputError: a connection string that cannot be opened.
    """
    try:
        conn_str, ids = parse_connection(connection)
        dev, baud = split_connection(conn_str)
        conn = open_link(connection, conn_str, source_system=ids.get("sysid", 1),
                         source_component=ids.get("compid", 191))
    except AddressError as e:
        raise InputError(str(e)) from None
    mavutil = mavutil2()
    link = _Link(conn)
    t0 = time.monotonic()
    keeper = StreamKeeper(link.send, ids.get("sysid"), needs_position=flavour == "px4",
                          start=t0, missing_after=max(1.0, stream_s))
    serial = baud is not None or dev.startswith(("/dev/", "COM"))
    params = ParamReader(link.send, param_names(flavour, serial), retry=0.4, attempts=3)
    try:
        try:
            _converse(link, keeper, params, mavutil.mavlink, t0, timeout_s, stream_s,
                      lambda: _no_vehicle(connection, ids, timeout_s))
        except LinkClosed as e:
            raise InputError(str(e)) from None
        v = keeper.vehicle
        assert v is not None   # the conversation ends only once the vehicle answered
        now = time.monotonic()
        pos = keeper.streams[MSG_LOCAL_POSITION_NED]
        return Facts(flavour=flavour, autopilot=v.autopilot, system=v.system,
                     params=dict(params.values), params_asked=True, serial=serial,
                     attitude_hz=keeper.streams[MSG_ATTITUDE].rate(now, stream_s),
                     position_hz=pos.rate(now, stream_s))
    finally:
        try:
            conn.close()
        except Exception:  # noqa: BLE001
            pass


def _no_vehicle(connection: str, ids: dict[str, int], timeout_s: float) -> NoVehicle:
    who = f"system {ids['sysid']}'s autopilot" if "sysid" in ids else "an autopilot"
    return NoVehicle(f"{connection}: no HEARTBEAT from {who} within "
                     f"{timeout_s:g} s: check the address (udpin: to listen, "
                     "udpout: to send first), the cable and baud rate, and that "
                     "the flight controller's port speaks MAVLink")


def _converse(link: _Link, keeper: StreamKeeper, params: ParamReader, m: Any, t0: float,
              timeout_s: float, stream_s: float, no_vehicle: Callable[[], NoVehicle]) -> None:
    """Heartbeats out, messages in, until the vehicle answered, its parameters are read and
    its streams measured for ``stream_s`` (or the parameters' deadline passed).

    Raises:
        NoVehicle: no HEARTBEAT within ``timeout_s`` of ``t0``.
    """
    next_hb = 0.0
    deadline = t0 + timeout_s
    streams_from: float | None = None
    while True:
        now = time.monotonic()
        if now >= next_hb:
            link.send(lambda mav: mav.heartbeat_send(m.MAV_TYPE_ONBOARD_CONTROLLER,
                                                     m.MAV_AUTOPILOT_INVALID, 0, 0,
                                                     m.MAV_STATE_ACTIVE))
            next_hb = now + 1.0
        if keeper.vehicle is None and now >= deadline:
            raise no_vehicle()
        if keeper.vehicle is not None and deadline <= t0 + timeout_s:
            deadline = now + timeout_s        # a second deadline for the parameters
        a = keeper.streams[MSG_ATTITUDE]
        if streams_from is None and a.first_request is not None:
            streams_from = now
        streams_done = streams_from is not None and now - streams_from >= stream_s + 1.0
        if keeper.vehicle is not None and (params.done(now) and streams_done
                                           or now >= deadline):
            return
        msg = link.conn.recv_match(blocking=True, timeout=0.05)
        now = time.monotonic()
        if msg is not None and msg.get_type() != "BAD_DATA":
            keeper.on_message(msg, now)
            params.on_message(msg, keeper.vehicle)
        keeper.poll(now)
        params.poll(now, keeper.vehicle)
