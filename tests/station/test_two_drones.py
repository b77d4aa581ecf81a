"""Two ``drovisio run`` drones and one station over Zenoh on loopback: both seen with their
targets, a ``kill -9`` seen as lost at once (the drone's liveliness token goes with its
session), a restart seen again without touching the station."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drovisio.station import Fleet, StationLink

pytest.importorskip("zenoh")

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _long_sample(path: Path) -> Path:
    """The sample approach video three times over (30 s at 15 fps): a drone that is still
    flying when it is killed, on a machine of any speed."""
    import cv2

    from drovisio.fileio import write_video

    cap = cv2.VideoCapture(str(SAMPLE / "approach" / "approach.mp4"))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    h, w = frames[0].shape[:2]
    write_video(path, frames * 3, fps=15, size=(w, h))
    return path


def _rendered_video(path: Path) -> Path:
    """8 rendered views of a coded brick, each held 30 frames, at 10 fps (24 s)."""
    from drovisio.camera_file import load_camera
    from drovisio.fileio import write_video
    from drovisio.geometry import rot_z, transform
    from drovisio.layout import load_layout
    from drovisio.synth import BrickInstance, Effects, Ground, Scene, camera_over, render

    cam = load_camera(SAMPLE / "camera.yaml")
    lay = load_layout(REPO / "marker_layouts" / "drick-aruco-centre.json")
    frames = []
    for k in range(8):
        cfw = camera_over([0.0, 0.0, 0.1], 0.9 + 0.05 * k, tilt_deg=10, heading_deg=15 * k)
        img = render(Scene(cam, cfw, Ground("gravel", 1),
                           [BrickInstance(lay, transform(rot_z(0.2), [0, 0, 0.1]), instance=0)]),
                     Effects(noise_sigma=1.0, seed=k), ss=1).image
        frames += [img] * 30
    write_video(path, frames, fps=10, size=(cam.width, cam.height))
    return path


def _drone(port: int, drone_id: str, source: Path, layout: str, web: str = "") -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "drovisio", "run", "--source", str(source),
         "--camera", str(SAMPLE / "camera.yaml"), "--layout", str(REPO / "marker_layouts" / layout),
         "--mount", str(SAMPLE / "approach" / "mount.json"), "--drone-id", drone_id,
         "--sink", f"zenoh:connect=tcp/127.0.0.1:{port}{web}", "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)


def _until(cond, bound: float) -> float | None:
    """Seconds until cond() held, or None if it did not within bound."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < bound:
        if cond():
            return time.monotonic() - t0
        time.sleep(0.02)
    return None


def _state(fleet: Fleet, drone: str) -> str | None:
    return next((d.state for d in fleet.status() if d.drone_id == drone), None)


def _target(fleet: Fleet, drone: str):
    return next((d.target for d in fleet.status() if d.drone_id == drone), None)


def test_station_sees_two_drones_a_kill_and_a_restart(tmp_path):
    port = _free_port()
    fleet = Fleet()
    link = StationLink(fleet, listen=[f"tcp/127.0.0.1:{port}"])
    video = _rendered_video(tmp_path / "rendered.mp4")
    sample = _long_sample(tmp_path / "approach.mp4")
    one = _drone(port, "drone1", sample, "drick-aruco-pyramids.json",
                 web="&web=http://127.0.0.1:18080/")
    two = _drone(port, "drone2", video, "drick-aruco-centre.json")
    procs = [one, two]
    try:
        # both seen with a target (the first frames also load the detectors' kernels)
        seen: dict[str, dict] = {}

        def targets() -> bool:
            for d in fleet.status():
                if d.target is not None and d.state == "live":
                    seen.setdefault(d.drone_id, d.target)
            return len(seen) == 2

        assert _until(targets, 90) is not None, (fleet.status(), one.poll(), two.poll())
        assert _until(lambda: {d.drone_id: d.state for d in fleet.status()}
                      == {"drone1": "live", "drone2": "live"}, 10) is not None
        t1, t2 = seen["drone1"], seen["drone2"]
        assert t1["layout"] == "drick-aruco-pyramids" and t2["layout"] == "drick-aruco-centre"
        assert 0.3 < float(np.linalg.norm(t2["tvec"])) < 2.0    # metres from the camera
        info = {d.drone_id: d.info for d in fleet.status()}
        assert info == {"drone1": {"web": "http://127.0.0.1:18080/"}, "drone2": {}}
        # kill -9: no goodbye from the drone; its session's end withdraws its token
        os.kill(one.pid, signal.SIGKILL)
        one.wait(10)
        lost_after = _until(lambda: _state(fleet, "drone1") == "lost", 2.0)
        assert lost_after is not None, fleet.status()
        assert _state(fleet, "drone2") == "live"
        # a restart is seen again by the same station
        one = _drone(port, "drone1", sample, "drick-aruco-pyramids.json")
        procs.append(one)
        assert _until(lambda: _state(fleet, "drone1") == "live", 60) is not None
        assert link.dropped == 0
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(10)
        link.close()
