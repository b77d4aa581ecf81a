"""``drovisio mission check | simulate | diagram``."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import yaml

from drovisio import cli
from drovisio.mission import diagram
from drovisio.mission.machine import TRANSITIONS, State


def _write(scn, path):
    path.write_text(yaml.safe_dump(scn.model_dump(by_alias=True, exclude_none=True),
                                   sort_keys=False))
    return str(path)


def test_help_has_examples(capsys):
    for action in ("check", "simulate", "diagram", "landing"):
        assert cli.main(["mission", action, "--help"]) == 0
        out = capsys.readouterr().out
        assert "Example:" in out and f"drovisio mission {action}" in out.split("Example:")[1]
    assert cli.main(["mission"]) == 2


def test_diagram_covers_the_table(capsys):
    assert cli.main(["mission", "diagram"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("stateDiagram-v2")
    for s in State:
        assert s.value in text
    edges = diagram.grouped_edges()
    groups = {g.key: set(g.members) for g in diagram.GROUPS}
    covered = set()
    for src, trig, dst, _ in edges:
        for s in groups.get(src, {State(src)} if src in State.__members__ else set()):
            covered.add((s, trig, State(dst)))
    assert covered == {(t.source, t.trigger, t.target) for t in TRANSITIONS}
    assert cli.main(["mission", "diagram", "--format", "dot"]) == 0
    assert capsys.readouterr().out.startswith("digraph mission {")
    ET.fromstring(diagram.svg())  # well-formed


def test_check_prints_the_table_and_exits_0(small, tmp_path, capsys):
    path = _write(small, tmp_path / "small.yaml")
    rc = cli.main(["mission", "check", path, "--fault", "missed grab", "--fault",
                   "three failed drops", "--json", str(tmp_path / "t.json")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "missed grab" in out and "three failed drops" in out and "all held" in out
    # the scenario's drone landing with ArduPilot's precision landing, and straight down
    landing = [ln for ln in out.splitlines() if ln.startswith("precision landing on a")]
    assert len(landing) == 2 and "touchdown error median" in landing[0]
    assert "leaves the picture" in landing[0] and "straight down" in landing[1]
    rows = json.loads((tmp_path / "t.json").read_text())
    assert [r["outcome"] for r in rows] == ["completed", "safe_zone"]


def test_check_rejects_an_invalid_scenario(small, tmp_path, capsys):
    d = small.model_dump(by_alias=True, exclude_none=True)
    d["bricks"][0]["instance"] = 99
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(d))
    assert cli.main(["mission", "check", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"{p}: bricks[0].instance" in err


def test_simulate_records(small, tmp_path, capsys):
    path = _write(small, tmp_path / "small.yaml")
    rc = cli.main(["mission", "simulate", path, "--bricks", "1", "--record",
                   str(tmp_path / "rec")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "outcome: DONE" in out and "placement error: max" in out
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["outcome"] == "DONE" and manifest["rules"]["geofence"] is True
    assert (tmp_path / "rec" / "ticks.jsonl").stat().st_size > 10_000


def test_check_exits_1_when_an_outcome_is_not_the_expected_one(small, tmp_path, monkeypatch,
                                                                capsys):
    from drovisio.mission import faults

    wrong = faults.FaultCase("no fault, wrongly expected to abort", (), "safe_zone")
    monkeypatch.setattr(faults, "CHECK_FAULTS", (wrong,))
    path = _write(small.subset(["b1"]), tmp_path / "one.yaml")
    assert cli.main(["mission", "check", path]) == 1
    out = capsys.readouterr().out
    assert "expected safe_zone, got completed" in out


def test_landing_prints_errors_for_a_mount_and_warns_below_2_hz(capsys):
    assert cli.main(["mission", "landing", "--tilt", "20", "--runs", "4"]) == 0
    out = capsys.readouterr().out
    assert "this mount (tilt 20°)" in out and "straight down" in out and "WARNING" not in out
    assert cli.main(["mission", "landing", "--rate", "1.5", "--runs", "2"]) == 0
    out = capsys.readouterr().out
    assert "initialised in 0% of them" in out and "WARNING: 1.4 detections a second" in out


def test_a_camera_tilt_beyond_the_horizon_is_refused_in_one_line(small, tmp_path, capsys):
    d = small.model_dump(by_alias=True, exclude_none=True)
    d["drone"]["camera"]["mount"]["tilt_deg"] = 1e308
    p = tmp_path / "tilt.yaml"
    p.write_text(yaml.safe_dump(d))
    assert cli.main(["mission", "check", str(p)]) == 2
    err = capsys.readouterr().err
    assert err == (f"drovisio mission: {p}: drone.camera.mount.tilt_deg: 1e+308 is out of "
                   "range: give a number from -90 to 90 degrees\n")
    assert cli.main(["mission", "landing", "--tilt", "1e308"]) == 2
    assert ("argument --tilt: 1e+308 is out of range: give a number from -90 to 90"
            in capsys.readouterr().err)


def _with_camera(small, path, camera_file: str):
    d = small.model_dump(by_alias=True, exclude_none=True)
    d["drone"]["camera"]["file"] = camera_file
    path.write_text(yaml.safe_dump(d))
    return path


def test_a_camera_file_that_cannot_be_read_is_one_line_naming_scenario_and_field(
        small, tmp_path, capsys):
    import os

    os.mkfifo(tmp_path / "pipe.yaml")
    (tmp_path / "text.yaml").write_text("root:x:0:0:root:/root:/bin/bash\n")
    cases = {
        "nocam.yaml": f"{tmp_path / 'nocam.yaml'}: camera file not found",
        "pipe.yaml": f"{tmp_path / 'pipe.yaml'}: not a regular file (a pipe or device); "
                     "give the camera file itself",
        str(tmp_path): f"{tmp_path}: is a folder; give the camera file itself",
        "text.yaml": f"{tmp_path / 'text.yaml'}: not a camera file: expected OpenCV "
                     "FileStorage fields 'camera_matrix' and 'distortion_coefficients'",
    }
    for name, why in cases.items():
        p = _with_camera(small, tmp_path / "scn.yaml", name)
        for action in (["check", str(p), "--fault", "no fault"],
                       ["simulate", str(p), "--record", str(tmp_path / "rec")]):
            assert cli.main(["mission", *action]) == 2
            out, err = capsys.readouterr()
            # said when the scenario is read, before anything is simulated
            assert out == "" and err == f"drovisio mission: {p}: drone.camera.file: {why}\n"
    assert not (tmp_path / "rec").exists()


def test_a_camera_file_beside_or_anywhere_is_still_read(small, tmp_path):
    from drovisio.camera import Camera
    from drovisio.camera_file import save_camera
    from drovisio.mission.scenario import load_scenario
    from drovisio.mission.sim import camera_for

    cam = Camera.from_fov(800, 600, 70.0)
    (tmp_path / "site").mkdir()
    save_camera(cam, tmp_path / "site" / "cam.yaml")
    (tmp_path / "plans").mkdir()
    for name in ("../site/cam.yaml", str(tmp_path / "site" / "cam.yaml")):
        scn = load_scenario(_with_camera(small, tmp_path / "plans" / "scn.yaml", name))
        assert camera_for(scn).K.tolist() == cam.K.tolist()
        assert (camera_for(scn).width, camera_for(scn).height) == (800, 600)
    assert camera_for(small).width == 640   # the built-in webcam
