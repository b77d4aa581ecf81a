"""The shipped landing-pad pictures measure their mount (README's example, as printed);
the pan is refused when the codes seen cannot tell where the nose is; the ground the camera
sees is said honestly at any tilt."""

from __future__ import annotations

import numpy as np
import pytest

from drovisio.calibration.mount import measure_from_images
from drovisio.camera import Camera
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.mount import Mount, ground_footprint, load_mount
from drovisio.resources import sample_sessions_dir
from drovisio.scenes import level_drone_over_code

PAD_DIR = sample_sessions_dir() / "pad"


def test_the_shipped_pad_pictures_give_their_mount(tmp_path, capsys, monkeypatch):
    from drovisio import cli

    truth = load_mount(PAD_DIR / "mount.json").angles()
    monkeypatch.chdir(sample_sessions_dir().parent)     # README's paths, as printed
    out = tmp_path / "mount.json"
    rc = cli.main(["calibrate", "mount", "--camera", "sample_sessions/camera.yaml", "--aligned",
                   "--out", str(out), "sample_sessions/pad"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert err.count("1 code brick(s) lying flat (landing-pad)") == len(list(PAD_DIR.glob("*.jpg")))
    got = load_mount(out).angles()
    assert truth["tilt_deg"] == 20.0
    for k in ("tilt_deg", "pan_deg", "roll_deg"):
        assert abs(got[k] - truth[k]) < 0.3, (k, got, truth)


def test_the_pan_is_refused_from_bricks_and_said_why():
    truth = Mount.from_angles(20.0, 0.0, 0.0)
    brick = load_layout(shipped_layouts_dir() / "drick-aruco-pyramids.json")
    shots = [(f"brick{k}", level_drone_over_code(truth.body_from_camera, brick, 30.0 * k,
                                                  yaw, 0.9, seed=k).image)
             for k, yaw in enumerate((-69.5, 40.0))]
    m = measure_from_images(shots, Camera.drone_webcam(), [brick], aligned=True)
    assert m.result["pan_deg"] is None
    assert "drick-aruco-pyramids" in m.result["pan_refused"]
    assert m.lines[0] == m.result["pan_refused"]
    # tilt and roll are known all the same
    assert abs(m.result["tilt_deg"] - 20.0) < 1.0 and abs(m.result["roll_deg"]) < 1.0


def test_pad_pictures_that_disagree_on_the_nose_give_no_pan():
    truth = Mount.from_angles(20.0, 0.0, 0.0)
    pad = load_layout(shipped_layouts_dir() / "landing-pad.json")
    shots = [(f"pad{k}", level_drone_over_code(truth.body_from_camera, pad, 0.0, yaw, 1.0,
                                                seed=k).image)
             for k, yaw in enumerate((0.0, 25.0))]
    m = measure_from_images(shots, Camera.drone_webcam(), [pad], aligned=True)
    assert m.result["pan_deg"] is None and "disagree" in m.result["pan_refused"]
    assert "25°" in m.result["pan_refused"]


@pytest.mark.parametrize("tilt, sees, horizon", [(20.0, True, False), (70.0, True, True),
                                                 (120.0, False, True)])
def test_the_ground_in_view_at_any_tilt(tilt, sees, horizon):
    f = ground_footprint(Mount.from_angles(tilt), Camera.drone_webcam(), 1.5)
    assert f["sees_ground"] is sees and f["horizon"] is horizon
    if sees and not horizon:
        assert f["below"] and 1.0 < f["farthest_m"] < 3.0
    assert np.isfinite(f["farthest_m"])
