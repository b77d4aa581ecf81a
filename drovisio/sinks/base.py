"""The sink protocol, and the one count of what a sink delivered."""

from __future__ import annotations

import threading
from typing import Protocol

__all__ = ["Delivery", "Sink", "SinkError"]


class SinkError(ValueError):
    """A sink that cannot be opened (bad spec, unusable path)."""


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
