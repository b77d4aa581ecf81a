"""A sink counts as sent only what its link or file took: a message dropped while its link is
down (a MAVLink TCP peer gone, a serial port dead, nobody on Zenoh) or whose write failed is
counted as not sent, said once when the loss starts and once when it ends, and ``run``'s end
says how many were not sent."""

from __future__ import annotations

import os
import re
import select
import socket
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from drovisio.cli import main
from drovisio.commands.run import Alarms
from drovisio.geometry import from_rvec_tvec
from drovisio.pipeline import FrameOutput
from drovisio.sinks import open_sink
from drovisio.sinks.mavlink import MavlinkSink, mavutil2
from drovisio.tracking import TrackedBrick

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"
DEADLINE_S = 30.0
"""Generous: only a failing test waits this long."""


def _target() -> FrameOutput:
    """A frame whose target was measured in it (a LANDING_TARGET is sent for it)."""
    rvec, tvec = np.array([3.1, 0.0, 0.0]), np.array([0.1, 0.0, 1.0])
    b = TrackedBrick("drick-aruco-centre", 1, 7, "aruco", rvec, tvec, np.eye(6) * 1e-4,
                     time.time(), time.time(), 0.0, True,
                     last_measured=from_rvec_tvec(rvec, tvec))
    return FrameOutput("cam", 1, 1, time.time(), time.monotonic(), [b], target=b)


def _said(alarms: Alarms, *sinks) -> list[str]:
    """What ``drovisio run`` says on a line of its own for this status of the sinks."""
    st = SimpleNamespace(source=SimpleNamespace(state="live", label="cam", error=None),
                         unfit_frames=0, unfit=None, sinks=[s.status() for s in sinks])
    return alarms.new(st)


class Autopilot:
    """A MAVLink TCP server on loopback standing in for the autopilot, counting the
    LANDING_TARGETs it reads. ``go()`` closes its connections and stops listening (the peer
    went away), as it does by itself once it accepted ``leave_after`` connections;
    ``come_back()`` listens again on the same port."""

    def __init__(self, leave_after: int | None = None) -> None:
        self.targets = 0
        self.accepted = 0
        self.leave_after = leave_after
        self.port = 0
        self._listen()

    def _listen(self) -> None:
        self.server = socket.create_server(("127.0.0.1", self.port))
        self.port = self.server.getsockname()[1]
        self.conns: list[socket.socket] = []
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, args=(self.server, self.conns, self.stop),
                                   daemon=True)
        self.th.start()

    def _run(self, server, conns, stop) -> None:
        mav = mavutil2().mavlink.MAVLink(None)
        mav.robust_parsing = True
        while not stop.is_set():
            ready, _, _ = select.select([server, *conns], [], [], 0.05)
            for s in ready:
                if s is server:
                    conns.append(server.accept()[0])
                    self.accepted += 1
                    if self.accepted == self.leave_after:
                        self._close(server, conns)
                        return
                    continue
                data = s.recv(4096)
                if not data:
                    conns.remove(s)
                    s.close()
                    continue
                for m in mav.parse_buffer(data) or []:
                    self.targets += m.get_type() == "LANDING_TARGET"

    @staticmethod
    def _close(server, conns) -> None:
        for c in conns:
            c.close()
        server.close()

    def go(self) -> None:
        self.stop.set()
        self.th.join(DEADLINE_S)
        self._close(self.server, self.conns)

    def come_back(self) -> None:
        self._listen()


def test_a_mavlink_tcp_peer_gone_counts_lost_not_sent_and_says_it_once(capfd, until):
    peer = Autopilot()
    sink = MavlinkSink(f"tcp:127.0.0.1:{peer.port}")
    name = f"mavlink:tcp:127.0.0.1:{peer.port}"
    alarms = Alarms("cam.yaml")
    try:
        for _ in range(3):
            sink.send(_target())
        until(lambda: peer.targets == 3, DEADLINE_S)
        st = sink.status()
        assert (st["sent"], st["lost"], st["down"]) == (3, 0, None)
        assert _said(alarms, sink) == []

        peer.go()
        # the peer's kernel may take one more write before the link is known closed
        until(lambda: sink.status()["down"] is not None, DEADLINE_S,
              step=lambda: sink.send(_target()))
        sent, lost = sink.status()["sent"], sink.status()["lost"]
        said = _said(alarms, sink)
        assert len(said) == 1, said
        assert said[0].startswith(f"sink {name} lost (127.0.0.1:{peer.port} closed the "
                                  "connection; check that the address is a MAVLink TCP "
                                  "server's")
        assert said[0].endswith("; its messages are not sent until it comes back")
        for _ in range(5):
            sink.send(_target())
        st = sink.status()
        assert (st["sent"], st["lost"]) == (sent, lost + 5)   # not sent: lost
        assert _said(alarms, sink) == []                        # said once

        peer.come_back()     # reconnected at most once a second, on the next use
        until(lambda: sink.status()["sent"] > sent, DEADLINE_S,
              step=lambda: sink.send(_target()))
        st = sink.status()
        assert st["down"] is None and st["lost"] >= lost + 5
        assert _said(alarms, sink) == [f"sink {name} back ({st['lost']} messages not sent "
                                       "meanwhile)"]
        until(lambda: peer.targets >= 3 + st["sent"] - sent, DEADLINE_S)
    finally:
        sink.close()
        peer.go()
    cap = capfd.readouterr()
    assert cap.out == "" and cap.err == ""     # pymavlink's own prints kept off


