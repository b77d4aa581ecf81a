"""``drovisio study``: protocols checked by field, rendered and recorded steps through the
same analysis, every figure drawn and read back, AprilTag 3's conventions measured, the
errors the benchmarks' own, and bad input named without stopping the study."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from drovisio import cli
from drovisio.camera import Camera
from drovisio.layout import load_layout, shipped_layouts_dir, with_dictionary
from drovisio.study import run as study_run
from drovisio.study.analysis import frame_errors
from drovisio.study.example import write_recorded_example
from drovisio.study.frames import step_frames, truth_camera_from_brick
from drovisio.study.methods import APRILTAG_PIXEL_OFFSET, METHODS
from drovisio.study.protocol import (
    FIGURES,
    PROTOCOL_SCHEMA,
    ProtocolError,
    Step,
    default_protocol,
    load_protocol,
)
from drovisio.study.report import write_report
from drovisio.study.run import StudyCancelled, run_study

CODE = load_layout(shipped_layouts_dir() / "drick-aruco-centre.json")


def _small_protocol(frames: int = 2) -> dict:
    """Every thesis figure once or twice: 18 steps."""
    full = default_protocol(quick=True, frames=frames)
    keep, seen = [], {}
    for s in full.steps:
        key = (s.figure, s.layout, s.vary)
        if seen.get(key, 0) < (2 if s.vary in ("distance", "offset_x") else 1) and \
                s.layout in ("dots", "code", "code-36h11"):
            seen[key] = seen.get(key, 0) + 1
            keep.append(s.model_dump(exclude_none=True))
    return {"schema": PROTOCOL_SCHEMA, "name": "small",
            "layouts": [x.model_dump(exclude_none=True) for x in full.layouts
                        if x.name != "two-codes"], "steps": keep}


@pytest.fixture(scope="module")
def small_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    proto = load_protocol(_write(out / "p.yaml", _small_protocol()))
    res = run_study(proto, out, memory_seconds=1.0, speed_bricks=(1, 3), speed_frames=1,
                    landing_runs=3)
    data = write_report(res, out / "report", "drovisio study run --protocol p.yaml", "text")
    return res, data, out / "report"


def _write(path: Path, data) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_every_figure_is_drawn_and_reads_back(small_study):
    res, data, out = small_study
    assert set(data["figures"]) == {*FIGURES, "6.10", "6.11"}
    for fig in data["figures"]:
        img = cv2.imread(str(out / f"fig-{fig}.png"))
        assert img is not None and img.shape[0] > 200 and img.shape[1] > 400, fig
    for fig in FIGURES:
        panels = data["figures"][fig]["panels"]
        assert panels, fig
        for p in panels:
            assert p["ylabel"] and p["xlabel"], (fig, p)
            # one box per applicable method and step; the others named, not dropped
            for m, n in p["boxes"].items():
                assert n == len(p["values"]), (fig, p["layout"], m, n)
            kind = FIGURES[fig]["kind"]
            # AprilTag 3 reads the 4x4 codes too (given to it as a family)
            expect = {"dots": {"drovisio-dots", "drovisio-dots-image"},
                      "codes": {"drovisio-codes", "drovisio-codes-image", "opencv",
                                "apriltag3"}}[kind]
            assert set(p["boxes"]) == expect, (fig, p["layout"], p["boxes"])
            if kind == "codes":
                assert "apriltag3" not in p.get("not_applicable", {})
    assert set(data["figures"]["6.11"]["methods"]) == {
        m for m, x in METHODS.items() if not x.accuracy_only}
    assert any(pts for pts in data["figures"]["6.10"]["lines"].values())
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 10
    assert "drovisio study run --protocol p.yaml" in html and "Versions and machine" in html
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert len(lines) == len(res.records) and json.loads(lines[0])["method"] in METHODS


def test_the_figures_hold_the_measured_errors(small_study):
    res, data, _ = small_study
    # Drovisio on the one-code brick, square-on at the nearest distance (0.4 m):
    # millimetres, not centimetres
    near = min(r["value"] for r in res.records if r["vary"] == "distance")
    assert near <= 0.4
    rs = [r for r in res.records if r["layout"] == "code" and r["vary"] == "distance"
          and r["value"] == near and r["method"] == "drovisio-codes"]
    assert rs and all(r["found"] for r in rs)
    assert max(r["errors"]["z_pct"] for r in rs) < 1.0
    assert max(r["errors"]["xy_cm"] for r in rs) < 0.3
    s = [x for x in data["summary"] if x["layout"] == "dots" and x["vary"] == "rot_z"]
    assert s and all(x["found"] == x["frames"] and x["p95"] < 1.0 for x in s)


def test_errors_are_the_benchmarks_own_on_the_same_frames():
    from drovisio.bench.aruco import Frame, Stats, _errors
    from drovisio.detect.aruco import ArucoBrickDetector

    cam = Camera.drone_webcam()
    det = ArucoBrickDetector(cam, [CODE])
    step = Step(figure="6.6", layout="code", vary="offset_x", value=0.3, frames=3)
    for fr in step_frames(step, CODE, cam, 11, Path(".")):
        poses = det.detect(fr.image)
        assert len(poses) == 1

        class Truth:
            layout, instance = CODE.name, 0
            camera_from_brick = fr.camera_from_brick
            tvec = fr.camera_from_brick[:3, 3]
            code_corners_px: dict = {}

        st = Stats()
        _errors(st, poses, Frame(fr.image, [Truth()], np.zeros(3), {}, 0.0), 640, 480)
        e = frame_errors(poses[0].camera_from_brick(), fr.camera_from_brick)
        assert abs(e["lateral_mm"] - st.lateral_mm[0]) < 0.1
        assert abs(e["depth_pct"] - st.depth_pct[0]) < 0.01
        assert abs(e["yaw_deg"] - st.yaw_deg[0]) < 0.01


def test_dot_errors_are_the_dot_benchmarks_own():
    from types import SimpleNamespace

    from drovisio.bench.dots.scoring import truth_pose_errors as _pose_errors
    from drovisio.detect.dots import DotDetector

    cam = Camera.drone_webcam()
    dots = load_layout(shipped_layouts_dir() / "drick-dots-2x3.json")
    det = DotDetector(cam, [dots])
    step = Step(figure="6.5", layout="dots", vary="rot_z", value=30.0, frames=3)
    n = 0
    for fr in step_frames(step, dots, cam, 12, Path(".")):
        for p in det.detect(fr.image):
            T = p.camera_from_brick()
            b = _pose_errors(SimpleNamespace(camera_from_brick=fr.camera_from_brick),
                             T[:3, :3], T[:3, 3], True)
            e = frame_errors(T, fr.camera_from_brick, symmetric=True, kind="dots")
            assert abs(e["lateral_mm"] - 1000 * b["lateral_m"]) < 0.1
            assert abs(e["depth_pct"] - 100 * b["depth_rel"]) < 0.01
            assert abs(e["yaw_deg"] - b["yaw_deg"]) < 0.01
            n += 1
    assert n == 3


def test_apriltag_corners_in_opencvs_convention():
    pytest.importorskip("pupil_apriltags")
    from drovisio.study.methods import apriltag_detector

    lay = with_dictionary(CODE, "DICT_APRILTAG_36h11")
    cam = Camera.from_fov(640, 480, 60.0)            # no distortion: the corners as drawn
    det = apriltag_detector("tag36h11")
    offs = []
    for value in (0.4, 0.6):
        step = Step(figure="6.7", layout="c", vary="distance", value=value, frames=2)
        for fr in step_frames(step, lay, cam, 5, Path("."), ss=4):
            tag = det.detect(cv2.cvtColor(fr.image, cv2.COLOR_BGR2GRAY))[0]
            T = fr.camera_from_brick
            true = cam.project(lay.code_corners_m()[0] @ T[:3, :3].T + T[:3, 3])
            got = np.asarray(tag.corners)[[1, 0, 3, 2]] - APRILTAG_PIXEL_OFFSET
            offs.append(got - true)
    offs = np.concatenate(offs)
    # the corner order is OpenCV's and the half pixel is taken off: what stays is AprilTag's
    # own corner error, well under a pixel and without a half-pixel bias
    assert np.abs(offs).max() < 0.6 and np.abs(offs.mean(axis=0)).max() < 0.15, offs.mean(0)


def test_recorded_example_and_image_folders_line_up(tmp_path):
    proto_path = write_recorded_example(tmp_path, frames=3)
    proto = load_protocol(proto_path)
    assert sum(s.source is not None for s in proto.steps) == len(proto.steps)
    res = run_study(proto, tmp_path, methods=["drovisio-codes", "drovisio-dots"],
                    memory_seconds=0, speed_bricks=())
    assert res.skipped == []
    names = {(r["step"], r["frame"]) for r in res.records}
    assert ("2", "frame_000.jpg") not in names and (2, "frame_000.jpg") in names
    assert (0, "code_60cm.mp4#2") in names
    for r in res.records:
        assert r["recorded"] and r["found"], r
        # the truth of a recorded step is its set-up: renders written as video agree with it
        # (a single code square-on, no gravity: its depth to a few percent)
        assert r["errors"]["xy_cm"] < 1.0 and r["errors"]["z_pct"] < 5.0, r
    for step in range(len(proto.steps)):
        z = [r["errors"]["z_pct"] for r in res.records if r["step"] == step]
        assert np.median(z) < 4.0, (step, z)        # MPEG-4 compressed: a few percent
    T = truth_camera_from_brick(proto.steps[0])
    assert T[2, 3] == pytest.approx(0.6)


def test_bad_input_is_named_and_the_study_goes_on(tmp_path):
    write_recorded_example(tmp_path, frames=2)
    data = yaml.safe_load((tmp_path / "protocol.yaml").read_text())
    data["steps"].append({**data["steps"][3], "frames": 2})
    data["steps"][-1].pop("value")                      # a recording without its truth
    data["steps"][0]["source"] = "missing.mp4"
    data["steps"][1]["frames"] = 5                      # the video has 2
    data["steps"][2]["frames"] = 4                      # the folder has 2 images
    data["layouts"].append({"name": "code-at", "layout": "drick-aruco-centre"})
    data["steps"].append({**data["steps"][3], "layout": "code-at", "figure": "6.7",
                          "source": "code_120cm.mp4", "frames": 2})
    res = run_study(load_protocol(_write(tmp_path / "bad.yaml", data)), tmp_path,
                    methods=["drovisio-codes", "apriltag3"], memory_seconds=0,
                    speed_bricks=())
    assert len(res.skipped) == 4
    assert "missing.mp4: source: no such file or folder (step distance 0.6 m)" \
        in res.skipped[0]
    assert "dots_100cm.mp4: value: no truth for this recording" in res.skipped[3]
    assert "code_120cm.mp4: the video has 2 frame(s), the step asks for frames: 5" \
        in res.skipped[1]
    assert "code_rotz45: 2 image(s), the step asks for frames: 4" in res.skipped[2]
    assert any(r["layout"] == "code-at" and r["found"] for r in res.records)
    # AprilTag 3 reads the 4x4 codes too (given to it as a family built from OpenCV's table)
    if "apriltag3" not in res.left_out:
        assert "apriltag3" not in res.not_applicable.get("code-at", {})
        assert any(r["layout"] == "code-at" and r["method"] == "apriltag3" and r["found"]
                   for r in res.records)


def test_a_recording_unlike_the_camera_or_not_a_recording_skips_its_step_in_one_line(
        tmp_path, capsys):
    write_recorded_example(tmp_path, frames=2)
    data = yaml.safe_load((tmp_path / "protocol.yaml").read_text())
    small = tmp_path / "small"                 # pictures at half the camera's size
    small.mkdir()
    for f in sorted((tmp_path / "code_rotz45").glob("*.jpg")):
        img = cv2.imread(str(f))
        cv2.imwrite(str(small / f.name), cv2.resize(img, (320, 240)))
    (tmp_path / "notes.txt").write_text("root:x:0:0\n")
    data["steps"][0]["source"] = "small"
    data["steps"][1]["source"] = str(tmp_path / "notes.txt")
    data["steps"] = data["steps"][:2]
    proto = _write(tmp_path / "p.yaml", data)
    rc = cli.main(["study", "run", "--protocol", str(proto), "--out", str(tmp_path / "out"),
                   "--methods", "drovisio-codes", "--memory-seconds", "0", "--quick"])
    err = capsys.readouterr().err
    assert rc == 0 and "internal error" not in err
    skipped = [ln for ln in err.splitlines() if ln.startswith("skipped:")]
    assert skipped == [
        f"skipped: step 1 (Fig. 6.7, code, distance 0.6 m): {small / 'frame_000.jpg'}: the "
        "frame is 320x240 but the study's camera is for 640x480; record at that size, or give "
        "the protocol the recording camera's file (camera:)",
        f"skipped: step 2 (Fig. 6.7, code, distance 1.2 m): {tmp_path / 'notes.txt'}: source: "
        "not a video (.avi, .h264, .m4v, .mjpeg, .mjpg, .mkv, .mov, .mp4, .mpeg, .mpg, .ts, "
        ".webm, .wmv) nor a folder of images; give the recording of step distance 1.2 m"]


@pytest.mark.parametrize("edit, field", [
    (lambda d: d["steps"][0].pop("value"), "steps.0: Value error, value: a rendered step"),
    (lambda d: d["steps"][0].update(figure="6.12"), "steps.0.figure"),
    (lambda d: d["steps"][0].update(layout="nope"), "steps.0.layout"),
    (lambda d: d["steps"][0].update(frames=0), "steps.0.frames"),
    (lambda d: d["steps"][0].update(vary="tilt"), "steps.0.vary"),
    (lambda d: d.update(extra=1), "extra"),
])
def test_protocol_errors_name_the_file_and_the_field(tmp_path, edit, field):
    data = _small_protocol()
    edit(data)
    p = _write(tmp_path / "p.yaml", data)
    with pytest.raises(ProtocolError) as e:
        load_protocol(p)
    assert str(p) in str(e.value) and field in str(e.value)
    (tmp_path / "nan.json").write_text('{"schema": "drovisio/study-protocol@1", "name": "x", '
                                       '"layouts": [{"name": "a", "layout": "b"}], "steps": '
                                       '[{"figure": "6.3", "layout": "a", "vary": "distance",'
                                       ' "value": NaN}]}')
    with pytest.raises(ProtocolError, match="nan.json: NaN is not a number"):
        load_protocol(tmp_path / "nan.json")


def test_without_apriltag_the_study_says_what_was_left_out(tmp_path, no_apriltag):
    proto = load_protocol(_write(tmp_path / "p.yaml", {
        "schema": PROTOCOL_SCHEMA, "name": "x",
        "layouts": [{"name": "c", "layout": "drick-aruco-centre",
                     "dictionary": "DICT_APRILTAG_36h11"}],
        "steps": [{"figure": "6.7", "layout": "c", "vary": "distance", "value": 0.5,
                   "frames": 1}]}))
    res = run_study(proto, tmp_path, memory_seconds=0, speed_bricks=())
    assert "pip install drovisio[peers]" in res.left_out["apriltag3"]
    assert {r["method"] for r in res.records} == {"drovisio-codes", "drovisio-codes-image",
                                                  "opencv"}


def test_a_cancelled_study_stops_at_its_next_frame_and_gives_no_result(tmp_path,
                                                                       monkeypatch):
    proto = load_protocol(_write(tmp_path / "p.yaml", _small_protocol(frames=2)))
    cancel = threading.Event()
    steps: list[str] = []
    real = study_run.step_frames

    def first_step_cancels(step, *args, **kwargs):
        steps.append(step.label)
        cancel.set()          # as the web tool does when it stops, from another thread
        return real(step, *args, **kwargs)

    monkeypatch.setattr(study_run, "step_frames", first_step_cancels)
    with pytest.raises(StudyCancelled):
        run_study(proto, tmp_path, methods=["drovisio-codes"], memory_seconds=1.0,
                  speed_bricks=(1,), speed_frames=1, landing_runs=1, cancel=cancel)
    assert len(steps) == 1 < len(proto.steps)


def test_cli_refuses_a_bad_protocol_in_one_line(tmp_path, capsys):
    bad = _write(tmp_path / "bad.yaml", {"schema": PROTOCOL_SCHEMA, "name": "x",
                                         "layouts": [], "steps": []})
    assert cli.main(["study", "run", "--protocol", str(bad), "--out",
                     str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.yaml: layouts" in err[0]


def test_cli_writes_into_a_folder_and_refuses_what_is_not_one(tmp_path, capsys):
    (tmp_path / "a-file").write_text("keep me")
    for out in (tmp_path / "a-file", tmp_path / "a-file" / "below"):
        assert cli.main(["study", "example", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--out" in err[0] and "Traceback" not in err[0]
    assert (tmp_path / "a-file").read_text() == "keep me"
    folder = tmp_path / "existing"
    folder.mkdir()
    assert cli.main(["study", "example", "--out", str(folder), "--frames", "1"]) == 0
    assert (folder / "protocol.yaml").is_file()


def test_the_report_shows_landing_errors_per_mount(small_study):
    res, data, report = small_study
    rows = {(x["layout"], x["tilt_deg"]): x for x in data["landing"]}
    assert {t for _, t in rows} == {0.0, 20.0}
    for x in rows.values():
        assert x["runs"] == 3 and 0.0 <= x["median_error_m"] <= x["p90_error_m"]
        assert 0 < x["rate_hz"] <= 30.0
    code = [k for k in rows if k[0] == "code"]
    assert code, rows.keys()
    # looking straight down keeps the brick longer than the 20° mount
    assert rows[("code", 0.0)]["blind_height_m"] < rows[("code", 20.0)]["blind_height_m"]
    html = (report / "report.html").read_text()
    assert "Precision landing (ArduPilot model)" in html and "blind height" in html


def test_cli_refuses_an_out_folder_that_is_a_recorded_steps_folder(tmp_path, capsys):
    """The step folders come from the protocol: the report's figures written among a step's
    pictures would be read as frames by the next run."""
    steps = tmp_path / "views"
    steps.mkdir()
    cv2.imwrite(str(steps / "frame_000.jpg"), np.zeros((48, 64, 3), np.uint8))
    proto = _write(tmp_path / "p.yaml", {
        "schema": PROTOCOL_SCHEMA, "name": "x",
        "layouts": [{"name": "c", "layout": "drick-aruco-centre"}],
        "steps": [{"figure": "6.9", "layout": "c", "vary": "rot_z", "value": 45,
                   "frames": 1, "source": "views"}]})
    before = sorted(p.name for p in steps.iterdir())
    assert cli.main(["study", "run", "--protocol", str(proto), "--out", str(steps),
                     "--quick"]) == 2
    err = capsys.readouterr().err
    assert err == (f"drovisio study: {steps}: --out would land among what the command reads "
                   f"from step 1's source views ({proto}); choose another folder\n")
    assert sorted(p.name for p in steps.iterdir()) == before
