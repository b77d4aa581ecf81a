"""``--record FILE.mcap`` and ``--source FILE.mcap``: read back with ``rosbags`` (another
library than the writer), replayed through ``drovisio run``, and cut by ``kill -9``."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.cli import main
from drovisio.geometry import so3_exp
from drovisio.mount import load_mount
from drovisio.pose.covariance import mahalanobis2, pose_error
from drovisio.ros.frames import flu_from_camera
from drovisio.ros.mcap_source import iter_images

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"
APPROACH = SAMPLE / "approach"
BASE = ["--camera", str(SAMPLE / "camera.yaml"), "--mount", str(APPROACH / "mount.json"),
        "--layout", str(REPO / "marker_layouts" / "drick-aruco-pyramids.json"),
        "--layout", str(REPO / "marker_layouts" / "drick-aruco-centre.json"), "--quiet"]
FRAMES = 24


def _jsonl(p: Path) -> list[dict]:
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()]


def _read_rosbags(path: Path) -> tuple[list, dict[str, list]]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    msgs: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
        conns = [(c.topic, c.msgtype) for c in r.connections]
        for c, _t, raw in r.messages():
            msgs.setdefault(c.topic, []).append(r.deserialize(raw, c.msgtype))
    return conns, msgs


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    d = tmp_path_factory.mktemp("mcap")
    rec, out = d / "run.mcap", d / "run.jsonl"
    # png: lossless, so that a replay sees the very frames the run saw
    code = main(["run", "--source", str(APPROACH / "approach.mp4"), *BASE,
                 "--frames", str(FRAMES), "--sink", f"jsonl:{out}", "--record", str(rec),
                 "--record-images", "png"])
    assert code == 0
    return rec, _jsonl(out)


def test_rosbags_reads_the_types_counts_and_poses(recorded):
    rec, js = recorded
    conns, msgs = _read_rosbags(rec)
    assert dict(conns) == {
        "/tf_static": "tf2_msgs/msg/TFMessage",
        "/drovisio/camera/camera_info": "sensor_msgs/msg/CameraInfo",
        "/drovisio/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
        "/drovisio/bricks": "vision_msgs/msg/Detection3DArray",
        "/drovisio/target": "geometry_msgs/msg/PoseWithCovarianceStamped",
        "/drovisio/output": "std_msgs/msg/String"}
    n = len(js)
    assert n == FRAMES
    counts = Counter({k: len(v) for k, v in msgs.items()})
    assert counts == {"/tf_static": 1, "/drovisio/camera/camera_info": n,
                      "/drovisio/camera/image_raw/compressed": n, "/drovisio/bricks": n,
                      "/drovisio/output": n,
                      "/drovisio/target": sum(f["target"] is not None for f in js)}
    assert [json.loads(m.data) for m in msgs["/drovisio/output"]] == js
    info = msgs["/drovisio/camera/camera_info"][0]
    assert (info.width, info.height, info.distortion_model) == (640, 480, "plumb_bob")
    img = msgs["/drovisio/camera/image_raw/compressed"][0]
    assert img.format == "png" and bytes(img.data[1:4]) == b"PNG"
    # the mount, in ROS's FLU body frame
    mount = load_mount(APPROACH / "mount.json")
    tf = msgs["/tf_static"][0].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "camera_optical_frame")
    T = flu_from_camera(mount.body_from_camera)
    np.testing.assert_allclose([tf.transform.translation.x, tf.transform.translation.y,
                                tf.transform.translation.z], T[:3, 3], atol=1e-12)
    # every brick of the JSON output, with its pose and covariance, in the same order
    bricks_seen = 0
    for f, arr in zip(js, msgs["/drovisio/bricks"]):
        t = arr.header.stamp.sec + arr.header.stamp.nanosec * 1e-9
        assert t == pytest.approx(f["t"], abs=1e-6)
        assert [d.id for d in arr.detections] == [f"{b['layout']}/{b['instance']}"
                                                  for b in f["bricks"]]
        for det, b in zip(arr.detections, f["bricks"]):
            p = det.results[0].pose.pose
            np.testing.assert_allclose([p.position.x, p.position.y, p.position.z],
                                       b["tvec"], atol=1e-6)
            q = p.orientation
            R = _quat_xyzw_to_R(q.x, q.y, q.z, q.w)
            np.testing.assert_allclose(R, so3_exp(np.array(b["rvec"])), atol=1e-6)
            np.testing.assert_allclose(det.results[0].pose.covariance.reshape(6, 6),
                                       b["covariance"], rtol=1e-5, atol=1e-15)
            assert det.results[0].hypothesis.class_id == b["layout"]
            bricks_seen += 1
    assert bricks_seen >= FRAMES
    # the target, in the body frame (FLU)
    targets = iter(msgs["/drovisio/target"])
    for f in js:
        if f["target"] is None:
            continue
        m = next(targets)
        b = next(x for x in f["bricks"] if x["track"] == f["target"]["track"])
        Tb = np.eye(4)
        Tb[:3, :3], Tb[:3, 3] = so3_exp(np.array(b["rvec"])), b["tvec"]
        want = flu_from_camera(mount.body_from_camera) @ Tb
        p = m.pose.pose.position
        assert m.header.frame_id == "base_link"
        np.testing.assert_allclose([p.x, p.y, p.z], want[:3, 3], atol=1e-6)


def _quat_xyzw_to_R(x, y, z, w):
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _same_poses(a: list[dict], b: list[dict]) -> float:
    """Largest Mahalanobis² distance between the two runs' poses (same bricks per frame)."""
    worst = 0.0
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert [(k["layout"], k["instance"]) for k in x["bricks"]] == \
            [(k["layout"], k["instance"]) for k in y["bricks"]], x["frame"]
        for p, q in zip(x["bricks"], y["bricks"]):
            e = pose_error(so3_exp(np.array(q["rvec"])), q["tvec"],
                           so3_exp(np.array(p["rvec"])), p["tvec"])
            worst = max(worst, mahalanobis2(e, np.array(p["covariance"])))
    return worst


