"""``drovisio bench real``: the kind of each real folder, the figures beside OpenCV and
AprilTag 3, its JSON through the verified writer, bad arguments in one line."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from drovisio.cli import main

REAL = Path(os.environ.get("DROVISIO_REAL_DATA", Path(__file__).resolve().parents[3]
                           / "shared" / "datasets" / "real"))


def _need(sub: str) -> Path:
    d = REAL / sub
    if not d.is_dir():
        msg = f"real data {d} is absent; set DROVISIO_REAL_DATA to run these tests"
        if os.environ.get("DROVISIO_REQUIRE_SHARED") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return d


def test_charuco_and_chessboard_folders(tmp_path, capsys):
    charuco, chess = _need("charuco"), _need("chess-opencv24")
    out = tmp_path / "real.json"
    rc = main(["bench", "real", str(charuco), str(chess), "--calibrate", "none",
               "--json", str(out)])
    text, err = capsys.readouterr()
    assert rc == 0 and "Traceback" not in err
    rep = json.loads(out.read_text())["folders"]
    assert [r["kind"] for r in rep] == ["charuco", "chessboard"]
    ch, cb = rep
    assert ch["board_squares"] == [5, 7] and ch["dictionary"] == "DICT_6X6_250"
    assert ch["codes"]["drovisio"] == ch["codes"]["opencv"] == 17
    assert ch["codes"]["ambiguous"] == 0
    assert ch["pose_vs_board"]["trans_mm"]["max"] < 2.0
    assert ch["pose_vs_board"]["rot_deg"]["max"] < 0.2
    assert (ch["corners_vs_board_px"]["drovisio"]["median"]
            < ch["corners_vs_board_px"]["opencv"]["median"])
    # the reference itself: the board pose reprojects its 24 ChArUco corners to 0.22 px RMS,
    # and a prediction that trusts neither the focal length nor the pose (the board plane's
    # homography) gives the code corners the same distances (0.36 px median against 0.36)
    assert ch["board_pose_rms_px"]["max"] < 0.3
    h, b = (ch["corners_vs_board_px"][k]["median"] for k in ("drovisio_vs_homography",
                                                             "drovisio"))
    assert abs(h - b) < 0.1
    # what is left is where the codes are: OpenCV's raw corners put each code, as a whole,
    # off the prediction by the same shift as Drovisio's (correlation 0.87 in x, 0.96 in y;
    # the two shifts 0.19 px apart, each 0.32 px from the prediction, median), and with each
    # code's own shift removed Drovisio's corners are 0.22 px from it (median)
    s = ch["code_shift_px"]
    assert s["drovisio"]["n"] == 17 and min(s["correlation_xy"]) > 0.7
    assert s["difference"]["median"] < 0.7 * s["drovisio"]["median"]
    assert ch["corners_vs_board_px"]["drovisio_shift_removed"]["median"] < 0.3
    # AprilTag 3, given the board's DICT_6X6_250 as a family, reads the 17 codes too: a third
    # reading, sharing no code with the other two, that assumes nothing of the board. It
    # puts each code off the prediction by the same shift as Drovisio (correlation 0.97 in
    # x, 0.98 in y; 0.10 px apart, median), and every Drovisio code is within 0.5 px RMS of
    # AprilTag's corners (0.33 median, 0.46 at most; OpenCV's 0.78)
    assert ch["codes"]["apriltag"] == 17 and "DICT_6X6_250 as its family" in ch["apriltag"]
    assert min(s["correlation_xy_apriltag"]) > 0.9
    assert s["difference_apriltag"]["median"] < 0.5 * s["drovisio"]["median"]
    a = ch["corners_rms_px"]
    assert a["drovisio_vs_apriltag"]["n"] == 17 and a["drovisio_vs_apriltag"]["max"] < 0.5
    assert a["opencv_vs_apriltag"]["median"] > 2 * a["drovisio_vs_apriltag"]["median"]
    assert ch["codes_within_half_px"] == {"codes": 17, "of_apriltag": 17, "of_board": 11,
                                          "of_either": 17}
    # OpenCV's 2.4-era chessboards with its expected corners: 7 of 7, within 0.05 px
    assert cb["board"] in ([7, 5], [5, 7]) and cb["found"] == {"drovisio": 7, "opencv": 7}
    c = cb["corners_vs_expected_px"]["drovisio"]
    assert c["n"] == 7 * 35 and c["median"] < 0.05
    assert "codes found: Drovisio 17, OpenCV 17, AprilTag 3 17" in text


def test_tag_folder_with_apriltag(tmp_path, capsys):
    d = _need("apriltag-multi")
    pytest.importorskip("pupil_apriltags")
    out = tmp_path / "tags.json"
    assert main(["bench", "real", str(d), "--json", str(out)]) == 0
    r = json.loads(out.read_text())["folders"][0]
    assert r["kind"] == "tags" and r["dictionary"] == "DICT_APRILTAG_36h11"
    n = r["codes"]
    assert n["opencv"] == 54 and n["apriltag"] == 56 and n["opencv_kept"] == 54
    assert n["drovisio"] == 56 and r["missed_opencv_codes"] == []
    assert n["false"] == 0 and n["duplicate_bricks"] == 0
    c = r["corners_rms_px"]
    assert c["drovisio_vs_apriltag"]["median"] < 0.5 * c["opencv_vs_apriltag"]["median"]
    assert set(r["ms_per_photo"]) == {"drovisio", "opencv", "apriltag"}
    # AprilTag's corners as a reference, against the outer edge lines (a reading neither
    # method makes): 0.12 px RMS per code (median, 48 codes), no offset left after the
    # half-pixel convention (-0.009, -0.006 px); Drovisio 0.14 px; where the two differ by
    # over 0.5 px (1 code with clean edges) the edges side with AprilTag
    e = r["edge_reference"]
    assert e["apriltag_vs_edges"]["n"] >= 40 and e["apriltag_vs_edges"]["median"] < 0.2
    assert max(abs(v) for v in e["apriltag_mean_offset_px"]) < 0.05
    assert e["drovisio_vs_edges"]["median"] < 0.3


def test_tag_folder_of_aruco_codes_with_apriltag(tmp_path):
    """OpenCV's ArUco and ChArUco tutorial photos (in the repository, with their source):
    AprilTag 3 reads their DICT_6X6_250 codes given to it as a family, and every code OpenCV
    reads (19, one board partly under a hand) is kept, within 0.5 px RMS of AprilTag 3's
    corners (measured 0.20 median, 0.44 at most; OpenCV's own 0.72 / 1.02), no false code."""
    pytest.importorskip("pupil_apriltags")
    d = Path(__file__).resolve().parents[1] / "data" / "real" / "opencv-tutorial"
    out = tmp_path / "tags.json"
    assert main(["bench", "real", str(d), "--json", str(out)]) == 0
    r = json.loads(out.read_text())["folders"][0]
    assert r["kind"] == "tags" and r["dictionary"] == "DICT_6X6_250"
    n = r["codes"]
    assert n["opencv"] == n["apriltag"] == n["opencv_kept"] == n["drovisio"] == 19
    assert r["missed_opencv_codes"] == [] and n["false"] == 0
    c = r["corners_rms_px"]
    assert c["drovisio_vs_apriltag"]["n"] == 19 and c["drovisio_vs_apriltag"]["max"] < 0.5
    assert c["opencv_vs_apriltag"]["median"] > 2 * c["drovisio_vs_apriltag"]["median"]


@pytest.mark.parametrize("argv, words", [
    (["--repeat", "0"], "--repeat 0: give 1 to 20"),
    (["--calibrate", "brown"], "'brown' is no model"),
    (["--marker", "0.05"], "smaller than the square"),
    (["--tag-size", "1e9"], "--tag-size: 1e+09 is out of range: give a number from 0.001 to 10 m"),
])
def test_bad_arguments_are_one_line(tmp_path, capsys, argv, words):
    rc = main(["bench", "real", str(tmp_path), *argv])
    _, err = capsys.readouterr()
    assert rc == 2 and words in err and "Traceback" not in err
    assert len([x for x in err.splitlines() if x.strip()]) == 1


def test_folders_that_are_none_of_the_kinds(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("no photos here")
    rc = main(["bench", "real", str(tmp_path)])
    _, err = capsys.readouterr()
    assert rc == 2 and "no images" in err and str(tmp_path) in err
    rc = main(["bench", "real", str(tmp_path / "missing")])
    _, err = capsys.readouterr()
    assert rc == 2 and "missing: no such file or folder; give folders of real photos" in err


def _png_header(w: int, h: int) -> bytes:
    """A PNG that is only its header (IHDR then IEND): what a decoder sizes its buffer by."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(
            ">I", zlib.crc32(kind + body))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IEND", b""))


def test_a_picture_whose_header_is_over_the_cap_is_refused_from_its_header(tmp_path, capsys):
    (tmp_path / "huge.png").write_bytes(_png_header(20000, 20000))
    rc = main(["bench", "real", str(tmp_path)])
    _, err = capsys.readouterr()
    assert rc == 2 and err == (
        f"drovisio bench: {tmp_path / 'huge.png'}: the image is 400 Mpx, more than the 50 Mpx "
        "Drovisio decodes; resize it (or set DROVISIO_MAX_IMAGE_MPX); or remove it from the "
        "folder\n")


def test_outer_edge_corners_find_a_blurred_squares_corners():
    """The edge reference on a square drawn at 8× and averaged down (pixel centres at
    integers), blurred like a lens (σ 0.8 px): its corners within 0.1 px, clean lines; a
    start 1.5 px off does not move them."""
    import cv2
    import numpy as np

    from drovisio.detect.corners.edges import EDGE_LINE_MAX_RMS_PX, outer_edge_corners

    S = 8
    truth = np.array([[40.3, 52.7], [131.6, 45.2], [140.1, 138.9], [47.8, 127.4]])
    # fine pixel centres in coarse pixels, inside the convex quad (every side's left turn)
    f = (np.arange(200 * S) + 0.5) / S - 0.5
    x, y = np.meshgrid(f, f)
    inside = np.ones_like(x, bool)
    for a, b in zip(truth, np.roll(truth, -1, axis=0)):
        inside &= (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]) > 0
    fine = np.where(inside, 35.0, 210.0)
    img = fine.reshape(200, S, 200, S).mean(axis=(1, 3)).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    start = truth + np.array([[1.5, -1.0], [-1.2, 1.5], [0.8, -1.5], [-1.5, 1.0]])
    got = outer_edge_corners(img, start)
    assert got is not None
    corners, line_rms = got.corners_px, got.worst_rms_px
    # measured: 0.08 px; the points scatter 0.13 px RMS about their lines (clean: < 0.3)
    assert np.abs(corners - truth).max() < 0.1 and line_rms < EDGE_LINE_MAX_RMS_PX


def test_plain_opencv_fisheye_solve_is_called_as_opencv_5_wants_it():
    """The peer's fisheye calibration gets its points in the shape OpenCV 5 reads (one row a
    view): on exact fisheye projections it recovers the focal length, so a failure the bench
    reports on real views is OpenCV's solve, not our call."""
    import cv2
    import numpy as np

    from drovisio.bench.real import _opencv_calibration

    K = np.array([[290.0, 0, 400.0], [0, 290.0, 252.0], [0, 0, 1]])
    D = np.array([-0.03, -0.02, 0.002, 0.001])
    grid = np.zeros((48, 3))
    grid[:, :2] = np.mgrid[0:8, 0:6].T.reshape(-1, 2) * 0.1
    grid -= grid.mean(axis=0)
    rng = np.random.default_rng(3)
    objs, imgs = [], []
    for _ in range(12):
        rv = rng.uniform(-0.5, 0.5, 3)
        tv = np.r_[rng.uniform(-0.4, 0.4, 2), rng.uniform(0.8, 1.4)]
        px, _ = cv2.fisheye.projectPoints(grid.reshape(-1, 1, 3), rv, tv, K, D)
        objs.append(grid.copy())
        imgs.append(px.reshape(-1, 1, 2))
    got = _opencv_calibration(objs, imgs, (800, 504), fisheye=True)
    assert "failed" not in got, got
    assert abs(got["fx"] - 290.0) < 0.5 and got["rms_px"] < 0.01


# --------------------------------------------------------------------------- hostile folders
TUTORIAL = Path(__file__).resolve().parents[1] / "data" / "real" / "opencv-tutorial"


def _run(capsys, *argv: object) -> tuple[int, str, str]:
    rc = main(["bench", "real", *map(str, argv)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return rc, out, err


def _chessboard(w: int = 640, h: int = 480, square: int = 40):
    """A drawn 8x6-square chessboard (7x5 inner corners), grey on white, in a w x h photo."""
    import numpy as np

    img = np.full((h, w), 230, np.uint8)
    x0, y0 = (w - 8 * square) // 2, (h - 6 * square) // 2
    for r in range(6):
        for c in range(8):
            if (r + c) % 2 == 0:
                img[y0 + r * square:y0 + (r + 1) * square,
                    x0 + c * square:x0 + (c + 1) * square] = 25
    return img


def _chess_folder(d: Path, sizes=((640, 480), (640, 480))) -> Path:
    import cv2

    d.mkdir()
    for i, (w, h) in enumerate(sizes):
        cv2.imwrite(str(d / f"chess{i}.png"), _chessboard(w, h, square=min(w, h) // 12))
    return d


def _charuco_folder(d: Path) -> Path:
    """OpenCV's tutorial board (5x7 squares, DICT_6X6_250) drawn into a 640x480 photo, with
    its tutorial camera file."""
    import cv2
    import numpy as np

    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02,
                                   cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    img = np.full((480, 640), 255, np.uint8)
    img[30:450, 170:470] = board.generateImage((300, 420))
    d.mkdir()
    cv2.imwrite(str(d / "board.png"), img)
    (d / "camera.yaml").write_text((TUTORIAL / "camera.yaml").read_text())
    return d


def _copy_tutorial(d: Path) -> Path:
    import shutil

    shutil.copytree(TUTORIAL, d)
    return d


def test_a_camera_file_for_another_image_size_is_one_line(tmp_path, capsys):
    d = _copy_tutorial(tmp_path / "tags")
    cam = d / "camera.yaml"
    cam.write_text(cam.read_text().replace("image_width: 640", "image_width: 1280")
                   .replace("image_height: 480", "image_height: 960"))
    rc, _, err = _run(capsys, d)
    assert rc == 2 and err.splitlines()[-1] == (
        f"drovisio bench: {cam}: image_width, image_height: 1280x960, but the photos are "
        "640x480; give the camera file of these photos (or photos of its size)")


def test_a_camera_file_without_a_size_far_from_the_photos_centre_is_said(tmp_path, capsys):
    d = _copy_tutorial(tmp_path / "tags")
    cam = d / "camera.yaml"
    cam.write_text(cam.read_text().replace("image_width: 640\n", "")
                   .replace("image_height: 480\n", "").replace("3.1770297317353277e+02",
                                                               "5.1770297317353277e+02"))
    rc, _, err = _run(capsys, d, "--repeat", "1")
    assert rc == 0
    assert (f"{cam}: the camera file gives no image size; using 640x480 from the images, but "
            "its principal point (518, 278) is far from their centre: is the file for another "
            "resolution?") in err.splitlines()


def test_a_second_camera_file_in_the_folder_is_said(tmp_path, capsys):
    """Which camera file the figures are against must not be a guess: the first in name
    order is used and the others are named (a file that holds no camera is no second one)."""
    import shutil

    d = _copy_tutorial(tmp_path / "tags")
    shutil.copy(d / "camera.yaml", d / "a_other.yml")
    (d / "params.yml").write_text("%YAML:1.0\n---\nadaptiveThreshWinSizeMin: 3\n")
    rc, _, err = _run(capsys, d, "--repeat", "1")
    assert rc == 0
    assert (f"{d}: camera files a_other.yml and camera.yaml; a_other.yml, the first in name "
            "order, is used; keep only the photos' own camera file in the folder"
            ) in err.splitlines()


@pytest.mark.parametrize("kind", ["chessboard", "charuco"])
def test_photos_of_mixed_sizes_are_refused_for_every_kind(tmp_path, capsys, kind):
    import cv2

    if kind == "chessboard":   # was measured all the same: plain OpenCV's solve mixed them
        d = _chess_folder(tmp_path / "set", ((640, 480), (800, 600)))
        odd, first, size = d / "chess1.png", "chess0.png", "800x600"
    else:                      # was an internal error of the detector
        d = _charuco_folder(tmp_path / "set")
        odd, first, size = d / "small.png", "board.png", "320x240"
        cv2.imwrite(str(odd), cv2.resize(cv2.imread(str(d / "board.png")), (320, 240)))
    rc, _, err = _run(capsys, d, "--calibrate", "none")
    assert rc == 2 and err.splitlines()[-1] == (
        f"drovisio bench: {odd}: {size}, but {first} is 640x480: the photos of one folder "
        "must be of one size (one camera file is for one size); move it to a folder of its own")


def test_json_over_an_input_of_a_folder_is_refused_before_any_work(tmp_path, capsys):
    d = _copy_tutorial(tmp_path / "tags")
    cam = d / "camera.yaml"
    before = cam.read_bytes()
    rc, out, err = _run(capsys, d, "--json", cam)
    assert rc == 2 and out == "" and err == (
        f"drovisio bench: {cam}: --json is the same file as camera.yaml of DIR {d}; writing it "
        "would destroy it: choose another name\n")
    assert cam.read_bytes() == before
    photo = d / "singlemarkersoriginal.jpg"
    rc, out, err = _run(capsys, d, "--json", photo)
    assert rc == 2 and err == (f"drovisio bench: {photo}: --json would land among what the "
                               f"command reads from DIR {d}; choose another folder\n")


def test_a_yaml_alias_bomb_as_the_camera_file_is_one_line(tmp_path, capsys):
    d = _copy_tutorial(tmp_path / "tags")
    cam = d / "camera.yaml"
    cam.write_text("a0: &a0 [0, 0, 0, 0, 0, 0, 0, 0, 0]\n" + "".join(
        f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n" for i in range(1, 6))
        + "camera_matrix: [*a5, 0, 320, 0, 500, 240, 0, 0, 1]\n"
        "distortion_coefficients: [0, 0, 0, 0, 0]\n")
    rc, _, err = _run(capsys, d)
    assert rc == 2 and err.splitlines()[-1] == (
        f"drovisio bench: {cam}: its YAML aliases expand to more than 100,000 values (an alias "
        "bomb?); write the values out instead; expected an OpenCV or ROS camera file; fix it "
        "or remove it from the folder")


def test_a_broken_reference_camera_file_is_not_passed_over(tmp_path, capsys):
    """A chessboard set's camera file that cannot be read was left out in silence, and the
    figures said "no camera file in the folder"; a file that is no camera file at all (a
    detector's parameters) is still passed over."""
    d = _chess_folder(tmp_path / "set")
    (d / "detector_params.yml").write_text("%YAML:1.0\nadaptiveThreshWinSizeMin: 3\n")
    cam = d / "reference.yaml"
    cam.write_text("camera_matrix: [[500, 0, 320], [0, 500, 240], [0, 0, 1]]\n"
                   "distortion_coefficients: [0, 0, 0]\n")
    rc, _, err = _run(capsys, d, "--calibrate", "none")
    assert rc == 2 and err.splitlines()[-1] == (
        f"drovisio bench: {cam}: distortion_coefficients: 3 coefficients; OpenCV's model has "
        "4, 5, 8, 12 or 14 (k1 k2 p1 p2 k3 ...); fix it or remove it from the folder")


@pytest.mark.parametrize("content, words", [
    # OpenCV's own parser raised inside (an internal error), or allocated what rows x cols
    # announced (80 GB here), or blocked on a pipe
    ("%YAML:1.0\ncorners: !!opencv-matrix\n  rows: 35\n  data: [ 1, 2, [[[",
     "not valid YAML at line 4, column 20: expected the node content, but found '<stream "
     "end>'; fix the file or remove it from the folder"),
    ("%YAML:1.0\ncorners: !!opencv-matrix\n  rows: 100000\n  cols: 100000\n  dt: \"2f\"\n"
     "  data: [ 1.5, .nan ]\n",
     "corners.data: nan is not a finite number; give a number from -1e+06 to 1e+06 px"),
    ("%YAML:1.0\ncorners: !!opencv-matrix\n  rows: 1\n  cols: 1\n  dt: \"2f\"\n  data: [ 1 ]\n",
     "corners: expected a list of x, y pixel pairs (at most 40000 corners); fix the file or "
     "remove it from the folder"),
])
def test_expected_corner_files_are_read_within_bounds(tmp_path, capsys, content, words):
    d = _chess_folder(tmp_path / "set")
    dat = d / "chess_corners0.dat"
    dat.write_text(content)
    rc, _, err = _run(capsys, d, "--calibrate", "none")
    assert rc == 2 and err.splitlines()[-1] == f"drovisio bench: {dat}: {words}"


@pytest.mark.parametrize("argv, line", [
    # OpenCV built the board it was given: 10^10 squares took every byte of the machine
    (["--board", "charuco:100000x100000"],
     "drovisio bench: board spec 'charuco:100000x100000:DICT_6X6_250': 100000x100000 inner "
     "corners is not a plausible board"),
    (["--board", "charuco:30x30"],
     "drovisio bench: board spec 'charuco:30x30:DICT_6X6_250': the board needs 480 markers "
     "but DICT_6X6_250 has 250"),
    (["--board", "charuco:0x0"],
     "drovisio bench: board spec 'charuco:0x0:DICT_6X6_250': needs at least 3x3 inner corners "
     "(got 0x0); expected KIND:COLSxROWS counting inner corners, e.g. chessboard:9x6 (a "
     "board of 10x7 squares) or charuco:9x6"),
    (["--square", "1e-300", "--marker", "1e-301"],
     "drovisio bench real: argument --square: 1e-300 is out of range: give a number from 0.001 "
     "to 1 m (see drovisio bench real --help)"),
])
def test_a_charuco_board_is_bounded_as_every_board_spec(tmp_path, capsys, argv, line):
    d = _charuco_folder(tmp_path / "board")
    rc, _, err = _run(capsys, d, *argv)
    assert rc == 2 and err.splitlines()[-1] == line


@pytest.mark.parametrize("make, why", [
    (lambda d: (d / "a.png").symlink_to(d / "missing.png"),
     "a symbolic link to nothing (its target does not exist); give the real path"),
    (lambda d: ((d / "a.png").symlink_to(d / "b.png"), (d / "b.png").symlink_to(d / "a.png")),
     "a loop of symbolic links (they lead to each other, never to a file or folder); give the "
     "real path"),
    (lambda d: os.mkfifo(d / "a.png"), "not a regular file (a pipe or a device)"),
])
def test_a_picture_that_is_no_file_is_named_not_passed_over(tmp_path, capsys, make, why):
    d = _chess_folder(tmp_path / "set")
    make(d)
    rc, _, err = _run(capsys, d, "--calibrate", "none")
    assert rc == 2 and err == (f"drovisio bench: {d / 'a.png'}: {why}; or remove it from the "
                               "folder\n")


def test_a_folder_of_more_pictures_than_used_says_so_and_shows_progress(
        tmp_path, capsys, monkeypatch):
    from drovisio.bench import real_folder

    monkeypatch.setattr(real_folder, "MAX_IMAGES", 2)
    d = _chess_folder(tmp_path / "set", ((640, 480),) * 3)
    rc, _, err = _run(capsys, d, "--calibrate", "none")
    assert rc == 0
    lines = err.splitlines()
    assert lines[0] == (f"{d}: 3 pictures; the first 2 in name order are used (from chess0.png "
                        "to chess1.png)")
    assert f"  ... {d}: 1 of 2 photos done" in lines and f"  ... {d}: 2 of 2 photos done" in lines


def test_pictures_held_at_once_are_bounded_by_the_work_cap(tmp_path, capsys, monkeypatch):
    from drovisio.errors import LIMITS

    monkeypatch.setattr(LIMITS, "max_work_bytes", 2**20)
    d = _chess_folder(tmp_path / "set", ((640, 480),) * 4)
    rc, _, err = _run(capsys, d, "--calibrate", "none")
    assert rc == 2 and err == (
        f"drovisio bench: {d}: 4 pictures of 640x480 held at once need 0.0 GiB, more than the "
        "0.0 GiB cap; give fewer or smaller pictures (DROVISIO_MAX_WORK_MIB raises the cap)\n")


@pytest.mark.parametrize("fisheye, words", [
    (True, "OpenCV's fisheye.calibrate failed in Mat: 0 <= _rowRange.start"),
    (False, "OpenCV's calibrateCamera failed in initIntrinsicParams2D: matH0.size()"),
])
def test_plain_opencvs_failed_solve_is_said_by_its_function_not_its_source_path(fisheye, words):
    """A failed reference solve is said by OpenCV's function and check, without the build's
    source path and version line OpenCV's message opens with."""
    import numpy as np

    from drovisio.bench.real import _opencv_calibration

    got = _opencv_calibration([np.zeros((4, 3), np.float32)], [np.zeros((4, 2), np.float32)],
                              (10, 10), fisheye)
    assert set(got) == {"failed"} and got["failed"].startswith(words)
    assert ".cpp" not in got["failed"] and "OpenCV(" not in got["failed"]
