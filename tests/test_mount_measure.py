"""Measuring the camera mount from a code lying flat in view of the drone standing level:
rendered with known mounts, measured through the whole detector."""

from __future__ import annotations

import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.mount import Mount, MountError, measure_mount
from drovisio.scenes import level_drone_over_code

# the shipped landing pad: five codes over 0.6 m of a flat plate (one 0.30 m code)
LAYOUT = load_layout(shipped_layouts_dir() / "landing-pad.json")


def _shot(mount: Mount, heading_deg: float, brick_yaw_deg: float, height: float = 1.0,
          seed: int = 0):
    return level_drone_over_code(mount.body_from_camera, LAYOUT, heading_deg, brick_yaw_deg,
                                 height, seed)


@pytest.mark.parametrize("tilt, pan, roll", [(20.0, 0.0, 0.0), (35.0, 4.0, -3.0),
                                             (12.0, -6.0, 5.0)])
def test_the_mount_is_measured_within_half_a_degree(tilt, pan, roll):
    truth = Mount.from_angles(tilt, pan, roll, offset_m=(0.08, 0.0, 0.05))
    det = ArucoBrickDetector(Camera.drone_webcam(), [LAYOUT])
    aligned, turned = [], []
    for k, heading in enumerate((0.0, 70.0, 200.0)):
        for yaw, out in ((0.0, aligned), (37.0 + 50 * k, turned)):
            r = _shot(truth, heading, yaw, seed=k)
            poses = det.detect(r.image)
            assert len(poses) == 1
            out.append(poses[0].camera_from_brick())
    m = measure_mount(aligned, aligned=True)
    assert abs(m["tilt_deg"] - tilt) < 0.5 and abs(m["roll_deg"] - roll) < 0.5
    assert abs(m["pan_deg"] - pan) < 0.5 and m["n"] == 3 and m["spread_deg"] < 1.0
    # a brick at any heading: tilt and roll still, no pan
    m = measure_mount(turned)
    assert abs(m["tilt_deg"] - tilt) < 0.5 and abs(m["roll_deg"] - roll) < 0.5
    assert m["pan_deg"] is None


def test_nothing_in_view_says_what_to_do():
    with pytest.raises(MountError, match="put a shipped code flat on the ground"):
        measure_mount([])


def test_calibrate_mount_command_writes_the_mount_file(tmp_path, capsys):
    import json

    import cv2

    from drovisio import cli
    from drovisio.camera_file import save_camera
    from drovisio.mount import load_mount

    truth = Mount.from_angles(25.0, 3.0, -2.0)
    for k, heading in enumerate((0.0, 120.0)):
        cv2.imwrite(str(tmp_path / f"pad{k}.png"), _shot(truth, heading, 0.0, seed=k).image)
    (tmp_path / "broken.jpg").write_bytes(b"\xff\xd8\xff garbage")
    save_camera(Camera.drone_webcam(), tmp_path / "camera.yaml")
    out = tmp_path / "mount.json"
    rc = cli.main(["calibrate", "mount", "--camera", str(tmp_path / "camera.yaml"), "--aligned",
                   "--offset", "0.08", "0", "0.05", "--out", str(out), str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "pad0.png: 1 code brick(s) lying flat (landing-pad)" in err
    assert "broken.jpg: skipped" in err and "Traceback" not in err
    # where a straight descent onto each brick goes blind with this mount, and straight down
    line = [ln for ln in err.splitlines() if ln.startswith("landing on a drick-aruco-centre")][0]
    assert "with this mount (tilt 25°) the brick" in line and "looking straight down" in line
    m = load_mount(out).angles()
    assert abs(m["tilt_deg"] - 25.0) < 0.5 and abs(m["pan_deg"] - 3.0) < 0.5
    assert abs(m["roll_deg"] + 2.0) < 0.5 and m["offset_m"] == [0.08, 0.0, 0.05]
    assert "measured from 2 picture(s)" in json.loads(out.read_text())["note"]
    # no code in view: one line that says what to do
    blank = tmp_path / "blank"
    blank.mkdir()
    cv2.imwrite(str(blank / "ground.png"), np.full((480, 640, 3), 120, np.uint8))
    rc = cli.main(["calibrate", "mount", "--camera", str(tmp_path / "camera.yaml"),
                   "--out", str(tmp_path / "m2.json"), str(blank)])
    err = capsys.readouterr().err
    assert rc == 2 and err.strip().endswith("in front of the drone")
    assert not (tmp_path / "m2.json").exists()
