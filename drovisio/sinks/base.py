"""The sink protocol, and the one count of what a sink delivered."""

from __future__ import annotations

import threading
from typing import Protocol
from urllib.parse import urlsplit

from drovisio.errors import one_line

__all__ = ["Delivery", "Sink", "SinkError", "host_port"]


class SinkError(ValueError):
    """A sink that cannot be opened (bad spec, unusable path).

    A sink raises it with what is wrong and what to do, never with its SINK string:
    :func:`drovisio.sinks.open_sink`, the one way every sink is opened, raises it again with
    the spec, said once in front (``--sink SPEC: why; what to do``), so that no sink's own
    wording can say the spec twice.

    Args:
        why: What is wrong and what to do.
        spec: The SINK string, given only by :func:`drovisio.sinks.open_sink`.
    """

    def __init__(self, why: str, spec: str | None = None) -> None:
        self.why = why
        self.spec = spec
        super().__init__(why if spec is None
                         else f"--sink {one_line(spec, 80)}: {one_line(why, 300)}")


def host_port(url: str, example: str, port_zero: bool = False) -> tuple[str, int]:
    """``SCHEME://HOST:PORT`` → (host, port), for the sinks written so.

    Args:
        url: The SINK string.
        example: One written right (``udp://127.0.0.1:9870``), said in the refusal.
        port_zero: Port 0 is taken (a server's: any free port).

    Raises:
        SinkError: no host, no port, or a port out of range.
    """
    scheme = example.partition("://")[0]
    low = 0 if port_zero else 1
    u = urlsplit(url)
    try:
        port = u.port
    except ValueError:        # out of range, or not a number
        port = None
    if not u.hostname or port is None or port < low:
        raise SinkError(f"expected {scheme}://HOST:PORT with a port {low}-65535, e.g. "
                        f"{example}")
    return u.hostname, port


class Sink(Protocol):
    name: str

    def send(self, output) -> None: ...

    def close(self) -> None: ...

    def status(self) -> dict: ...


class Delivery:
    """What a sink delivered and what it did not: every sink counts through one of these.

    A message is ``sent`` only once its link or file took it. One its link dropped (closed,
    not connected: nothing was written) is ``lost``; one whose write failed is in ``errors``
    (``last_error``). From either until a write goes through again the sink is ``down``
    (why, in words), so that ``drovisio run`` says each loss once as it starts and once as it
    ends (:class:`drovisio.commands.run.Alarms`). Thread-safe: a sink may write from its own
    thread too (the MAVLink heartbeats).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.sent = 0
        self.lost = 0
        self.errors = 0
        self.last_error: str | None = None
        self.down: str | None = None

    def delivered(self, count: bool = True) -> None:
        """A write went through (``count``: one of the sink's messages, not a heartbeat)."""
        with self._lock:
            self.sent += int(count)
            self.down = None

    def dropped(self, why: str, count: bool = True) -> None:
        """The link dropped a write (``why``: what is wrong and what to check)."""
        with self._lock:
            self.lost += int(count)
            self.down = why

    def failed(self, why: str) -> None:
        """A write failed (disk full, closed pipe, unreachable network)."""
        with self._lock:
            self.errors += 1
            self.last_error = self.down = why

    def note(self, why: str) -> None:
        """A problem that lost no message (a read that failed): ``last_error`` only."""
        with self._lock:
            self.last_error = why

    def status(self) -> dict:
        """The sink status's counts: ``sent``, ``lost``, ``errors``, ``last_error``,
        ``down``."""
        with self._lock:
            return {"sent": self.sent, "lost": self.lost, "errors": self.errors,
                    "last_error": self.last_error, "down": self.down}
