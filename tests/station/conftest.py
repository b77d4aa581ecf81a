"""Drones for the station's tests: ``drovisio run`` processes publishing over Zenoh on
loopback, from the sample video (long enough to be killed while flying) and from rendered
frames."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"


def long_sample(path: Path) -> Path:
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


def rendered_video(path: Path) -> Path:
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


def drone(port: int, drone_id: str, source: Path, layout: str, web: str = "") -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "drovisio", "run", "--source", str(source),
         "--camera", str(SAMPLE / "camera.yaml"), "--layout", str(REPO / "marker_layouts" / layout),
         "--mount", str(SAMPLE / "approach" / "mount.json"), "--drone-id", drone_id,
         "--sink", f"zenoh:connect=tcp/127.0.0.1:{port}{web}", "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)


@pytest.fixture
def drones(free_port) -> SimpleNamespace:
    """The helpers above, for the tests of this folder."""
    return SimpleNamespace(REPO=REPO, SAMPLE=SAMPLE, free_port=free_port, long_sample=long_sample,
                           rendered_video=rendered_video, drone=drone)
