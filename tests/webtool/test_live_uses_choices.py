"""On the demo (the sample session), a mount saved on the mount page and a calibration
chosen with "Use this calibration" are what the live view uses at once, without a restart;
measuring the mount from the demo's bricks refuses the pan and says why."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from fastapi.testclient import TestClient

from drovisio.camera_file import load_camera, save_camera
from drovisio.mount import body_from_camera_angles
from drovisio.resources import sample_sessions_dir
from webtool.app import create_app
from webtool.services import get_service
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"


@pytest.fixture
def app(tmp_path):
    a = create_app(Settings(data_dir=tmp_path / "data"))
    yield a
    from webtool.services import close_services

    close_services(a)


def _wait_frames(live, until, n: int = 2, timeout: float = 60.0) -> None:
    start = live.seq
    until(lambda: live.seq >= start + n, timeout, pause=0.05, say=lambda _: live.error)


def test_a_saved_mount_is_used_by_the_live_view_at_once(app, tmp_path, until):
    client = TestClient(app, base_url=LOCAL)
    live = get_service(app, "live")
    live.ensure_started()
    _wait_frames(live, until)
    assert abs(live.mount.angles()["tilt_deg"] - 20.0) < 1e-6          # the sample's

    # measured from the demo's bricks "with the x arrow to the nose": no pan, and why
    r = client.post("/api/mount/measure-live", json={"aligned": True})
    assert r.status_code == 200, r.text
    got = r.json()
    assert got["pan_measured"] is False and "drick" in got["pan_refused"]
    assert got["proposed"]["pan_deg"] == 0.0 and abs(got["proposed"]["tilt_deg"] - 20) < 1.5

    angles = {"tilt_deg": 33.0, "pan_deg": 0.0, "roll_deg": 0.0, "offset_m": [0.08, 0, 0.05]}
    assert client.post("/api/mount/preview", json={"angles": angles}).status_code == 200
    r = client.post("/api/mount/save")
    assert r.status_code == 200, r.text
    saved = tmp_path / "data" / "mount" / "mount.json"
    assert saved.is_file()
    # no restart: the running pipeline now uses it
    assert live.config().mount_file == saved
    assert np.allclose(live.mount.body_from_camera,
                       body_from_camera_angles(33.0, 0.0, 0.0, (0.08, 0, 0.05)), atol=1e-9)
    _wait_frames(live, until)
    assert live.pipeline is not None and live.error is None
    # and after a restart too
    again = create_app(Settings(data_dir=tmp_path / "data"))
    assert again.state.settings.mount == saved


def test_a_chosen_calibration_is_used_by_the_live_view_at_once(app, tmp_path, until):
    live = get_service(app, "live")
    live.ensure_started()
    _wait_frames(live, until)
    fx_before = live.camera.fx
    # what "Use this calibration" does to the settings, then tells the live view
    cam = load_camera(sample_sessions_dir() / "camera.yaml")
    K = cam.K.copy()
    K[0, 0] *= 1.01
    path = save_camera(dataclasses.replace(cam, K=K), tmp_path / "chosen.yaml")
    app.state.settings.camera = path
    live.reconfigure()
    assert live.camera.fx == pytest.approx(fx_before * 1.01)
    _wait_frames(live, until)
    assert live.error is None
