"""The camera mount page's API: the human form, its preview (ground in view, 3D scene), the
mount file written and read back, measuring it from pictures and from the live camera, and
hostile input."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from drovisio.camera_file import load_camera
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.mount import Mount, body_from_camera_angles, load_mount
from drovisio.resources import sample_sessions_dir
from drovisio.scenes import level_drone_over_code
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"
API = "/api/mount"
PAD = load_layout(shipped_layouts_dir() / "landing-pad.json")


@pytest.fixture
def client(tmp_path):
    app = create_app(Settings(mount_dir=tmp_path / "mount", calibration_dir=tmp_path / "cal"))
    with TestClient(app, base_url=LOCAL) as c:
        yield c


def _angles(tilt, pan=0.0, roll=0.0, offset=(0.0, 0.0, 0.0)):
    return {"tilt_deg": tilt, "pan_deg": pan, "roll_deg": roll, "offset_m": list(offset)}


def test_the_sample_mount_and_the_ground_it_sees(client):
    st = client.get(API).json()
    assert st["angles"] == _angles(20.0, offset=(0.08, 0.0, 0.05))
    assert st["saved"] is False and st["loaded_from"].endswith("approach/mount.json")
    # the optical axis meets the ground 1.45 m below the camera, tan(20°) of that ahead
    f, r = st["footprint"]["centre"]
    assert f == pytest.approx(0.08 + 1.45 * math.tan(math.radians(20)), abs=1e-3)
    assert r == pytest.approx(0.0, abs=1e-6)
    assert st["footprint"]["below"] is True


def test_preview_moves_the_camera_in_the_3d_scene(client):
    sc = client.get(f"{API}/scene").json()
    assert sc["url"] == "/mount/3d/" and sc["port"]
    body = {"angles": _angles(60.0, 10.0, -5.0, (0.1, 0.02, 0.03)), "height_m": 2.0}
    st = client.post(f"{API}/preview", json=body).json()
    T = body_from_camera_angles(60.0, 10.0, -5.0, (0.1, 0.02, 0.03))
    assert np.allclose(st["body_from_camera"], T, atol=1e-6)
    # 60° forward at 2 m: the ground under the drone is out of view; the axis meets it ahead
    fp = st["footprint"]
    assert fp["below"] is False and fp["nearest_m"] > 0.5
    axis_f = 0.1 + (2.0 - 0.03) * math.tan(math.radians(60)) * math.cos(math.radians(10))
    assert fp["centre"][0] == pytest.approx(axis_f, abs=1e-3)
    shown = client.get(f"{API}/scene").json()["shown"]
    assert np.allclose(shown["body_from_camera"], T) and shown["height_m"] == 2.0
    assert client.get("/mount/3d/").status_code == 200      # viser's page through the app
    assert st["saved"] is False


def test_save_writes_both_forms_and_a_camera_source_uses_it(client, tmp_path):
    body = {"angles": _angles(32.5, -4.0, 1.5, (0.12, -0.01, 0.04)), "height_m": 1.0}
    client.post(f"{API}/preview", json=body)
    st = client.post(f"{API}/save").json()
    path = tmp_path / "mount" / "mount.json"
    assert st["saved"] is True and st["file"] == str(path)
    data = json.loads(path.read_text())
    assert data["camera"]["tilt_deg"] == pytest.approx(32.5)
    assert data["camera"]["offset_m"] == pytest.approx([0.12, -0.01, 0.04])
    T = body_from_camera_angles(32.5, -4.0, 1.5, (0.12, -0.01, 0.04))
    assert np.allclose(load_mount(path).body_from_camera, T, atol=1e-9)
    # the page reopens on it; a camera source (not the sample) uses it from the next start
    assert client.get(API).json()["saved"] is True
    again = create_app(Settings(mount_dir=tmp_path / "mount", source="0",
                                calibration_dir=tmp_path / "cal"))
    assert again.state.settings.mount == path
    sample = create_app(Settings(mount_dir=tmp_path / "mount", calibration_dir=tmp_path / "cal"))
    assert sample.state.settings.mount == path          # the demo uses it too


def test_measure_from_pictures_of_a_code_lying_flat(client):
    camera = load_camera(sample_sessions_dir() / "camera.yaml")
    truth = Mount.from_angles(27.0, 6.0, -3.0)
    files = []
    for k, heading in enumerate((0.0, 140.0)):
        img = level_drone_over_code(truth.body_from_camera, PAD, heading, 0.0, seed=k,
                                    camera=camera).image
        files.append(("files", (f"pad{k}.png", cv2.imencode(".png", img)[1].tobytes(),
                                "image/png")))
    files.append(("files", ("notes.jpg", b"\xff\xd8\xff not a picture", "image/jpeg")))
    r = client.post(f"{API}/measure", params={"aligned": "true"}, files=files)
    assert r.status_code == 200, r.text
    got = r.json()
    p = got["proposed"]
    assert abs(p["tilt_deg"] - 27.0) < 0.5 and abs(p["roll_deg"] + 3.0) < 0.5
    assert abs(p["pan_deg"] - 6.0) < 0.5 and got["pictures"] == 2 and got["pan_measured"]
    assert any(line.startswith("notes.jpg: skipped") for line in got["lines"])
    # nothing measurable: one line that names the picture
    r = client.post(f"{API}/measure", files=[files[-1]])
    assert r.status_code == 422
    assert "notes.jpg" in r.json()["detail"] and "flat" in r.json()["detail"]


def test_measure_from_the_live_camera(client):
    # the sample: a drone with the 20° mount over bricks lying flat
    r = client.post(f"{API}/measure-live", json={"aligned": False})
    assert r.status_code == 200, r.text
    got = r.json()
    assert got["pictures"] >= 3 and abs(got["proposed"]["tilt_deg"] - 20.0) < 1.5
    assert got["proposed"]["offset_m"] == [0.08, 0.0, 0.05]   # offsets are not measured


def test_a_live_camera_slow_to_give_frames_is_waited_for(monkeypatch):
    """A camera that starts, or gives frames slower than the 4 s for one (a busy machine
    measuring each, the first one loading the detectors): its frames are waited for, not
    called "no frame: is it connected?"; one that is lost is said after 4 s."""
    from types import SimpleNamespace

    from drovisio.sources import SourceState
    from webtool.mount import service

    class Live:
        """Each frame comes after 30 looks (1.5 s at the service's 20 a second)."""

        error, camera, layouts = None, None, None

        def __init__(self, state):
            self.looks = 0
            self.pipeline = SimpleNamespace(source=SimpleNamespace(state=state))

        def ensure_started(self):
            pass

        def latest_image(self):
            self.looks += 1
            k = self.looks // 30
            return None if k == 0 else (k, np.zeros((4, 4, 3), np.uint8))

    svc = service.MountService(Settings())
    monkeypatch.setattr(service, "measure_from_images", lambda got, *a: [n for n, _ in got])
    monkeypatch.setattr(svc, "_result", lambda measured, aligned: measured)
    got = svc.measure_live(Live(SourceState.LIVE), aligned=False, timeout=0.2)
    assert got == [f"live frame {k}" for k in range(1, 6)]
    with pytest.raises(service.Conflict, match="no frame from the camera in 0.2 s: is it "):
        svc.measure_live(Live(SourceState.LOST), aligned=False, timeout=0.2)


@pytest.mark.parametrize("body", [
    {"angles": _angles(181.0)}, {"angles": _angles(20.0, 200.0)},
    {"angles": _angles(20.0, offset=(50.0, 0.0, 0.0))}, {"angles": _angles(20.0), "height_m": 0},
    {"angles": {**_angles(20.0), "yaw": 3}}, {"angles": _angles(20.0), "extra": 1}, {},
])
def test_bad_mounts_are_refused_by_field(client, body):
    r = client.post(f"{API}/preview", json=body)
    assert r.status_code == 422 and r.json()["detail"]


def test_non_finite_and_too_many_pictures(client):
    r = client.post(f"{API}/preview", content=b'{"angles": {"tilt_deg": NaN}}',
                    headers={"content-type": "application/json"})
    assert r.status_code == 422
    many = [("files", (f"p{i}.png", b"x", "image/png")) for i in range(21)]
    r = client.post(f"{API}/measure", files=many)
    assert r.status_code == 422 and "at most 20" in r.json()["detail"]


def test_the_mount_page_says_where_the_landing_goes_blind(client):
    st = client.get(API).json()
    blind = {b["layout"]: b for b in st["blind"]}
    centre = blind["drick-aruco-centre"]
    assert 1.6 < centre["leaves_at_m"] < 1.8          # the sample mount: 20° forward
    assert centre["straight_down_leaves_at_m"] < 0.4
    st = client.post(API + "/preview", json={"angles": _angles(0.0, offset=(0.08, 0.0, 0.05)),
                                            "height_m": 1.5}).json()
    centre = {b["layout"]: b for b in st["blind"]}["drick-aruco-centre"]
    assert centre["leaves_at_m"] == pytest.approx(centre["straight_down_leaves_at_m"])
