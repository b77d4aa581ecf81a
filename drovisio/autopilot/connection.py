"""MAVLink connection strings and pymavlink in MAVLink 2: what the sink
(:class:`drovisio.sinks.mavlink.MavlinkSink`) and ``drovisio autopilot check``
(:mod:`drovisio.autopilot.session`) both need before they open a link.

A connection string is pymavlink's (``udpout:127.0.0.1:14550``, ``tcp:127.0.0.1:5760``,
``/dev/ttyAMA0,921600``) with our ids as options (``?sysid=N&compid=M``). What cannot be
used raises :class:`AddressError`, in one line naming the connection; each caller says it
in its own error type. Both open their link with :func:`open_link`.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import select
import socket
import threading
import time
from typing import Any

from drovisio._threads import join_thread
from drovisio.errors import LIMITS

__all__ = ["AddressError", "LinkClosed", "LinkDown", "check_host", "mavutil2", "open_link",
           "parse_connection", "split_connection"]

#: Least time between two attempts to connect a closed TCP link again (the sink's).
RECONNECT_EVERY_S = 1.0
#: How often an attempt to connect again looks whether its link was closed meanwhile.
_CONNECT_STEP_S = 0.05


class AddressError(ValueError):
    """A MAVLink connection string that cannot be used: ``NAME: why``.

    Args:
        name: How the connection is named (``mavlink:...``, or as the user gave it).
        why: What is wrong and what to do; kept apart so that a caller that names the
            connection itself (the sink's ``--sink SPEC: ...``) says it once.
    """

    def __init__(self, name: str, why: str) -> None:
        self.name = name
        self.why = why
        super().__init__(f"{name}: {why}")


class LinkDown(ConnectionError):
    """A message the link could not send now: nothing (or not all of it) went out. The
    message names the connection and what to check; the caller counts the message as lost,
    never as sent."""


class LinkClosed(LinkDown):
    """The other end of a TCP link closed it, or a serial device stopped answering (and, for
    a link that reconnects, it could not be made again yet); the message names the address
    or device and what to check."""


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
            raise AddressError(f"mavlink:{spec}", f"unknown option {key!r}: use "
                               "?sysid=N&compid=M")
        if not eq or not value.strip().isdigit() or not 1 <= int(value) <= 255:
            raise AddressError(f"mavlink:{spec}", f"{key}: expected a whole number 1-255, "
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
        raise AddressError(name, f"expected {kind}:HOST:PORT (e.g. {kind}:127.0.0.1:14550)")
    try:
        socket.getaddrinfo(host, int(port))
    except (socket.gaierror, UnicodeError) as e:
        raise AddressError(name, f"unknown host {host!r} ({e}); check the address") from None
    if kind == "tcp":
        _probe_tcp(name, host, int(port))


def open_link(name: str, conn: str, *, source_system: int, source_component: int,
              reconnect: bool = False) -> Any:
    """pymavlink's connection to ``conn`` (``DEVICE[,BAUD]``), opened the one way the sink
    and ``autopilot check`` both use: the address checked first (:func:`check_host`),
    MAVLink 2, pymavlink's own messages kept off stdout, and a TCP link or a serial port
    bounded (:func:`_bounded_tcp`, :func:`_bounded_serial`): a write it cannot send raises
    :class:`LinkDown` instead of being dropped in silence.

    Args:
        name: How messages name the connection (``mavlink:...`` or the string given).
        reconnect: Connect a closed TCP link again, and open a dead serial port again, at
            most once a second, when it is next used.

    Raises:
        AddressError: an address that cannot be used or opened (one line naming it).
    """
    dev, baud = split_connection(conn)
    check_host(name, dev)
    mavutil = mavutil2()
    try:
        # pymavlink prints its TCP connect retries on stdout: the one line below says it
        with contextlib.redirect_stdout(io.StringIO()):
            link = mavutil.mavlink_connection(dev, source_system=source_system,
                                              source_component=source_component,
                                              autoreconnect=reconnect, retries=1,
                                              **({"baud": baud} if baud else {}))
    except Exception as e:  # noqa: BLE001 - pymavlink raises anything on a bad device
        raise AddressError(name, f"cannot open the MAVLink connection ({e}); check the "
                           "device (or address) and that no other program holds it") from None
    if isinstance(link, mavutil.mavtcp):     # and its Unix-socket kind
        _bounded_tcp(link, name, reconnect)
    elif isinstance(link, mavutil.mavserial):
        _bounded_serial(link, name, reconnect)
    elif isinstance(link, mavutil.mavudp):
        _bounded_udp(link, name)
    return link


def _bounded_tcp(link: Any, name: str, reconnect: bool) -> None:
    """A pymavlink TCP link whose closing raises :class:`LinkClosed` once per use.

    pymavlink prints "EOF on TCP socket" and returns at every read of a link the other end
    closed; the socket stays readable, so a read loop printed it hundreds of thousands of
    times a second; and it drops every write while the link is closed (or its peer is not
    reading) without a word. Here a closed link is shut on our side, each read, write or
    reconnect raises :class:`LinkClosed` (the callers say it in one line, or count the
    message as lost), a write the peer has no room for raises :class:`LinkDown`, and a link
    that reconnects tries once per :data:`RECONNECT_EVERY_S`, each try within that time,
    never pymavlink's retries with their sleeps. Closing the link ends a try under way
    (:func:`_connect` gives up once told) and waits for its thread (``join_thread``).
    """
    addr = link.destination_addr            # (host, port), or a Unix socket's path
    where = f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else str(addr)
    closed = (f"{name}: {where} closed the connection; check that the address is a "
              "MAVLink TCP server's (the autopilot's, SITL's or mavlink-router's) and that no "
              "other program holds its connection")
    next_try = [0.0]
    # a connect runs on its own thread: a peer that drops packets holds it up to its
    # deadline, and the link is used from the pipeline's thread (a frame must not wait)
    attempt: dict[str, Any] = {"thread": None, "sock": None, "error": None}
    # the reader's thread and the writer's both reconnect: one takes a connected socket
    lock = threading.Lock()
    closing = threading.Event()

    def shut() -> None:
        if link.port is not None:
            with contextlib.suppress(OSError):
                link.port.close()
        link.port = None
        link.fd = None    # pymavlink then waits instead of polling a dead descriptor
        raise LinkClosed(closed)

    def try_connect() -> None:
        try:
            sock = _connect(addr, min(RECONNECT_EVERY_S, LIMITS.connect_timeout_s), closing)
        except OSError as e:
            attempt["error"] = e.strerror or str(e)
            return
        with lock:
            attempt["sock"] = sock        # close() closes one it connected too late

    def connect_again() -> None:
        if not reconnect or not isinstance(addr, tuple):
            raise LinkClosed(closed)
        with lock:
            if closing.is_set():          # closed: no new attempt, no socket handed over
                raise LinkClosed(closed)
            if link.port is not None:     # the other thread took a connected socket
                return
            sock, attempt["sock"] = attempt["sock"], None
            if sock is not None:          # the last attempt connected: use it
                link.port = sock
                link.fd = sock.fileno()
                return
            error, attempt["error"] = attempt["error"], None
            now = time.monotonic()
            busy = attempt["thread"] is not None and attempt["thread"].is_alive()
            if not busy and now >= next_try[0]:
                next_try[0] = now + RECONNECT_EVERY_S
                attempt["thread"] = threading.Thread(target=try_connect, daemon=True,
                                                     name="mavlink-reconnect")
                attempt["thread"].start()
        raise LinkClosed(closed + (f" (connecting again: {error})" if error else ""))

    def write(buf: bytes) -> None:
        port = link.port
        if port is None:
            connect_again()               # raises until a reconnect has connected
            port = link.port
        try:
            n = port.send(buf)
        except BlockingIOError:
            n = 0
        except OSError:                   # reset, broken pipe, or shut by the reader
            if link.port is port:
                shut()
            raise LinkClosed(closed) from None
        if n < len(buf):   # the cut message is skipped by the peer's parser at the next one
            raise LinkDown(f"{name}: {where} is not reading what is sent (its buffer is full); "
                           "check that the peer reads the link")

    def close() -> None:
        with lock:                        # no attempt starts after this
            closing.set()
            thread = attempt["thread"]
        join_thread(thread, f"connecting to {where} again")
        with lock:
            socks, attempt["sock"] = (attempt["sock"], link.port), None
            link.port = link.fd = None
        for sock in socks:
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()

    link.handle_eof = shut
    link.handle_disconnect = shut
    link.reconnect = connect_again
    link.write = write
    link.close = close


def _connect(addr: tuple[str, int], timeout: float, stop: threading.Event
             ) -> socket.socket | None:
    """A non-blocking TCP connection to ``addr``, made within ``timeout`` seconds.

    A peer that drops packets would hold a plain connect to its deadline: this one also
    gives up as soon as ``stop`` is set (its link was closed), so that a close waits for
    no deadline.

    Returns:
        The connected socket (``TCP_NODELAY``); None once ``stop`` was set.

    Raises:
        OSError: refused, unreachable, or no answer within ``timeout`` (TimeoutError).
    """
    end = time.monotonic() + timeout
    error: OSError = TimeoutError(errno.ETIMEDOUT, "timed out")
    for family, kind, proto, _, sockaddr in socket.getaddrinfo(*addr, type=socket.SOCK_STREAM):
        sock = socket.socket(family, kind, proto)
        try:
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            err = sock.connect_ex(sockaddr)
            while err in (errno.EINPROGRESS, errno.EALREADY, errno.EWOULDBLOCK):
                left = end - time.monotonic()
                if stop.is_set() or left <= 0:
                    break
                if select.select([], [sock], [], min(left, _CONNECT_STEP_S))[1]:
                    err = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            if err == 0:
                return sock
            sock.close()
            if stop.is_set():
                return None
            error = (TimeoutError(errno.ETIMEDOUT, "timed out")
                     if err in (errno.EINPROGRESS, errno.EALREADY, errno.EWOULDBLOCK)
                     else OSError(err, os.strerror(err)))
        except OSError as e:
            sock.close()
            error = e
    raise error


def _bounded_serial(link: Any, name: str, reconnect: bool) -> None:
    """A pymavlink serial port whose failing write raises :class:`LinkClosed`.

    pymavlink prints "Device ... is dead" on stdout (where ``jsonl:-`` writes), drops that
    write and every later one without a word, and reopens the port at each write, printing
    again when it works. Here a failed write raises :class:`LinkClosed` naming the device
    and what to check (the callers say it in one line, or count the message as lost), and a
    port that reconnects is opened again at most once per :data:`RECONNECT_EVERY_S`,
    silently.
    """
    dead = (f"{name}: {link.device} stopped answering; check the cable (or USB adapter) and "
            "that the flight controller is powered" + ("; opening it again once a second"
                                                       if reconnect else ""))
    next_try = [0.0]

    def reopen() -> bool:
        import serial  # pymavlink's own dependency, loaded by its serial link already

        now = time.monotonic()
        if not reconnect or now < next_try[0]:
            return False
        next_try[0] = now + RECONNECT_EVERY_S
        try:
            port = serial.Serial(link.device, link.baud, timeout=0, dsrdtr=False,
                                 rtscts=False, xonxoff=False)
        except (OSError, ValueError, serial.SerialException):
            return False
        with contextlib.suppress(Exception):
            link.port.close()
        link.port = port
        link.fd = port.fileno()
        link.portdead = False
        return True

    def write(buf: bytes) -> None:
        if link.portdead and not reopen():
            raise LinkClosed(dead)
        try:
            link.port.write(bytes(buf))
        except Exception as e:  # noqa: BLE001 - pyserial raises several kinds for a lost port
            link.portdead = True
            raise LinkClosed(f"{dead} ({e})") from None

    link.write = write


class _SendErrors:
    """A UDP socket that keeps what its last ``sendto`` raised (pymavlink's write swallows
    it); everything else is the socket's."""

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        self.error: OSError | None = None

    def sendto(self, *args: Any) -> int:
        try:
            return self._sock.sendto(*args)
        except OSError as e:
            self.error = e
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sock, name)


