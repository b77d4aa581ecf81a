"""Closing a ``mavlink:`` sink ends and waits for every thread its link started: the reader,
and an attempt to connect a closed TCP link again that is still waiting for a peer that does
not answer (ended at once, never waited out to its deadline)."""

from __future__ import annotations

import socket
import threading

import pytest

import drovisio.autopilot.connection as connection
from drovisio.errors import LIMITS
from drovisio.sinks.mavlink import MavlinkSink

HANG = 60.0
"""Seconds: a bound that turns a hang into a failure, nothing measured by it."""


class SilentAfterTwo:
    """A loopback TCP server that accepts the sink's two connections (the start-up probe and
    the link), then accepts nothing: its backlog is filled, so that a new connect's SYNs are
    dropped, as by a peer gone behind a firewall."""

    def __init__(self) -> None:
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(0)
        self.port = self.server.getsockname()[1]
        self.conns: list[socket.socket] = []
        self.fillers: list[socket.socket] = []
        self._accepting = threading.Thread(target=self._accept_two, daemon=True)
        self._accepting.start()

    def _accept_two(self) -> None:
        for _ in range(2):
            self.conns.append(self.server.accept()[0])

    def go_silent(self) -> None:
        """Stop answering new connects, then close the link (the peer went away)."""
        self._accepting.join(HANG)
        assert len(self.conns) == 2, "the sink did not connect"
        for _ in range(4):
            c = socket.socket()
            c.setblocking(False)
            try:
                c.connect(("127.0.0.1", self.port))
            except BlockingIOError:
                pass
            self.fillers.append(c)
        probe = socket.socket()
        probe.settimeout(0.3)
        try:
            probe.connect(("127.0.0.1", self.port))
            pytest.skip("this kernel accepts past a full backlog: no silent peer")
        except TimeoutError:
            pass
        finally:
            probe.close()
        for c in self.conns:
            c.close()

    def close(self) -> None:
        for c in [*self.conns, *self.fillers, self.server]:
            c.close()


def _attempts(before: set[threading.Thread]) -> list[threading.Thread]:
    return [t for t in threading.enumerate()
            if t.name.startswith("mavlink-reconnect") and t not in before and t.is_alive()]


def test_close_ends_and_waits_for_a_pending_reconnect_attempt(monkeypatch, until):
    # an attempt would wait for the silent peer far longer than the test's bound: only
    # an attempt that the close ends lets the close return
    monkeypatch.setattr(connection, "RECONNECT_EVERY_S", 600.0)
    monkeypatch.setattr(LIMITS, "connect_timeout_s", 600.0)
    peer = SilentAfterTwo()
    before = set(threading.enumerate())
    sink = MavlinkSink(f"tcp:127.0.0.1:{peer.port}")
    try:
        peer.go_silent()
        [attempt] = until(lambda: _attempts(before), HANG)   # connecting again, unanswered
        reader = sink._thread
        closer = threading.Thread(target=sink.close, daemon=True, name="closer")
        closer.start()
        closer.join(HANG)
        assert not closer.is_alive(), "close waited out the attempt's deadline"
        assert not attempt.is_alive(), "close returned with the attempt still running"
        assert not reader.is_alive()
        assert _attempts(before) == [], "an attempt started after the close"
    finally:
        sink.close()
        peer.close()
