"""``drovisio detect``: the DESIGN.md contract and bad input, through ``drovisio.cli.main``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.camera_file import save_camera
from drovisio.cli import main
from drovisio.layout import shipped_layouts_dir
from drovisio.scenes import gravity_in_camera
from drovisio.synth import (
    BrickInstance,
    Ground,
    Scene,
    camera_over,
    render,
    rot_z,
    transform,
)

CENTRE = str(shipped_layouts_dir() / "drick-aruco-centre.json")
PYRAMIDS = str(shipped_layouts_dir() / "drick-aruco-pyramids.json")


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    """A camera file and one rendered frame with two bricks (centre #4, pyramids #1)."""
    from drovisio.layout import load_layouts

    d = tmp_path_factory.mktemp("detect")
    cam = Camera.drone_webcam()
    save_camera(cam, d / "camera.yaml")
    centre, pyr = load_layouts([CENTRE, PYRAMIDS])
    scene = Scene(camera=cam, camera_from_world=camera_over([0, 0, 0], 1.1, 20, 10),
                  ground=Ground("gravel", 3),
                  bricks=[BrickInstance(centre, transform(rot_z(0.5), [-0.12, 0.05, 0.1]), 4),
                          BrickInstance(pyr, transform(rot_z(-0.3), [0.15, -0.08, 0.1]), 1)])
    r = render(scene, ss=3)
    cv2.imwrite(str(d / "frame.png"), r.image)
    return {"dir": d, "image": r.image, "truth": r.bricks,
            "gravity": gravity_in_camera(r.camera_from_world)}


def _run(capsys, *argv):
    rc = main(["detect", *map(str, argv)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    lines = [json.loads(x) for x in out.splitlines() if x.strip()]
    return rc, lines, err


def _base(files):
    return ["--camera", files["dir"] / "camera.yaml", "--layout", CENTRE, "--layout", PYRAMIDS]


def test_folder_of_images_gives_one_line_per_frame_in_name_order(scene_files, tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(scene_files["dir"] / "frame.png", frames / "0001.png")
    cv2.imwrite(str(frames / "0000.png"), np.full((480, 640, 3), 128, np.uint8))
    rc, lines, err = _run(capsys, *_base(scene_files), frames)
    assert rc == 0
    assert [(x["file"], x["frame"]) for x in lines] == [(str(frames / "0000.png"), 0),
                                                       (str(frames / "0001.png"), 1)]
    assert lines[0]["bricks"] == []
    bricks = lines[1]["bricks"]
    assert [(b["layout"], b["instance"], b["markers"]) for b in bricks] == [
        ("drick-aruco-centre", 4, [4]), ("drick-aruco-pyramids", 1, [22, 23])]
    truth = {(t.layout, t.instance): t for t in scene_files["truth"]}
    for b in bricks:
        assert set(b) >= {"layout", "instance", "method", "rvec", "tvec",
                          "reprojection_rmse_px", "markers"}
        assert b["method"] == "aruco"
        t = truth[(b["layout"], b["instance"])]
        assert np.linalg.norm(np.array(b["tvec"]) - t.tvec) < 0.01
    assert "2 frames, 2 bricks" in err  # the summary goes to stderr


def test_out_file_and_gravity_file(scene_files, tmp_path, capsys):
    img = scene_files["dir"] / "frame.png"
    grav = tmp_path / "gravity.jsonl"
    grav.write_text(json.dumps({"file": str(img), "gravity": scene_files["gravity"].tolist()})
                    + "\n")
    out = tmp_path / "poses.jsonl"
    rc, lines, err = _run(capsys, *_base(scene_files), "--gravity-file", grav, "--out", out,
                          img)
    assert rc == 0 and lines == []  # nothing on stdout
    rec = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(rec) == 1 and len(rec[0]["bricks"]) == 2
    assert all("ambiguous" not in b for b in rec[0]["bricks"])
    assert "gravity for 1" in err


def test_bad_gravity_file_is_named(scene_files, tmp_path, capsys):
    grav = tmp_path / "g.jsonl"
    grav.write_text('{"file": "a.png", "gravity": [0, 0, 1]}\n{"file": "b.png", "gravity": 3}\n')
    rc, lines, err = _run(capsys, *_base(scene_files), "--gravity-file", grav,
                          scene_files["dir"] / "frame.png")
    assert rc == 2 and lines == []
    assert f"{grav}, line 2" in err and "gravity" in err


@pytest.mark.parametrize("text, says", [
    ('{"file": "a.png", "gravity": [0, 1, 0]}\n{"file": "./a.png", "gravity": [0, -1, 0]}\n',
     "line 2: file: './a.png' is given again (first at line 1); give each frame's gravity "
     "once"),
    ('{"file": "v.mp4", "frame": 3, "gravity": [0, 1, 0]}\n'
     '{"file": "v.mp4", "frame": 3, "gravity": [0, 1, 0]}\n',
     "line 2: file: 'v.mp4' frame 3 is given again (first at line 1); give each frame's "
     "gravity once"),
    ('{"file": "a.png", "gravity": [1e308, 1e308, 0]}\n',
     "line 1: gravity: [1e+308, 1e+308, 0] is not a unit vector (each number from -1.05 to "
     "1.05); give the direction of gravity, pointing down, camera frame"),
    ('{"file": "v.mp4", "frame": ' + "9" * 4200 + ', "gravity": [0, 1, 0]}\n',
     "line 1: a number of 4200 digits; give at most 30"),
    ('{"file": "a.png", "gravity": [0, 1, 0], "x": ' + "[" * 200 + "]" * 200 + '}\n',
     "line 1: nested more than 32 levels deep; this is not a file Drovisio writes or reads"),
])
def test_gravity_file_refusals_are_one_line(scene_files, tmp_path, capsys, text, says):
    grav = tmp_path / "g.jsonl"
    grav.write_text(text)
    rc, lines, err = _run(capsys, *_base(scene_files), "--gravity-file", grav,
                          scene_files["dir"] / "frame.png")
    assert rc == 2 and lines == []
    assert err == f"drovisio detect: {grav}, {says}\n"


def test_gravity_file_is_read_without_numeric_warnings_and_within_its_bounds(tmp_path,
                                                                            monkeypatch):
    import warnings

    from drovisio.commands.detect import GravityTable
    from drovisio.errors import InputError

    grav = tmp_path / "g.jsonl"
    grav.write_text('{"file": "a.png", "gravity": [1e308, 1e308, 0]}\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # numpy's overflow warning would fail here
        with pytest.raises(InputError, match="is not a unit vector"):
            GravityTable.load(str(grav))
    monkeypatch.setattr(GravityTable, "MAX_LINES", 3)
    grav.write_text("\n" * 4)   # blank lines count: the file is refused before it is parsed
    with pytest.raises(InputError) as e:
        GravityTable.load(str(grav))
    assert str(e.value) == f"{grav}: more than 3 lines; split the run"
    monkeypatch.setattr(GravityTable, "MAX_LINE_BYTES", 1024)
    grav.write_text(json.dumps({"file": "a.png", "gravity": [0, 1, 0], "x": "a" * 1024}))
    with pytest.raises(InputError) as e:
        GravityTable.load(str(grav))
    assert str(e.value) == (f'{grav}, line 1: longer than 1 KiB; a line is {{"file", "frame", '
                            '"gravity"}: is it the right file?')


def test_gravity_table_matches_by_name_path_and_unique_base_name(tmp_path):
    from drovisio.commands.detect import GravityTable

    grav = tmp_path / "g.jsonl"
    grav.write_text("\n".join(json.dumps(x) for x in [
        {"file": "d1/a.png", "gravity": [0, 2 ** -0.5, 2 ** -0.5]},
        {"file": "d2/a.png", "gravity": [0, 1, 0]},
        {"file": "d1/b.png", "gravity": [0, 0, 1.02]},
        {"file": "v.mp4", "frame": 0, "gravity": [1, 0, 0]},
        {"file": "v.mp4", "gravity": [-1, 0, 0]}]) + "\n")
    t = GravityTable.load(str(grav))
    assert np.allclose(np.linalg.norm(t.unit, axis=1), 1.0)
    assert t.lookup("d1/a.png", 0, False).tolist() == pytest.approx([0, 2 ** -0.5, 2 ** -0.5])
    assert t.lookup("./d2/a.png", 0, False).tolist() == [0, 1, 0]
    assert t.lookup("a.png", 0, False) is None            # two files of that name
    assert t.lookup("x/b.png", 0, False).tolist() == [0, 0, 1]   # the only b.png, made unit
    assert t.lookup("v.mp4", 0, True).tolist() == [1, 0, 0]
    assert t.lookup("v.mp4", 5, True).tolist() == [-1, 0, 0]


def test_unreadable_image_gives_an_error_line_and_the_run_goes_on(scene_files, tmp_path,
                                                                   capsys):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    rc, lines, err = _run(capsys, *_base(scene_files), bad, tmp_path / "missing.jpg",
                          scene_files["dir"] / "frame.png")
    assert rc == 1
    assert [x["file"] for x in lines] == [str(bad), str(tmp_path / "missing.jpg"),
                                          str(scene_files["dir"] / "frame.png")]
    assert "error" in lines[0] and lines[0]["bricks"] == []
    assert "error" in lines[1]
    assert "error" not in lines[2] and len(lines[2]["bricks"]) == 2
    assert "broken.png" in err and "cannot be read as an image" in err


def test_greyscale_and_16_bit_images(scene_files, tmp_path, capsys):
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), cv2.cvtColor(scene_files["image"], cv2.COLOR_BGR2GRAY))
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), scene_files["image"].astype(np.uint16) * 257)
    rc, lines, err = _run(capsys, *_base(scene_files), grey, deep)
    assert rc == 0
    assert [len(x["bricks"]) for x in lines] == [2, 2]
    assert "greyscale" in err
    assert "16-bit" in err and "scaled to 8 bits" in err


def test_empty_folder(scene_files, tmp_path, capsys):
    empty = tmp_path / "nothing"
    empty.mkdir()
    rc, lines, err = _run(capsys, *_base(scene_files), empty)
    assert rc == 1 and lines == []
    assert "nothing" in err and "no images" in err


def test_missing_or_malformed_camera_file(scene_files, tmp_path, capsys):
    img = scene_files["dir"] / "frame.png"
    rc, lines, err = _run(capsys, "--camera", tmp_path / "nope.yaml", "--layout", CENTRE, img)
    assert rc == 2 and lines == []
    assert "nope.yaml" in err and "not found" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n"
                   "   dt: d\n   data: [ 1., 0., 2. ]\n")
    rc, lines, err = _run(capsys, "--camera", bad, "--layout", CENTRE, img)
    assert rc == 2 and lines == []
    assert "bad.yaml" in err