def _bounded_udp(link: Any, name: str) -> None:
    """A pymavlink UDP link whose unsent write raises :class:`LinkDown`.

    pymavlink drops a datagram the network refuses (no route, a full send buffer) without a
    word, and a listening link (``udpin:``) sends to nobody until a peer has sent to it: both
    were counted as sent. Here each raises :class:`LinkDown` naming why (the callers count
    the message as lost and say it once)."""
    sock = _SendErrors(link.port)
    link.port = sock
    wrote = link.write
    port = link.port.getsockname()[1] if link.udp_server else None
    nobody = (f"{name}: no MAVLink peer has sent to port {port} yet, so there is nobody to "
              "send to; start the autopilot (or mavlink-router) that sends there, or give "
              "udpout:HOST:PORT to send first")

    def write(buf: bytes) -> None:
        if link.udp_server and not link.clients:
            raise LinkDown(nobody)
        sock.error = None
        wrote(buf)
        if sock.error is not None:
            e = sock.error
            raise LinkDown(f"{name}: the datagram was not sent ({e.strerror or e}); check the "
                           "address and the network (or that the peer reads the link)")

    link.write = write


def _probe_tcp(name: str, host: str, port: int) -> None:
    """Connect once with a deadline before pymavlink does: its connect has none (a silent
    peer blocks ~7 minutes) and it retries a refused one for seconds."""
    deadline = LIMITS.connect_timeout_s
    try:
        with socket.create_connection((host, port), timeout=deadline):
            pass
    except TimeoutError:
        raise AddressError(name, f"no answer from {host}:{port} within {deadline:g} s; is "
                           "the autopilot (or its TCP bridge) on and is the address right?"
                           ) from None
    except OSError as e:
        raise AddressError(name, f"cannot connect to {host}:{port} ({e.strerror or e}); is "
                           "the autopilot (or its TCP bridge) listening there?") from None
