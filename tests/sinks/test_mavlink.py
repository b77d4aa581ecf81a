"""LANDING_TARGET to a pymavlink listener: ArduPilot (BODY_FRD) and PX4 (LOCAL_NED) modes."""

from __future__ import annotations

import argparse
import json
import math
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.commands.run import build_pipeline
from drovisio.mount import load_mount, ned_from_body
from drovisio.sinks.mavlink import (
    MAV_FRAME_BODY_FRD,
    MAV_FRAME_LOCAL_NED,
    VehicleState,
    landing_target_fields,
    mavutil2,
)
from drovisio.tracking import TrackedBrick

REPO = Path(__file__).resolve().parents[2]
APPROACH = REPO / "sample_sessions" / "approach"
LAYOUTS = [str(REPO / "marker_layouts" / f"{n}.json")
           for n in ("drick-aruco-pyramids", "drick-aruco-centre", "drick-dots-2x3")]
NED_FROM_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _truth():
    return [json.loads(x) for x in (APPROACH / "truth.jsonl").read_text().splitlines()]


def _args(source, sinks, **kw):
    a = dict(source=str(source), camera=str(REPO / "sample_sessions" / "camera.yaml"),
             layout=LAYOUTS, mount=str(APPROACH / "mount.json"), sink=sinks, record=None,
             target="nearest", autopilot="ardupilot", max_age=0.5, pace="realtime")
    a.update(kw)
    return argparse.Namespace(**a)


class Listener:
    """A pymavlink endpoint standing in for the flight controller."""

    def __init__(self, reply=None):
        mavutil = mavutil2()
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=1,
                                               source_component=1)
        self.port = self.conn.port.getsockname()[1]
        self.msgs: list[tuple[float, object]] = []
        self.heartbeats = 0
        self.reply = reply
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _run(self):
        next_reply = 0.0
        while not self.stop.is_set():
            m = self.conn.recv_match(blocking=True, timeout=0.02)
            now = time.monotonic()
            if m is not None:
                if m.get_type() == "LANDING_TARGET":
                    self.msgs.append((now, m))
                elif m.get_type() == "HEARTBEAT":
                    self.heartbeats += 1
            if self.reply is not None and self.heartbeats and now >= next_reply:
                self.reply(self.conn.mav)
                next_reply = now + 0.02  # 50 Hz, like an autopilot's ATTITUDE stream

    def close(self):
        self.stop.set()
        self.th.join(60)
        self.conn.close()


def _brick(rvec, tvec, instance=1):
    return TrackedBrick("drick-aruco-centre", instance, 7, "aruco", np.asarray(rvec, float),
                        np.asarray(tvec, float), np.eye(6), 100.0, 100.0, 0.0, True)


def test_landing_target_fields_conventions():
    mount = load_mount(APPROACH / "mount.json")
    b = _brick([3.1, 0.0, 0.0], [0.2, -0.1, 1.5])
    f = landing_target_fields(b, 100.000001, mount, "ardupilot", size_m=(0.3, 0.15))
    p_body = mount.point_in_body([0.2, -0.1, 1.5])
    assert f["frame"] == MAV_FRAME_BODY_FRD and f["position_valid"] == 1
    assert np.allclose([f["x"], f["y"], f["z"]], p_body)
    assert f["distance"] == pytest.approx(np.linalg.norm(p_body))
    assert f["angle_x"] == pytest.approx(math.atan2(0.2, 1.5))
    assert f["angle_y"] == pytest.approx(math.atan2(-0.1, 1.5))
    assert f["size_x"] == pytest.approx(2 * math.atan2(0.15, np.linalg.norm([0.2, -0.1, 1.5])))
    assert f["time_usec"] == 100000001 and f["target_num"] == 1
    # PX4: absolute local NED from the vehicle's attitude and position
    att, pos = (0.05, -0.1, 1.2), (3.0, -2.0, -1.8)
    f = landing_target_fields(b, 100.0, mount, "px4", att, pos)
    assert f["frame"] == MAV_FRAME_LOCAL_NED and f["position_valid"] == 1
    assert np.allclose([f["x"], f["y"], f["z"]], np.add(pos, ned_from_body(*att) @ p_body))
    f = landing_target_fields(b, 100.0, mount, "px4", None, pos)
    assert f["position_valid"] == 0