def test_overlapping_id_blocks_name_both_layouts(scene_files, tmp_path, capsys):
    data = json.loads(Path(CENTRE).read_text())
    data["name"] = "my-brick"
    clash = tmp_path / "my-brick.json"
    clash.write_text(json.dumps(data))
    rc, lines, err = _run(capsys, "--camera", scene_files["dir"] / "camera.yaml",
                          "--layout", CENTRE, "--layout", clash, scene_files["dir"] / "frame.png")
    assert rc == 2 and lines == []
    assert "drick-aruco-centre" in err and "my-brick" in err and "share ids" in err


def test_wrong_image_size_is_an_error_line(scene_files, tmp_path, capsys):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), scene_files["image"][:240, :320])
    rc, lines, _ = _run(capsys, *_base(scene_files), small)
    assert rc == 1 and "320x240" in lines[0]["error"]


def test_video_frames(scene_files, tmp_path, capsys):
    video = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG AVI")
    for _ in range(2):
        vw.write(scene_files["image"])
    vw.release()
    grav = tmp_path / "g.jsonl"
    g = scene_files["gravity"].tolist()
    grav.write_text("".join(json.dumps({"file": str(video), "frame": k, "gravity": g}) + "\n"
                            for k in (0, 1)))
    rc, lines, err = _run(capsys, *_base(scene_files), "--gravity-file", grav, video)
    assert rc == 0
    assert [(x["file"], x["frame"]) for x in lines] == [(str(video), 0), (str(video), 1)]
    assert all(len(x["bricks"]) == 2 for x in lines)
    assert "gravity for 2" in err


