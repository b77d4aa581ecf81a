"""``--sink zenoh:...``: rmw_zenoh's key expressions and attachment, the same CDR messages as
the recordings, one namespace per drone, a link that comes back. Loopback only."""

from __future__ import annotations

import json
import socket
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.cli import main
from drovisio.pipeline import FrameOutput
from drovisio.ros.messages import RosMessages
from drovisio.ros.msgdefs import decoder
from drovisio.ros.type_hash import rihs01
from drovisio.sinks import open_sink
from drovisio.sinks.base import SinkError
from drovisio.sinks.zenoh import ZenohSink, parse_spec, topic_key

zenoh = pytest.importorskip("zenoh")

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"
BASE = ["--camera", str(SAMPLE / "camera.yaml"), "--mount",
        str(SAMPLE / "approach" / "mount.json"),
        "--layout", str(REPO / "marker_layouts" / "drick-aruco-pyramids.json"),
        "--layout", str(REPO / "marker_layouts" / "drick-aruco-centre.json"), "--quiet"]


class Station:
    """A Zenoh peer listening on loopback and keeping every sample under ``key``."""

    def __init__(self, port: int, key: str = "**"):
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"peer"')
        cfg.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(cfg)
        self.samples: list[tuple[str, bytes, bytes | None]] = []
        self.sub = self.session.declare_subscriber(key, self._on)

    def _on(self, s) -> None:
        self.samples.append((str(s.key_expr), s.payload.to_bytes(),
                             None if s.attachment is None else s.attachment.to_bytes()))

    def wait(self, n: int, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while len(self.samples) < n and time.monotonic() < deadline:
            time.sleep(0.05)

    def close(self) -> None:
        self.session.close()


def test_keys_follow_rmw_zenoh():
    # the design document's own example, and our types
    assert topic_key(0, "/chatter", "std_msgs/msg/String") == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
    assert topic_key(3, "/drovisio/d1/bricks", "vision_msgs/msg/Detection3DArray") == (
        "3/drovisio/d1/bricks/vision_msgs::msg::dds_::Detection3DArray_/"
        + rihs01("vision_msgs/Detection3DArray"))


@pytest.mark.parametrize("spec, says", [
    ("zenoh:", "give connect"),
    ("zenoh:connect=127.0.0.1:7447", "tcp/HOST:PORT"),
    ("zenoh:connect=tcp/127.0.0.1:7447&mode=router", "mode"),
    ("zenoh:connect=tcp/127.0.0.1:7447&domain=999", "domain"),
    ("zenoh:connect=tcp/127.0.0.1:7447&colour=red", "unknown option 'colour'"),
    ("zenoh:mode=client", "needs connect"),
])
def test_bad_specs_name_the_option(spec, says):
    with pytest.raises(SinkError, match=says):
        parse_spec(spec)


def test_a_run_publishes_the_recordings_messages_under_its_drone(tmp_path, free_port):
    port = free_port()
    st = Station(port, "0/**")
    try:
        out = tmp_path / "out.jsonl"
        assert main(["run", "--source", str(SAMPLE / "approach" / "approach.mp4"), *BASE,
                     "--frames", "20", "--drone-id", "d1", "--sink", f"jsonl:{out}",
                     "--sink", f"zenoh:connect=tcp/127.0.0.1:{port}"]) == 0
        js = [json.loads(x) for x in out.read_text().splitlines()]
        st.wait(3 * len(js) + 2)
    finally:
        st.close()
    keys = Counter(k for k, _, _ in st.samples)
    want = {topic_key(0, "/drovisio/d1/bricks", "vision_msgs/msg/Detection3DArray"),
            topic_key(0, "/drovisio/d1/target", "geometry_msgs/msg/PoseWithCovarianceStamped"),
            topic_key(0, "/drovisio/d1/output", "std_msgs/msg/String"),
            topic_key(0, "/drovisio/d1/camera/camera_info", "sensor_msgs/msg/CameraInfo"),
            topic_key(0, "/tf_static", "tf2_msgs/msg/TFMessage"),
            # a small image a second, for a station's thumbnail
            topic_key(0, "/drovisio/d1/camera/image_raw/compressed",
                      "sensor_msgs/msg/CompressedImage")}
    assert set(keys) == want, keys
    img_key = topic_key(0, "/drovisio/d1/camera/image_raw/compressed",
                        "sensor_msgs/msg/CompressedImage")
    for k, payload, _ in st.samples:
        if k == img_key:
            m = decoder("sensor_msgs/CompressedImage")(payload)
            img = cv2.imdecode(np.frombuffer(bytes(m.data), np.uint8), cv2.IMREAD_COLOR)
            assert m.format == "jpeg" and img.shape == (240, 320, 3)
    # no frame lost on a link that is up (the sink's queue never overflowed here)
    bricks_key = topic_key(0, "/drovisio/d1/bricks", "vision_msgs/msg/Detection3DArray")
    assert keys[bricks_key] == len(js)
    by_t = {f["t"]: f for f in js}
    dec = decoder("vision_msgs/Detection3DArray")
    last_seq = 0
    for k, payload, att in st.samples:
        if k != bricks_key:
            continue
        m = dec(payload)
        t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
        f = by_t[min(by_t, key=lambda x: abs(x - t))]
        assert abs(f["t"] - t) < 1e-6
        assert m.header.frame_id == "d1/camera_optical_frame"
        assert [d.id for d in m.detections] == [f"{b['layout']}/{b['instance']}"
                                                for b in f["bricks"]]
        for d, b in zip(m.detections, f["bricks"]):
            p = d.results[0].pose.pose.position
            np.testing.assert_allclose([p.x, p.y, p.z], b["tvec"], atol=1e-6)
            np.testing.assert_allclose(np.reshape(d.results[0].pose.covariance, (6, 6)),
                                       b["covariance"], rtol=1e-5, atol=1e-15)
        # rmw_zenoh's attachment: sequence number, source timestamp (ns), 16-byte gid
        assert att is not None and len(att) == 32
        seq, ts = np.frombuffer(att[:16], "<i8")
        assert seq == last_seq + 1 and abs(ts * 1e-9 - t) < 1e-6
        last_seq = int(seq)


def _output(i: int) -> FrameOutput:
    t = time.time()
    return FrameOutput(source="test", frame=i, seq=i, t=t, t_mono=time.monotonic(),
                       bricks=[])


def test_a_lost_link_comes_back_without_a_restart(free_port):
    port = free_port()
    sink = open_sink(f"zenoh:connect=tcp/127.0.0.1:{port}", drone_id="d2")
    assert isinstance(sink, ZenohSink)
    key = "0/drovisio/d2/output/**"
    try:
        for i in range(50):   # nobody listens yet: nothing waits, nothing fails
            sink.send(_output(i))
        status = sink.status()
        assert status["errors"] == 0 and status["state"] == "connecting"
        # what did not fit the queue while no session could take it: lost, never sent
        assert (status["sent"], status["lost"], status["dropped"]) == (0, 50 - 16, 0)
        assert status["down"] == (f"zenoh:connect=tcp/127.0.0.1:{port}: no Zenoh peer or "
                                  f"router connected on tcp/127.0.0.1:{port}; check that the "
                                  "station (or router) runs and the network reaches it")
        for attempt in range(2):   # the station comes, goes, and comes back
            st = Station(port, key)
            try:
                i = 0
                deadline = time.monotonic() + 60   # a bound for failures only
                while not st.samples and time.monotonic() < deadline:
                    sink.send(_output(i))
                    i += 1
                    time.sleep(0.05)
                assert st.samples, f"nothing arrived (attempt {attempt})"
                data = json.loads(decoder("std_msgs/String")(st.samples[-1][1]).data)
                assert data["file"] == "test" and data["bricks"] == []
                assert sink.status()["sent"] >= 1 and sink.status()["down"] is None
            finally:
                st.close()
            # nobody connected: Zenoh would drop the frames silently; they are counted lost
            lost = sink.status()["lost"]
            deadline = time.monotonic() + 20
            while sink.status()["lost"] == lost and time.monotonic() < deadline:
                sink.send(_output(i))
                time.sleep(0.05)
            status = sink.status()
            assert status["lost"] > lost and "no Zenoh peer or router connected" in status["down"]
            sink.send(_output(i))        # taken by the sink's thread: lost, not sent
            deadline = time.monotonic() + 20
            while sink.status()["lost"] == status["lost"] and time.monotonic() < deadline:
                time.sleep(0.02)
            assert sink.status()["sent"] == status["sent"]
            assert sink.status()["lost"] >= status["lost"] + 1
    finally:
        sink.close()


def test_messages_carry_the_drone_in_topics_and_frames():
    from drovisio.ros.messages import namespace_for

    ns, prefix = namespace_for("drone7")
    m = RosMessages(namespace=ns, frame_prefix=prefix)
    assert m.topic("bricks") == "/drovisio/drone7/bricks" and m.topic("/tf_static") == "/tf_static"
    assert m.body_frame == "drone7/base_link" and m.camera_frame == "drone7/camera_optical_frame"
    assert namespace_for(None) == ("/drovisio", "")


def test_serve_takes_the_drone_id_and_the_mcap_options():
    from drovisio import cli
    from webtool.serve import settings_from

    s = settings_from(cli.build_parser().parse_args(
        ["serve", "--drone-id", "d3", "--record", "f.mcap", "--record-images", "png"]))
    assert (s.drone_id, s.record, s.record_images) == ("d3", Path("f.mcap"), "png")


def test_a_bad_drone_id_is_refused(capsys):
    assert main(["run", "--source", "x.mp4", *BASE, "--drone-id", "drone 1/../x"]) == 2
    err = capsys.readouterr().err
    assert "--drone-id" in err and "Traceback" not in err


@pytest.mark.parametrize("endpoint, ok", [
    ("tcp/127.0.0.1:7447", True), ("udp/drone-3.local:7447", True), ("tcp/[::1]:7447", True),
    ("ws/10.0.0.2:8000", True), ("tcp/127.0.0.1:0", False), ("tcp/127.0.0.1:70000", False),
    ("127.0.0.1:7447", False), ("tcp/127.0.0.1", False), ("http/127.0.0.1:80", False),
    ("tcp/a b:7447", False), ("tcp/" + "a" * 201 + ":7447", False)])
def test_the_station_and_the_sink_read_an_endpoint_alike(endpoint, ok):
    """One rule: what ``drovisio station --listen`` accepts, ``--sink zenoh:listen=`` accepts,
    and both refuse the rest with the same words."""
    import argparse

    from drovisio.commands.station import zenoh_endpoint

    if ok:
        assert zenoh_endpoint(endpoint) == endpoint
        assert parse_spec(f"zenoh:listen={endpoint}")["listen"] == [endpoint]
        return
    with pytest.raises(argparse.ArgumentTypeError) as a:
        zenoh_endpoint(endpoint)
    with pytest.raises(SinkError) as s:
        parse_spec(f"zenoh:listen={endpoint}")
    assert str(a.value) in str(s.value) and "tcp/HOST:PORT" in str(a.value)


_CLOSE_WHILE_OPENING = """
import sys
import threading

import zenoh

from drovisio.sinks import open_sink

inside = threading.Event()
real_open = zenoh.open


def opening(config):
    inside.set()
    return real_open(config)


zenoh.open = opening
sink = open_sink(sys.argv[1])
assert inside.wait(120), "the session was never being opened"
sink.close()
print("closed", sink.status()["state"])
"""


@pytest.mark.parametrize("peer", ["closed port", "silent listener"])
def test_a_close_while_the_session_opens_warns_once_and_the_process_exits(peer, free_port):
    """A client whose router does not answer stays inside ``zenoh.open`` for ever: the close
    made then waits a bounded time, says so in one warning naming the endpoint, and the
    process still ends (the subprocess's bound only turns a hang into a failure)."""
    import subprocess
    import sys

    listener = None
    if peer == "closed port":
        port = free_port()
    else:                      # takes the connection, never says a word
        listener = socket.create_server(("127.0.0.1", 0))
        port = listener.getsockname()[1]
    endpoint = f"tcp/127.0.0.1:{port}"
    try:
        r = subprocess.run([sys.executable, "-c", _CLOSE_WHILE_OPENING,
                            f"zenoh:mode=client&connect={endpoint}"], capture_output=True,
                           text=True, timeout=300, cwd=REPO, stdin=subprocess.DEVNULL)
    finally:
        if listener is not None:
            listener.close()
    assert (r.returncode, r.stdout) == (0, "closed connecting\n"), r.stderr
    assert r.stderr == (f"thread 'zenoh-sink' (opening a Zenoh session to {endpoint}, which "
                        "did not answer) did not end within 3 s; going on without it\n")