def test_run_ends_saying_how_many_targets_were_not_sent(capsys):
    peer = Autopilot(leave_after=2)   # the start-up probe, then gone once the link is made
    name = f"mavlink:tcp:127.0.0.1:{peer.port}"
    rc = main(["run", "--source", str(SAMPLE / "approach" / "approach.mp4"),
               "--camera", str(SAMPLE / "camera.yaml"),
               "--layout", str(REPO / "marker_layouts" / "drick-aruco-centre.json"),
               "--layout", str(REPO / "marker_layouts" / "drick-aruco-pyramids.json"),
               "--mount", str(SAMPLE / "approach" / "mount.json"), "--sink", name,
               "--frames", "30", "--quiet"])
    cap = capsys.readouterr()
    assert rc == 1 and cap.out == ""
    lines = cap.err.splitlines()
    end = [x for x in lines if x.startswith(f"drovisio run: sink {name}: ")]
    assert len(end) == 1, lines
    m = re.fullmatch(rf"drovisio run: sink {re.escape(name)}: (\d+) messages not sent while "
                     r"its link was down \((\d+) sent\)", end[0])
    assert m and int(m[1]) > 0 and int(m[1]) + int(m[2]) <= 30
    assert peer.targets == 0
    # said once at most (a status may not have come before the end), never "back"
    assert sum(f"sink {name} lost (" in x for x in lines) <= 1
    assert not any(" back (" in x for x in lines)
    peer.go()


def test_a_dead_serial_port_is_one_line_of_ours_not_pymavlinks(capfd):
    master, slave = os.openpty()
    path = os.ttyname(slave)
    sink = MavlinkSink(path)
    alarms = Alarms("cam.yaml")
    try:
        sink.send(_target())
        assert sink.status()["sent"] == 1
        os.close(master)          # the flight controller unplugged
        for _ in range(3):
            sink.send(_target())
        st = sink.status()
        assert (st["sent"], st["lost"]) == (1, 3)
        said = _said(alarms, sink)
        assert len(said) == 1
        assert said[0].startswith(f"sink mavlink:{path} lost ({path} stopped answering; check "
                                  "the cable (or USB adapter) and that the flight controller "
                                  "is powered; opening it again once a second")
        sink.send(_target())
        assert _said(alarms, sink) == []
    finally:
        sink.close()
        os.close(slave)
    cap = capfd.readouterr()
    assert "is dead" not in cap.out + cap.err
    assert cap.out == "" and cap.err == ""


def test_a_jsonl_write_that_fails_is_not_sent_and_said_once():
    sink = open_sink("jsonl:/dev/full")
    alarms = Alarms("cam.yaml")
    try:
        for _ in range(3):
            sink.send(_target())
        st = sink.status()
        assert (st["sent"], st["errors"]) == (0, 3)
        assert _said(alarms, sink) == ["sink jsonl:/dev/full lost ([Errno 28] No space left on "
                                       "device); its messages are not sent until it comes "
                                       "back"]
        sink.send(_target())
        assert _said(alarms, sink) == []
    finally:
        sink.close()


def test_a_udp_datagram_refused_is_not_sent_and_said_once():
    sink = open_sink("udp://255.255.255.255:9")     # broadcast, not allowed on this socket
    alarms = Alarms("cam.yaml")
    try:
        sink.send(_target())
        st = sink.status()
        assert (st["sent"], st["errors"]) == (0, 1) and st["down"] == "[Errno 13] Permission denied"
        assert _said(alarms, sink) == ["sink udp://255.255.255.255:9 lost ([Errno 13] Permission "
                                       "denied); its messages are not sent until it comes back"]
    finally:
        sink.close()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_mavlink_udp_listener_sends_nothing_until_a_peer_speaks_and_says_so(capfd, until):
    port = _free_udp_port()
    name = f"mavlink:udpin:127.0.0.1:{port}"
    sink = MavlinkSink(f"udpin:127.0.0.1:{port}")
    alarms = Alarms("cam.yaml")
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    try:
        for _ in range(4):
            sink.send(_target())
        st = sink.status()
        assert (st["sent"], st["lost"]) == (0, 4)      # nobody to send to: not sent
        said = _said(alarms, sink)
        assert said == [f"sink {name} lost (no MAVLink peer has sent to port {port} "
                        "yet, so there is nobody to send to; start the autopilot (or "
                        "mavlink-router) that sends there, or give udpout:HOST:PORT to send "
                        "first); its messages are not sent until it comes back"]
        mav = mavutil2().mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        hb = mav.heartbeat_encode(2, 3, 0, 0, 4).pack(mav)
        until(lambda: sink.status()["sent"] > 0, DEADLINE_S,
              step=lambda: (peer.sendto(hb, ("127.0.0.1", port)), sink.send(_target())))
        assert sink.status()["down"] is None
        assert _said(alarms, sink)[0].startswith(f"sink {name} back (")
        peer.setblocking(False)
        seen: set[str] = set()

        def read() -> None:
            sink.send(_target())
            while select.select([peer], [], [], 0.05)[0]:
                seen.update(m.get_type() for m in mav.parse_buffer(peer.recv(4096)) or [])

        # it reaches the peer
        until(lambda: seen, DEADLINE_S, done=lambda got: "LANDING_TARGET" in got, step=read)
    finally:
        sink.close()
        peer.close()
    cap = capfd.readouterr()
    assert cap.out == "" and cap.err == ""


def test_a_refused_mavlink_udp_datagram_is_not_counted_sent():
    sink = MavlinkSink("udpout:255.255.255.255:9")   # broadcast without SO_BROADCAST: EACCES
    try:
        sink.send(_target())
        st = sink.status()
        assert (st["sent"], st["lost"]) == (0, 1)
        assert st["down"].startswith("mavlink:udpout:255.255.255.255:9: the datagram was not "
                                     "sent (Permission denied); check the address")
    finally:
        sink.close()
