"""MAVLink connection strings and pymavlink in MAVLink 2: what the sink
(:class:`drovisio.sinks.mavlink.MavlinkSink`) and ``drovisio autopilot check``
(:mod:`drovisio.autopilot.session`) both need before they open a link.

A connection string is pymavlink's (``udpout:127.0.0.1:14550``, ``tcp:127.0.0.1:5760``,
``/dev/ttyAMA0,921600``) with our ids as options (``?sysid=N&compid=M``). What cannot be
used raises :class:`AddressError`, in one line naming the connection; each caller says it
in its own error type.
"""

from __future__ import annotations

import os
import socket
from typing import Any

from drovisio.errors import LIMITS

__all__ = ["AddressError", "check_host", "mavutil2", "parse_connection", "split_connection"]


class AddressError(ValueError):
    """A MAVLink connection string that cannot be used (the message names it)."""


def mavutil2() -> Any:
    """pymavlink's ``mavutil`` switched to MAVLink 2 (LANDING_TARGET's position fields are
    MAVLink 2 extensions). pymavlink keeps this choice process-wide."""
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil  # deferred: heavy, and the environment must be set first

    if str(mavutil.mavlink.WIRE_PROTOCOL_VERSION) != "2.0":
        mavutil.set_dialect(mavutil.current_dialect or "common")
    return mavutil


def parse_connection(spec: str) -> tuple[str, dict[str, int]]:
    """``udpout:127.0.0.1:14550?sysid=2&compid=191`` → (connection, {"sysid": 2, ...}).

    Raises:
        AddressError: an unknown option or an id outside 1-255 (named).
    """
    conn, sep, query = spec.partition("?")
    opts: dict[str, int] = {}
    if not sep:
        return conn, opts
    for part in query.split("&"):
        key, eq, value = part.partition("=")
        if key not in ("sysid", "compid"):
            raise AddressError(f"mavlink:{spec}: unknown option {key!r}: use "
                               "?sysid=N&compid=M")
        if not eq or not value.strip().isdigit() or not 1 <= int(value) <= 255:
            raise AddressError(f"mavlink:{spec}: {key}: expected a whole number 1-255, "
                               f"got {value!r}")
        opts[key] = int(value)
    return conn, opts


def split_connection(conn: str) -> tuple[str, int | None]:
    """``/dev/ttyAMA0,921600`` → (device, baud)."""
    dev, sep, baud = conn.rpartition(",")
    if sep and baud.isdigit() and ":" not in baud:
        return dev, int(baud)
    return conn, None


def check_host(name: str, dev: str) -> None:
    """An unknown host name fails loudly here: pymavlink's UDP writer would drop every
    message silently.

    Raises:
        AddressError: a malformed HOST:PORT, an unknown host, or a TCP peer that does not
            answer (named by ``name``).
    """
    kind, _, rest = dev.partition(":")
    if kind not in ("udp", "udpin", "udpout", "udpbcast", "tcp", "tcpin") or not rest:
        return
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise AddressError(f"{name}: expected {kind}:HOST:PORT (e.g. {kind}:127.0.0.1:14550)")
    try:
        socket.getaddrinfo(host, int(port))
    except (socket.gaierror, UnicodeError) as e:
        raise AddressError(f"{name}: unknown host {host!r} ({e}); check the address") from None
    if kind == "tcp":
        _probe_tcp(name, host, int(port))


def _probe_tcp(name: str, host: str, port: int) -> None:
    """Connect once with a deadline before pymavlink does: its connect has none (a silent
    peer blocks ~7 minutes) and it retries a refused one for seconds."""
    deadline = LIMITS.connect_timeout_s
    try:
        with socket.create_connection((host, port), timeout=deadline):
            pass
    except TimeoutError:
        raise AddressError(f"{name}: no answer from {host}:{port} within {deadline:g} s; is "
                           "the autopilot (or its TCP bridge) on and is the address right?"
                           ) from None
    except OSError as e:
        raise AddressError(f"{name}: cannot connect to {host}:{port} ({e.strerror or e}); is "
                           "the autopilot (or its TCP bridge) listening there?") from None
