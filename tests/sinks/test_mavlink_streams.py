"""The sink asks a vehicle that streams nothing unless asked; ids; one vehicle among several."""

from __future__ import annotations

import time

import pytest

from drovisio.sinks import open_sink
from drovisio.sinks.base import SinkError
from drovisio.sinks.mavlink import MavlinkSink, parse_mavlink_spec


def _known(value) -> bool:
    """A state read (None: older than its max age, which a loaded machine may reach between
    two calls: asked again)."""
    return value is not None


def test_ardupilot_answers_set_message_interval_and_streams(vehicle, until):
    v = vehicle(interval="accept")
    sink = MavlinkSink(f"udpout:127.0.0.1:{v.port}")
    try:
        roll, pitch, _ = until(lambda: sink.attitude_at(time.monotonic()), done=_known)
        assert roll == pytest.approx(0.1, abs=1e-6) and pitch == pytest.approx(-0.05, abs=1e-6)
        # asked the right vehicle, the right message, by SET_MESSAGE_INTERVAL
        # the two requests travel separately: wait for both rather than race the second
        until(lambda: {int(c.param1) for c in v.commands if c.command == 511} >= {30, 32})
        cmd = [c for c in v.commands if c.command == 511]
        assert all(c.target_system == 1 and c.target_component == 1 for c in cmd)
        assert v.stream_requests == []         # no fallback needed
        st = sink.status()
        assert st["vehicle"] == {"system": 1, "component": 1, "autopilot": "ArduPilot"}
        assert st["note"] is None
        until(lambda: sink.status()["streams"]["ATTITUDE"]["rate_hz"] > 20)
        assert sink.status()["streams"]["ATTITUDE"]["mode"] == "acked"
    finally:
        sink.close()


def test_falls_back_to_request_data_stream_when_refused(vehicle, until):
    v = vehicle(interval="refuse", data_stream=True)
    sink = MavlinkSink(f"udpout:127.0.0.1:{v.port}")
    try:
        until(lambda: sink.attitude_at(time.monotonic()) is not None)
        assert any(r.req_stream_id == 10 and r.start_stop == 1 for r in v.stream_requests)
        assert sink.status()["streams"]["ATTITUDE"]["mode"] == "fallback"
    finally:
        sink.close()


def test_no_answer_is_said_once(vehicle, until):
    v = vehicle(interval="ignore", data_stream=False)
    sink = MavlinkSink(f"udpout:127.0.0.1:{v.port}")
    try:
        until(lambda: sink.status()["note"] is not None)
        note = sink.status()["note"]
        assert "no ATTITUDE" in note and "level flight" in note and "system 1" in note
        assert "REQUEST_DATA_STREAM" in note       # the last way tried
        # asked twice by command, then the old way, then gave up saying so (the vehicle's
        # thread may read the last request after the note was given)
        until(lambda: sum(c.command == 511 and int(c.param1) == 30
                          for c in v.commands) >= 2)
        until(lambda: any(r.req_stream_id == 10 for r in v.stream_requests))
        time.sleep(1.0)
        assert sink.streams.notes == [note]       # said once
        assert sink.attitude_at(time.monotonic()) is None
    finally:
        sink.close()


def test_the_note_waits_for_every_way_of_asking_however_late_the_polls():
    """A busy machine polls late: a retry falls due when the stream is already overdue. The
    note still comes once, after the fallback, naming it (it said SET_MESSAGE_INTERVAL first,
    then REQUEST_DATA_STREAM: two notes, the first one wrong)."""
    from types import SimpleNamespace

    from drovisio.autopilot.link import StreamKeeper

    for polls in ((0.0, 1.0, 2.0, 3.0, 4.0), (0.0, 3.2, 4.3, 5.5)):
        sent: list = []
        keeper = StreamKeeper(sent.append, None, start=0.0)
        keeper.on_message(SimpleNamespace(get_type=lambda: "HEARTBEAT", get_srcSystem=lambda: 1,
                                          get_srcComponent=lambda: 1, autopilot=3, type=2), 0.0)
        for t in polls:
            keeper.poll(t)
        assert keeper.streams[30].mode == "fallback" and len(keeper.notes) == 1, keeper.notes
        assert keeper.note == keeper.notes[0] and "asked (REQUEST_DATA_STREAM)" in keeper.note