def test_vehicle_state_interpolates_and_expires():
    v = VehicleState()
    v.add_attitude(10.0, 0.0, 0.0, math.pi - 0.1)
    v.add_attitude(10.1, 0.1, 0.0, -math.pi + 0.1)  # yaw wraps
    r, p, y = v.attitude_at(10.05)
    assert r == pytest.approx(0.05) and abs(abs(y) - math.pi) < 1e-9
    assert v.attitude_at(10.5, max_age=0.3) is None


def test_ardupilot_landing_target_at_frame_rate_vs_truth(tmp_path, until):
    lst = Listener()
    jl = tmp_path / "out.jsonl"
    # every frame measured (pace "max"): at "realtime" a loaded machine, or the first run
    # compiling the kernels, skips frames and the count would measure the machine
    p = build_pipeline(_args(APPROACH / "approach.mp4",
                             [f"mavlink:udpout:127.0.0.1:{lst.port}", f"jsonl:{jl}"],
                             pace="max"))
    sink = next(s for s in p.sinks if s.name.startswith("mavlink:"))
    try:
        assert p.run(max_frames=45) == 45  # 3 s of the 15 fps video
        until(lambda: len(lst.msgs) >= sink.delivery.sent)   # all that was sent has arrived
    finally:
        p.close()
        lst.close()
    lines = [json.loads(x) for x in jl.read_text().splitlines()]
    ts = np.array([d["t"] for d in lines])
    truth = _truth()
    mount = load_mount(APPROACH / "mount.json")
    msgs = lst.msgs
    # one message per frame whose target was measured, each stamped with its own frame: the
    # rate is the frames' (a loaded machine may process fewer frames; none is sent twice)
    measured = [d for d in lines if d.get("target") and any(
        b["track"] == d["target"]["track"] and b.get("measured", True) for b in d["bricks"])]
    assert len(msgs) >= 40 and len(msgs) == len(measured)
    stamps = [m.time_usec for _, m in msgs]
    assert len(set(stamps)) == len(stamps) and stamps == sorted(stamps)
    assert lst.heartbeats >= 1
    errs, ang = [], []
    for _, m in msgs:
        assert m.frame == MAV_FRAME_BODY_FRD and m.position_valid == 1 and m.type == 2
        assert m.distance == pytest.approx(math.sqrt(m.x ** 2 + m.y ** 2 + m.z ** 2), rel=1e-5)
        k = int(np.argmin(np.abs(ts - m.time_usec / 1e6)))
        assert abs(ts[k] - m.time_usec / 1e6) < 2e-6  # time_usec = the frame's capture time
        d = lines[k]
        tgt = d["target"]
        cand = [b for b in truth[d["frame"]]["bricks"] if b["layout"] == tgt["layout"]
                and (tgt["instance"] is None or b["instance"] == tgt["instance"])]
        est = [b for b in d["bricks"] if b["track"] == tgt["track"]][0]
        tb = min(cand, key=lambda b: np.linalg.norm(np.subtract(b["tvec"], est["tvec"])))
        p_body = mount.point_in_body(tb["tvec"])
        errs.append(np.linalg.norm(np.subtract([m.x, m.y, m.z], p_body)))
        assert m.distance == pytest.approx(np.linalg.norm(p_body), abs=0.05)
        ang.append(max(abs(m.angle_x - math.atan2(tb["tvec"][0], tb["tvec"][2])),
                       abs(m.angle_y - math.atan2(tb["tvec"][1], tb["tvec"][2]))))
    assert np.median(errs) < 0.02 and max(errs) < 0.05
    assert np.degrees(np.median(ang)) < 0.5 and np.degrees(max(ang)) < 1.5


def _frd_state_of_frame(rec):
    """The vehicle attitude (roll, pitch, yaw) and local NED position of a truth frame."""
    mount = load_mount(APPROACH / "mount.json")
    world_from_camera = np.linalg.inv(np.asarray(rec["camera_from_world"]))
    world_from_body = world_from_camera @ mount.camera_from_body
    R = NED_FROM_ENU @ world_from_body[:3, :3]
    roll, pitch, yaw = (math.atan2(R[2, 1], R[2, 2]), -math.asin(R[2, 0]),
                        math.atan2(R[1, 0], R[0, 0]))
    return (roll, pitch, yaw), NED_FROM_ENU @ world_from_body[:3, 3]