def test_dots_method_on_code_only_layouts(scene_files, capsys):
    rc, lines, err = _run(capsys, *_base(scene_files), "--method", "dots",
                          scene_files["dir"] / "frame.png")
    assert rc == 2 and lines == []
    assert "none of the layouts has colour dots" in err


def test_a_broken_entry_of_a_folder_is_named_not_passed_over(scene_files, tmp_path, capsys):
    """A link to nothing, a loop of links and a pipe, each named like an image: every one is
    a frame that says why it cannot be read (it used to be left out without a word, the run
    a success over fewer frames than the folder shows)."""
    import os

    from drovisio.sources.folders import ImageFolderReader

    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(scene_files["dir"] / "frame.png", frames / "a.png")
    (frames / "b.png").symlink_to(tmp_path / "gone.png")
    (frames / "c.png").symlink_to(frames / "c.png")
    os.mkfifo(frames / "d.png")
    (frames / "sub.png").mkdir()      # a folder is no picture: passed over
    rc, lines, err = _run(capsys, *_base(scene_files), frames)
    assert rc == 1
    assert [(Path(x["file"]).name, x.get("error", "")[:20]) for x in lines] == [
        ("a.png", ""), ("b.png", "a symbolic link to n"), ("c.png", "a loop of symbolic l"),
        ("d.png", "not a regular file ("),
    ]
    assert "4 frames" in err and "3 errors" in err and "Traceback" not in err
    src = ImageFolderReader(frames)       # a run's folder source reads the same entries
    src.open()
    assert [f.name for f in src.files] == ["a.png", "b.png", "c.png", "d.png"]
    got = [src.read() for _ in range(4)]
    assert got[0].error is None and got[0].image is not None
    assert [g.error[:20] for g in got[1:]] == ["a symbolic link to n", "a loop of symbolic l",
                                              "not a regular file ("]