def test_replaying_the_recording_gives_the_same_poses(recorded, tmp_path):
    rec, js = recorded
    out = tmp_path / "replay.jsonl"
    assert main(["run", "--source", str(rec), *BASE, "--sink", f"jsonl:{out}",
                 "--pace", "max"]) == 0
    again = _jsonl(out)
    # the same frames, bricks and measurements; the filter sees the recorded clock (capture
    # stamps) instead of the run's monotonic one: differences far below one sigma
    assert [f["frame"] for f in again] == list(range(len(js)))
    assert _same_poses(js, again) < 1e-3
    for x, y in zip(js, again):
        for p, q in zip(x["bricks"], y["bricks"]):
            assert p["markers"] == q["markers"] and p["measured"] == q["measured"]
            assert p["reprojection_rmse_px"] == q["reprojection_rmse_px"]


class _EndlessCamera:
    """A loopback MJPEG camera showing the sample's first frames over and over (at most 15 a
    second) until closed: a source that never ends by itself, whatever the machine's pace."""

    def __init__(self, n: int = 30):
        cap = cv2.VideoCapture(str(APPROACH / "approach.mp4"))
        self.parts = []
        for _ in range(n):
            ok, img = cap.read()
            assert ok
            jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
            self.parts.append(b"--f\r\nContent-Type: image/jpeg\r\nContent-Length: "
                              + str(len(jpg)).encode() + b"\r\n\r\n" + jpg + b"\r\n")
        cap.release()
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.sock.settimeout(0.2)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/cam.mjpg"
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while not self.stop.is_set():
            try:
                c, _ = self.sock.accept()
            except OSError:
                continue
            threading.Thread(target=self._play, args=(c,), daemon=True).start()

    def _play(self, c: socket.socket):
        try:
            c.recv(4096)
            c.sendall(b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; "
                      b"boundary=f\r\n\r\n")
            k = 0
            while not self.stop.is_set():
                c.sendall(self.parts[k % len(self.parts)])
                k += 1
                self.stop.wait(1 / 15)
        except OSError:
            pass
        finally:
            c.close()

    def close(self):
        self.stop.set()
        self.sock.close()


def test_a_recording_cut_by_kill_9_replays_up_to_its_last_chunk(tmp_path):
    rec = tmp_path / "cut.mcap"
    camera = _EndlessCamera()
    cmd = [sys.executable, "-m", "drovisio.cli", "run", "--source", camera.url, *BASE,
           "--sink", "jsonl:" + str(tmp_path / "o.jsonl"), "--record", str(rec)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        # an endless source: wait for two flushed chunks (one a second), however slowly a
        # loaded machine records them (the bound is for failures only), then cut
        deadline = time.monotonic() + 600
        while sum(1 for _ in _safe_iter(rec)) < 40:
            assert proc.poll() is None, "run ended on an endless source"
            assert time.monotonic() < deadline, "no 40 images recorded"
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(60)
        camera.close()
    assert proc.returncode == -signal.SIGKILL
    kept = list(iter_images(rec))
    assert len(kept) >= 40, len(kept)
    with open(rec, "rb") as f:   # cut: no summary, no footer
        f.seek(-8, 2)
        assert f.read(8) != b"\x89MCAP0\r\n"
    out = tmp_path / "replay.jsonl"
    assert main(["run", "--source", str(rec), *BASE, "--sink", f"jsonl:{out}",
                 "--pace", "max"]) == 0
    again = _jsonl(out)
    assert len(again) == len(kept)
    assert all(f["bricks"] for f in again)   # the sample has bricks in every frame


def _safe_iter(path: Path):
    if not path.exists():
        return iter(())
    return iter_images(path)


@pytest.mark.parametrize("content, says", [
    (b"not an mcap file at all", "not an MCAP file"),
    (b"", "not an MCAP file"),
    (b"\x89MCAP0\r\n\x01" + b"\xff" * 8 + b"\x00" * 40, "no complete image"),   # a huge length
])
def test_a_broken_mcap_source_is_one_line_and_exit_2(capsys, tmp_path, content, says):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    assert main(["run", "--source", str(bad), *BASE]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"drovisio run: {bad}: --source: ") and says in err[-1], err
    assert "Traceback" not in "\n".join(err)
