"""`drovisio calibrate`: the DESIGN.md contract, progress, and every kind of bad input."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from drovisio import cli
from drovisio.camera_file import load_camera

BOARD = ["--board", "chessboard:9x6", "--square", "0.03"]


@pytest.fixture(scope="module")
def render_dir(rendered, tmp_path_factory):
    d = tmp_path_factory.mktemp("rendered")
    for v in rendered[:10]:
        cv2.imwrite(str(d / v.name), v.image)
    return d


def _run(capsys, *argv):
    rc = cli.main(["calibrate", *argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err and out == ""
    return rc, err


def test_opencv_samples_end_to_end(opencv_files, tmp_path, capsys):
    out, rep = tmp_path / "cam.yaml", tmp_path / "report.json"
    rc, err = _run(capsys, "--board", "chessboard:9x6", "--square", "0.025", "--report",
                   str(rep), "--out", str(out), str(opencv_files[0].parent))
    assert rc == 0
    for f in opencv_files:  # progress per image
        assert f"{f.name}: 54 corners" in err
    cam = load_camera(out)
    ros = load_camera(tmp_path / "cam.ros.yaml")
    assert cam.size == (640, 480) and np.allclose(cam.K, ros.K, rtol=1e-12)
    assert abs(cam.fx / 532.8 - 1) < 3e-3
    r = json.loads(rep.read_text())
    assert 0.1 < r["rms_px"] < 0.25 and "root mean square" in r["rms_definition"]
    assert len(r["per_view"]) == 13 and r["rejected"] == []
    assert set(r["uncertainty_px"]) >= {"p50", "p95", "max"}
    assert r["cross_validation_px"]["p95"] is not None
    assert r["verdict"]["ok"] is False and r["suggestion"]["sentence"]
    assert "verdict: NOT OK" in err and "top-left" in err


def test_rendered_folder_and_corrupt_jpeg_among_good_ones(render_dir, tmp_path, capsys):
    d = tmp_path / "imgs"
    shutil.copytree(render_dir, d)
    good = cv2.imencode(".jpg", cv2.imread(str(d / "view00.png")))[1].tobytes()
    (d / "broken.jpg").write_bytes(good[: len(good) // 2])
    (d / "notes.txt").write_text("not an image")  # not an image suffix: ignored
    (d / "fake.png").write_bytes(b"\x89PNG garbage")
    out, rep = tmp_path / "c.yaml", tmp_path / "r.json"
    rc, err = _run(capsys, *BOARD, "--report", str(rep), "--out", str(out), str(d))
    assert rc == 0 and out.exists() and (tmp_path / "c.ros.yaml").exists()
    r = json.loads(rep.read_text())
    rejected = {x["file"].split("/")[-1]: x["reason"] for x in r["rejected"]}
    assert "cut short" in rejected["broken.jpg"] and "cannot be read" in rejected["fake.png"]
    assert len(r["per_view"]) == 10


def test_mixed_image_sizes(render_dir, tmp_path, capsys):
    d = tmp_path / "mixed"
    shutil.copytree(render_dir, d)
    for name in ("view08.png", "view09.png"):
        img = cv2.imread(str(d / name))
        cv2.imwrite(str(d / name.replace(".png", "_hd.png")), cv2.resize(img, (960, 720)))
    rep = tmp_path / "r.json"
    rc, err = _run(capsys, *BOARD, "--report", str(rep), "--out", str(tmp_path / "c.yaml"),
                   str(d))
    assert rc == 0 and "mixed image sizes" in err and "960x720" in err
    r = json.loads(rep.read_text())
    assert sum("differs from the 640x480" in x["reason"] for x in r["rejected"]) == 2


def test_folder_with_no_board(tmp_path, capsys):
    d = tmp_path / "noboard"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):  # textured scenes without a board
        noise = rng.integers(0, 255, (480, 640)).astype(np.uint8)
        cv2.imwrite(str(d / f"n{i}.png"), cv2.GaussianBlur(noise, (0, 0), 3))
    out = tmp_path / "c.yaml"
    rc, err = _run(capsys, *BOARD, "--out", str(out), str(d))
    assert rc == 1 and not out.exists()
    assert "no chessboard:9x6 board found in any of the 3 image(s)" in err
    assert "INNER corners" in err


def test_wrong_board_size_suggests_the_right_one(render_dir, tmp_path, capsys):
    rep = tmp_path / "r.json"
    imgs = [str(render_dir / f"view0{i}.png") for i in range(4)]
    rc, err = _run(capsys, "--board", "chessboard:10x7", "--square", "0.03", "--report",
                   str(rep), "--out", str(tmp_path / "c.yaml"), *imgs)
    assert rc == 1 and "did you mean --board chessboard:9x6" in err
    r = json.loads(rep.read_text())  # the report still says what happened
    assert r["verdict"]["ok"] is False and len(r["rejected"]) == 4


def test_too_few_views(render_dir, tmp_path, capsys):
    rc, err = _run(capsys, *BOARD, "--out", str(tmp_path / "c.yaml"),
                   str(render_dir / "view00.png"), str(render_dir / "view01.png"))
    assert rc == 1 and "only 2 usable view(s)" in err


@pytest.mark.parametrize("setup,needle", [
    ("empty", "folder contains no images"),
    ("missing", "no such file or folder"),
    ("loop", "a loop of symbolic links (they lead to each other, never to a file or folder); "
             "give the real path"),
    ("dangling", "a symbolic link to nothing (its target does not exist); give the real path"),
])
def test_empty_folder_and_missing_path(tmp_path, capsys, setup, needle):
    p = tmp_path / setup
    if setup == "empty":
        p.mkdir()
    elif setup == "loop":
        p.symlink_to(tmp_path / "loop2")
        (tmp_path / "loop2").symlink_to(p)
    elif setup == "dangling":
        p.symlink_to(tmp_path / "nowhere")
    rc, err = _run(capsys, *BOARD, "--out", str(tmp_path / "c.yaml"), str(p))
    assert rc == 2 and needle in err and err.count("\n") == 1


def test_bad_board_spec_and_output(render_dir, tmp_path, capsys):
    rc, err = _run(capsys, "--board", "chessboard:9by6", "--square", "0.03", "--out",
                   str(tmp_path / "c.yaml"), str(render_dir))
    assert rc == 2 and "COLSxROWS" in err
    rc, err = _run(capsys, *BOARD, "--out", str(tmp_path), str(render_dir))
    assert rc == 2 and "is a folder" in err


def test_a_model_its_views_do_not_determine_is_refused_not_written(opencv_files, tmp_path,
                                                                   capsys):
    # the tilted sensor's 14 coefficients from 4 real views: each intrinsic within 10 % but
    # the projection uncertain by tens of pixels everywhere (it was written, marked NOT OK)
    four = [str(f) for f in opencv_files[:4]]
    out = tmp_path / "cam.yaml"
    rc, err = _run(capsys, "--board", "chessboard:9x6", "--square", "0.025", "--model",
                   "tilted", "--out", str(out), *four)
    said = [ln for ln in err.splitlines() if ln.startswith("drovisio calibrate:")]
    assert rc == 1 and len(said) == 1 and not out.exists()
    assert said[0].startswith("drovisio calibrate: calibration failed: the tilted solve is not "
                              "determined by these views: its projection is uncertain by ")
    assert said[0].endswith("px (1-sigma) at the median point of the image, more than 1 % of "
                            "the focal length; add views with the board tilted toward each "
                            "side and at other distances, or use a model with fewer "
                            "coefficients")
    # the same views determine plumb_bob's fewer coefficients: written
    rc, err = _run(capsys, "--board", "chessboard:9x6", "--square", "0.025", "--out",
                   str(out), *four)
    assert rc == 0 and out.exists()
    # the thin prism's: once its s1-s4 are held at 0 (the retry), said with the names once
    rc, err = _run(capsys, "--board", "chessboard:9x6", "--square", "0.025", "--model",
                   "thin_prism", "--out", str(tmp_path / "prism.yaml"), *four)
    assert rc == 0 and "(note) s1, s2, s3, s4 held at 0: with them free the solve is not " \
        "determined by these views: its projection is uncertain by" in err


def test_model_auto_on_the_real_views_says_why(opencv_files, tmp_path, capsys):
    out, rep = tmp_path / "cam.yaml", tmp_path / "report.json"
    rc, err = _run(capsys, "--board", "chessboard:9x6", "--square", "0.025", "--model", "auto",
                   "--report", str(rep), "--out", str(out), str(opencv_files[0].parent))
    assert rc == 0
    assert "lens model: kept plumb_bob: held-out RMS plumb_bob 0." in err
    r = json.loads(rep.read_text())
    assert r["camera"]["model"] == "plumb_bob" and r["model_choice"]["chosen"] == "plumb_bob"
    assert load_camera(out).model == "plumb_bob"


def test_model_fisheye_writes_a_fisheye_camera_file(tmp_path, capsys):
    from drovisio.calibration.synthetic import render_calibration_views
    from drovisio.camera import Camera

    truth = Camera.from_fov(960, 720, 140.0, dist=[0.02, -0.01, 0.003, -0.0005],
                            model="fisheye")
    for v in render_calibration_views(truth, 10, seed=4, ss=2):
        cv2.imwrite(str(tmp_path / v.name), v.image)
    out = tmp_path / "out" / "fish.yaml"
    out.parent.mkdir()
    rc, err = _run(capsys, "--board", "chessboard:9x6", "--square", "0.03", "--model",
                   "fisheye", "--out", str(out), str(tmp_path))
    assert rc == 0, err
    for f in (out, out.parent / "fish.ros.yaml"):
        cam = load_camera(f)
        assert cam.model == "fisheye" and abs(cam.fx / truth.fx - 1) < 0.003
