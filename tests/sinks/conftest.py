"""A pymavlink-scripted flight controller on loopback UDP that streams nothing unless asked."""

from __future__ import annotations

import threading
import time

import pytest

from drovisio.sinks.mavlink import mavutil2

ARDUPILOT_OK = {
    "PLND_ENABLED": 1, "PLND_TYPE": 1, "PLND_EST_TYPE": 1, "PLND_ORIENT": 25,
    "PLND_YAW_ALIGN": 0, "PLND_CAM_POS_X": 0, "PLND_CAM_POS_Y": 0, "PLND_CAM_POS_Z": 0,
    "PLND_LAG": 0.05,
}
PX4_OK = {"LTEST_MODE": 1, "LTEST_SCALE_X": 1, "LTEST_SCALE_Y": 1, "PLD_HACC_RAD": 0.05,
          "PLD_FAPPR_ALT": 2.0}


class ScriptedVehicle:
    """Listens on ``udpin:127.0.0.1:PORT`` as system ``sysid``, component 1; sends a HEARTBEAT
    a second once it heard anyone. ``interval``: answer ``SET_MESSAGE_INTERVAL`` as ArduCopter
    does (``accept``: COMMAND_ACK accepted, then stream at the asked interval; ``refuse``:
    COMMAND_ACK unsupported; ``ignore``: no answer). ``data_stream``: honour
    ``REQUEST_DATA_STREAM``. ``params``: the parameters it answers ``PARAM_REQUEST_READ``
    with. ``intruder``: also send ATTITUDE as another system (another vehicle on the router).
    """

    def __init__(self, sysid: int = 1, autopilot: int = 3, interval: str = "accept",
                 data_stream: bool = True, params: dict | None = None,
                 attitude=(0.1, -0.05, 1.0), intruder: int | None = None):
        mavutil = mavutil2()
        self.m = mavutil.mavlink
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=sysid,
                                               source_component=1)
        self.port = self.conn.port.getsockname()[1]
        self.sysid, self.autopilot = sysid, autopilot
        self.interval_mode, self.data_stream = interval, data_stream
        self.params = dict(params or {})
        self.attitude = attitude
        self.intruder = intruder
        self.rates: dict[int, float] = {}      # msg id → Hz
        self.commands: list = []
        self.stream_requests: list = []
        self.param_requests: list[str] = []
        self.heard = threading.Event()
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _send_as(self, sysid: int, fn) -> None:
        mav = self.conn.mav
        old = mav.srcSystem
        mav.srcSystem = sysid
        try:
            fn(mav)
        finally:
            mav.srcSystem = old

    def _run(self) -> None:
        m = self.m
        next_hb, due = 0.0, {}
        while not self.stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.005)
            now = time.monotonic()
            if msg is not None:
                self.heard.set()
                self._handle(msg)
            if not self.heard.is_set():
                continue
            if now >= next_hb:
                self.conn.mav.heartbeat_send(m.MAV_TYPE_QUADROTOR, self.autopilot, 0, 0,
                                             m.MAV_STATE_STANDBY)
                next_hb = now + 1.0
            t_ms = int(now * 1000) & 0xFFFFFFFF
            for mid, hz in list(self.rates.items()):
                if hz <= 0 or now < due.get(mid, 0.0):
                    continue
                due[mid] = now + 1.0 / hz
                if mid == 30:
                    self.conn.mav.attitude_send(t_ms, *self.attitude, 0.0, 0.0, 0.0)
                    if self.intruder is not None:
                        self._send_as(self.intruder, lambda mav, t=t_ms: mav.attitude_send(
                            t, -0.3, 0.3, -1.0, 0.0, 0.0, 0.0))
                elif mid == 32:
                    self.conn.mav.local_position_ned_send(t_ms, 1.0, 2.0, -3.0, 0, 0, 0)

    def _handle(self, msg) -> None:
        m = self.m
        t = msg.get_type()
        if t == "COMMAND_LONG" and msg.target_system == self.sysid:
            self.commands.append(msg)
            if msg.command == m.MAV_CMD_SET_MESSAGE_INTERVAL:
                if self.interval_mode == "accept":
                    self.rates[int(msg.param1)] = 1e6 / msg.param2 if msg.param2 > 0 else 0.0
                    self.conn.mav.command_ack_send(msg.command, m.MAV_RESULT_ACCEPTED)
                elif self.interval_mode == "refuse":
                    self.conn.mav.command_ack_send(msg.command, m.MAV_RESULT_UNSUPPORTED)
        elif t == "REQUEST_DATA_STREAM" and msg.target_system == self.sysid:
            self.stream_requests.append(msg)
            if self.data_stream:
                ids = {m.MAV_DATA_STREAM_EXTRA1: 30, m.MAV_DATA_STREAM_POSITION: 32}
                if msg.req_stream_id in ids:
                    self.rates[ids[msg.req_stream_id]] = float(msg.req_message_rate) \
                        if msg.start_stop else 0.0
        elif t == "PARAM_REQUEST_READ" and msg.target_system == self.sysid:
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            self.param_requests.append(name)
            if name in self.params:
                names = sorted(self.params)
                self.conn.mav.param_value_send(name.encode(), float(self.params[name]),
                                               m.MAV_PARAM_TYPE_REAL32, len(names),
                                               names.index(name))

    def close(self) -> None:
        self.stop.set()
        self.th.join(60)
        self.conn.close()


@pytest.fixture
def ardupilot_ok() -> dict:
    """ArduPilot parameters right for Drovisio (PLND_LAG for a 50 ms latency)."""
    return dict(ARDUPILOT_OK)


@pytest.fixture
def px4_ok() -> dict:
    return dict(PX4_OK)


@pytest.fixture
def vehicle():
    made: list[ScriptedVehicle] = []

    def make(**kw) -> ScriptedVehicle:
        v = ScriptedVehicle(**kw)
        made.append(v)
        return v

    yield make
    for v in made:
        v.close()


class ClosingPeer:
    """A TCP server on loopback that accepts each connection and closes it at once (what a
    port that speaks something else, or a firewall that answers for it, looks like)."""

    def __init__(self) -> None:
        import socket

        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.accepted = 0
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _run(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:      # closed: the test is over
                return
            self.accepted += 1
            conn.close()

    def close(self) -> None:
        self.server.close()


@pytest.fixture
def closing_peer():
    peer = ClosingPeer()
    yield peer
    peer.close()
