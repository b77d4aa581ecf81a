"""The station's fleet state: rate, latency, lost/live, the target, bounds."""

from __future__ import annotations

import pytest

from drovisio.station import Fleet


def _output(t: float, bricks: int = 2) -> dict:
    bs = [{"layout": "drick", "instance": k, "track": k + 1, "tvec": [0.1 * k, 0.0, 1.0],
           "rvec": [0.0, 0.0, 0.0]} for k in range(bricks)]
    return {"file": "cam", "frame": 0, "t": t, "bricks": bs,
            "target": {"layout": "drick", "instance": 1, "track": 2} if bricks > 1 else None}


def test_rate_latency_and_target_from_the_frames():
    fleet = Fleet()
    for k in range(60):   # 30 fps, each frame received 12 ms after its capture
        t = 1000.0 + k / 30
        fleet.frame("drone1", _output(t), t_recv=t + 0.012, mono=50.0 + k / 30)
    fleet.presence("drone1", True)
    (d,) = fleet.status(mono=50.0 + 59 / 30 + 0.01)
    assert d.state == "live" and d.frames == 60 and d.bricks == 2
    assert d.fps == pytest.approx(30.0, rel=1e-6)
    assert d.latency_ms_p50 == pytest.approx(12.0, abs=1e-6)
    assert d.latency_ms_p90 == pytest.approx(12.0, abs=1e-6)
    assert d.target == {"layout": "drick", "instance": 1, "track": 2,
                        "tvec": [0.1, 0.0, 1.0], "rvec": [0.0, 0.0, 0.0]}
    js = d.to_json()
    assert js["state"] == "live" and js["fps"] == 30.0 and js["latency_ms_p90"] == 12.0


def test_lost_when_silent_or_when_its_session_ends():
    fleet = Fleet(lost_after_s=1.0)
    fleet.frame("a", _output(0.0), t_recv=0.0, mono=10.0)
    fleet.frame("b", _output(0.0), t_recv=0.0, mono=10.0)
    fleet.presence("a", True)
    fleet.presence("b", True)
    assert [d.state for d in fleet.status(mono=10.9)] == ["live", "live"]
    assert [d.state for d in fleet.status(mono=11.1)] == ["lost", "lost"]   # silent
    fleet.frame("a", _output(1.0), t_recv=1.0, mono=11.2)
    fleet.frame("b", _output(1.0), t_recv=1.0, mono=11.2)
    fleet.presence("b", False)                                            # session ended
    a, b = fleet.status(mono=11.3)
    assert (a.state, b.state) == ("live", "lost") and b.fps == 0.0
    fleet.frame("b", _output(2.0), t_recv=2.0, mono=11.4)                 # back
    assert fleet.status(mono=11.5)[1].state == "live"


def test_bounded_in_drones_and_frames():
    fleet = Fleet(max_drones=3)
    for k in range(10):
        fleet.frame(f"d{k}", _output(0.0), t_recv=0.0, mono=float(k))
    assert [d.drone_id for d in fleet.status(mono=10.0)] == ["d7", "d8", "d9"]
    for k in range(1000):
        fleet.frame("d9", _output(k / 30), t_recv=k / 30, mono=10.0 + k / 30)
    d = fleet._drones["d9"]
    assert len(d.arrivals) == 90 and len(d.latencies_ms) == 90


def test_an_output_without_time_or_target_is_still_a_frame():
    fleet = Fleet()
    fleet.frame("x", {"bricks": "not a list", "t": float("nan")}, t_recv=1.0, mono=1.0)
    fleet.presence("x", True)
    (d,) = fleet.status(mono=1.1)
    assert d.frames == 1 and d.bricks == 0 and d.latency_ms_p50 is None and d.target is None


@pytest.mark.parametrize("web, ok", [
    ("http://192.168.1.21:8080/", True), ("https://drone1.site/", True),
    ("javascript:alert(1)", False), ("http://a b/", False), ("http://x/" + "a" * 300, False),
    ('http://x/"onmouseover=1', False)])
def test_a_drone_names_its_web_tool_only_as_an_http_address(web, ok):
    from drovisio.sinks.base import SinkError
    from drovisio.sinks.zenoh import parse_spec

    spec = f"zenoh:connect=tcp/127.0.0.1:7447&web={web}"
    if ok:
        assert parse_spec(spec)["web"] == web
    else:
        with pytest.raises(SinkError, match="web"):
            parse_spec(spec)


def test_the_station_drops_what_it_cannot_read(until):
    """A hostile or broken peer on the network: bytes that are no CDR, a JSON that is no
    object, a key that names no drone: dropped and counted, the fleet untouched."""
    import json
    import socket
    import time

    import zenoh

    from drovisio.ros.msgdefs import encoder
    from drovisio.sinks.zenoh import topic_key
    from drovisio.station import StationLink

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    fleet = Fleet()
    link = StationLink(fleet, listen=[f"tcp/127.0.0.1:{port}"])
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    peer = zenoh.open(cfg)
    try:
        key = topic_key(0, "/drovisio/evil/output", "std_msgs/msg/String")
        bad = [b"\x00\x01garbage", encoder("std_msgs/String")({"data": "[1, 2, 3]"}),
               encoder("std_msgs/String")({"data": "{not json"})]
        end = time.monotonic() + 60     # bounds for failures only, here and below
        while link.dropped < 3 and time.monotonic() < end:
            for payload in bad:
                peer.put(key, payload)
            peer.put("0/drovisio", b"no drone here")
            time.sleep(0.2)
        assert link.dropped >= 3
        assert fleet.status() == []
        good = encoder("std_msgs/String")({"data": json.dumps({"t": time.time(), "bricks": []})})
        until(lambda: [d.drone_id for d in fleet.status()], done=lambda ids: ids == ["evil"],
              step=lambda: peer.put(key, good), pause=0.1)
    finally:
        peer.close()
        link.close()