def test_px4_local_ned_from_the_links_attitude(tmp_path, until):
    rec = _truth()[0]
    (roll, pitch, yaw), pos = _frd_state_of_frame(rec)
    assert np.allclose(ned_from_body(roll, pitch, yaw),
                       NED_FROM_ENU @ (np.linalg.inv(np.asarray(rec["camera_from_world"]))
                                       @ load_mount(APPROACH / "mount.json").camera_from_body
                                       )[:3, :3], atol=1e-9)
    cap = cv2.VideoCapture(str(APPROACH / "approach.mp4"))
    ok, img = cap.read()
    cap.release()
    folder = tmp_path / "hover"
    folder.mkdir()
    cv2.imwrite(str(folder / "f0.png"), img)

    def autopilot(mav):
        t = int(time.monotonic() * 1000) & 0xFFFFFFFF
        mav.attitude_send(t, roll, pitch, yaw, 0.0, 0.0, 0.0)
        mav.local_position_ned_send(t, *pos, 0.0, 0.0, 0.0)

    lst = Listener(reply=autopilot)
    from drovisio.sources import FrameSource, ImageFolderReader
    p = build_pipeline(_args(folder, [f"mavlink:udpout:127.0.0.1:{lst.port}"],
                             autopilot="px4", target="drick-aruco-centre:1"))
    p.source = FrameSource(ImageFolderReader(folder, fps=15, loop=True))

    def with_position():
        return [m for _, m in list(lst.msgs) if m.position_valid == 1]

    # frames before the vehicle's state arrives (or while a loaded machine holds the
    # listener back) go out without a position: wait for ten that have one
    th = threading.Thread(target=p.run, daemon=True)
    th.start()
    try:
        until(lambda: len(with_position()) >= 10)
    finally:
        p.stop()
        th.join(60)
        p.close()
        lst.close()
    valid = with_position()
    assert len(valid) >= 10
    scene = json.loads((APPROACH / "scene.json").read_text())
    brick = [b for b in scene["bricks"] if b["layout"] == "drick-aruco-centre"][0]
    expect = NED_FROM_ENU @ np.asarray(brick["world_from_brick"])[:3, 3]
    for m in valid:
        assert m.frame == MAV_FRAME_LOCAL_NED and m.target_num == 1
        assert np.linalg.norm(np.subtract([m.x, m.y, m.z], expect)) < 0.03
    # the orientation: the brick's yaw in NED (world yaw 0° → NED yaw 90°)
    q = valid[-1].q
    yaw_ned = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
    assert abs(math.degrees(yaw_ned) - 90.0) < 3.0


def test_a_closed_tcp_link_is_said_quietly_and_reconnected_at_most_once_a_second(
        closing_peer, capfd, monkeypatch):
    from drovisio.autopilot import connection
    from drovisio.autopilot.connection import LinkClosed, open_link

    # one reconnect allowed, then none for the rest of the test (the interval is long)
    monkeypatch.setattr(connection, "RECONNECT_EVERY_S", 1e6)
    link = open_link("mavlink:tcp:x", f"tcp:127.0.0.1:{closing_peer.port}", source_system=1,
                     source_component=191, reconnect=True)
    def reconnects_done():   # a reconnect runs on its own thread: the reader never waits
        for t in threading.enumerate():
            if t.name == "mavlink-reconnect":
                t.join(timeout=30)

    for _ in range(4):
        with pytest.raises(LinkClosed, match=f"127.0.0.1:{closing_peer.port} closed the "
                                             "connection"):
            link.recv_match(blocking=True, timeout=10)
        reconnects_done()
    # a write while closed raises too (pymavlink dropped it silently): the sink counts it lost
    with pytest.raises(LinkClosed, match=f"127.0.0.1:{closing_peer.port} closed the connection"):
        link.mav.heartbeat_send(18, 8, 0, 0, 4)
    # the start-up probe, pymavlink's connect and one reconnect; none after
    assert closing_peer.accepted == 3
    cap = capfd.readouterr()
    assert cap.out == "" and cap.err == ""