def test_status_line_says_the_note_once():
    from drovisio.commands.run import new_notes

    said: set[str] = set()
    st = {"sinks": [{"sink": "mavlink:x", "note": "no ATTITUDE from ArduPilot"}]}
    assert "no ATTITUDE" in new_notes(st, said)
    assert new_notes(st, said) == ""


def test_nothing_on_the_link_is_said(vehicle, until):
    sink = MavlinkSink("udpout:127.0.0.1:9")    # discard port: nobody answers
    sink.streams.missing_after = 0.5
    try:
        until(lambda: sink.status()["note"] is not None)
        assert "no autopilot HEARTBEAT" in sink.status()["note"]
    finally:
        sink.close()


def test_px4_reads_only_its_own_vehicle(vehicle, until):
    # system 2 is ours; system 5 streams a different attitude on the same link
    v = vehicle(sysid=2, autopilot=12, intruder=5)
    sink = open_sink(f"mavlink:udpout:127.0.0.1:{v.port}?sysid=2&compid=195", autopilot="px4")
    try:
        until(lambda: sink.vehicle.position_at(time.monotonic()) is not None)
        time.sleep(0.3)
        for s in list(sink.vehicle.attitude):
            assert s.values == pytest.approx((0.1, -0.05, 1.0), abs=1e-6)
        position = until(lambda: sink.vehicle.position_at(time.monotonic()), done=_known)
        assert position == pytest.approx((1.0, 2.0, -3.0))
        assert sink.conn.mav.srcSystem == 2 and sink.conn.mav.srcComponent == 195
        assert all(c.target_system == 2 for c in v.commands)
    finally:
        sink.close()


def test_mavlink_spec_ids():
    assert parse_mavlink_spec("udpout:127.0.0.1:14550") == ("udpout:127.0.0.1:14550", {})
    assert parse_mavlink_spec("/dev/ttyAMA0,921600?sysid=3&compid=191") == (
        "/dev/ttyAMA0,921600", {"sysid": 3, "compid": 191})
    with pytest.raises(SinkError, match="sysid: expected a whole number 1-255"):
        parse_mavlink_spec("udpout:127.0.0.1:14550?sysid=256")
    with pytest.raises(SinkError, match="unknown option 'system'"):
        parse_mavlink_spec("udpout:127.0.0.1:14550?system=2")


def test_the_sinks_check_follows_a_fixed_parameter(vehicle, ardupilot_ok, until):
    v = vehicle(params=dict(ardupilot_ok, PLND_ORIENT=0))
    sink = MavlinkSink(f"udpout:127.0.0.1:{v.port}")
    sink.param_refresh_s = 0.5

    def orient():
        return {f["item"]: f for f in sink.check()}["PLND_ORIENT"]["status"]

    try:
        until(lambda: orient() == "wrong")
        v.params["PLND_ORIENT"] = 25          # fixed from the ground station meanwhile
        until(lambda: orient() == "ok")
    finally:
        sink.close()


def test_asks_again_when_a_stream_stops(vehicle, until):
    """An autopilot reboot forgets the intervals: the sink asks again, the stream comes back."""
    v = vehicle(interval="accept")
    sink = MavlinkSink(f"udpout:127.0.0.1:{v.port}")
    sink.streams.missing_after = 1.0
    try:
        until(lambda: sink.attitude_at(time.monotonic()) is not None)
        asked = sum(c.command == 511 and int(c.param1) == 30 for c in v.commands)
        v.rates.clear()                              # rebooted: streams nothing again
        until(lambda: sink.attitude_at(time.monotonic()) is None)
        until(lambda: sum(c.command == 511 and int(c.param1) == 30
                          for c in v.commands) > asked)
        until(lambda: sink.attitude_at(time.monotonic()) is not None)
    finally:
        sink.close()
