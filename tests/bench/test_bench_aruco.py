"""``drovisio bench aruco``: recall by code size and AprilTag 3 on the same frames, in the
JSON it writes; clear refusals of what it cannot measure."""

from __future__ import annotations

import json

import pytest

from drovisio.bench import aruco


def test_recall_by_size_and_apriltag_on_the_same_frames(tmp_path, capsys):
    pytest.importorskip("pupil_apriltags")
    out = tmp_path / "report.json"
    rc = aruco.main(["--frames", "3", "--bricks", "4", "--empty", "2", "--repeat", "1",
                     "--dictionary", "DICT_APRILTAG_36h11", "--apriltag", "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    by = data["recall_by_size"]
    assert set(by) == {"drovisio", "apriltag3"}
    for method in by.values():
        assert list(method) == ["14-20 px", "20-30 px", ">30 px"]
    # the bins add up to the rows' countable bricks, for both methods on the same frames
    ours = [r for r in data["rows"] if r.get("method") is None and r["scene"] == "bricks"
            and r["gravity"]]
    peer = [r for r in data["rows"] if r.get("method") == "apriltag3" and r["scene"] == "bricks"]
    assert sum(b["countable"] for b in by["drovisio"].values()) == ours[0]["countable"] > 0
    assert sum(b["countable"] for b in by["apriltag3"].values()) == peer[0]["countable"]
    assert sum(b["found"] for b in by["apriltag3"].values()) == peer[0]["found"] > 0
    assert peer[0]["apriltag_ms_median"] > 0 and peer[0]["false_bricks"] == 0
    text = capsys.readouterr().out
    assert "recall by code size, apriltag3:" in text and "AT3" in text


def test_what_cannot_be_measured_is_refused_in_one_line(capsys, request):
    assert aruco.main(["--dictionary", "DICT_9X9_1", "--frames", "1"]) == 2
    assert "--dictionary:" in capsys.readouterr().err
    request.getfixturevalue("no_apriltag")
    assert aruco.main(["--apriltag", "--dictionary", "DICT_APRILTAG_36h11",
                       "--frames", "1"]) == 2
    assert "pip install drovisio[peers]" in capsys.readouterr().err


def test_video_timing_on_a_folder_of_frames(tmp_path, capsys):
    # a folder of rendered frames with tag36h11 bricks: every detector runs on the same
    # frames, the codes are found (the figures are times, so only their shape is checked)
    pytest.importorskip("pupil_apriltags")
    import cv2

    from drovisio.camera import Camera
    from drovisio.layout import load_layouts, shipped_layouts_dir, with_dictionary
    from drovisio.scenes import SceneSpec, render_random

    base = load_layouts([shipped_layouts_dir() / "drick-aruco-centre.json",
                         shipped_layouts_dir() / "drick-aruco-pyramids.json"])
    lays = [with_dictionary(lay, "DICT_APRILTAG_36h11") for lay in base]
    spec = SceneSpec(layouts=lays, n_bricks=3, distance=(0.6, 1.0), tilt_deg=(0.0, 15.0))
    frames = tmp_path / "frames"
    frames.mkdir()
    for s in range(3):
        r = render_random(9100 + s, spec, Camera.drone_webcam(), ss=2)
        cv2.imwrite(str(frames / f"{s:03d}.png"), r.image)
    (frames / "notes.txt").write_text("not a frame")
    out = tmp_path / "video.json"
    rc = aruco.main(["--video", str(frames), "--dictionary", "DICT_APRILTAG_36h11",
                     "--repeat", "1", "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["frames"] == 3 and data["size"] == [640, 480]
    row = data["dictionaries"]["DICT_APRILTAG_36h11"]
    # the bricks the detector finds on these frames by itself, and codes for all three
    from drovisio.detect.aruco import ArucoBrickDetector

    det = ArucoBrickDetector(Camera.from_fov(640, 480, 60.0), lays)
    direct = sum(len(det.detect(cv2.imread(str(p)))) for p in sorted(frames.glob("*.png")))
    assert row["bricks"] == direct >= 5, (row, direct)
    assert row["plain_codes"] >= 5 and row["apriltag_tags"] >= 5, row
    for key in ("ours_s", "plain_s", "apriltag_s"):
        assert len(row[key]) == 2 and 0 < row[key][0] <= row[key][1]
    assert row["ratio_plain"][0] == pytest.approx(row["ours_s"][0] / row["plain_s"][0])
    text = capsys.readouterr().out
    assert "DICT_APRILTAG_36h11" in text and "AprilTag3 ms" in text


def test_video_that_cannot_be_read_is_refused_in_one_line(tmp_path, capsys):
    from drovisio.cli import main

    bad = tmp_path / "clip.avi"
    bad.write_bytes(b"\x00" * 64)
    assert main(["bench", "aruco", "--video", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "--video" in err[0], err
    assert main(["bench", "aruco", "--video", str(tmp_path / "none")]) == 2
    assert main(["bench", "aruco", "--video", str(tmp_path), "--dictionary", "DICT_9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "--dictionary" in err[1], err


def _avi(path, n: int = 30, size=(64, 48)):
    """An MJPEG AVI of ``n`` noise frames (noise: every frame a different size on disk)."""
    import cv2
    import numpy as np

    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, size)
    rng = np.random.default_rng(0)
    for _ in range(n):
        w.write(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    w.release()
    return path


def _bench_err(capsys, *argv: str) -> tuple[int, list[str]]:
    from drovisio.cli import main

    rc = main(["bench", "aruco", "--repeat", "1", "--dictionary", "DICT_4X4_50", *argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, [ln for ln in err.splitlines() if not ln.startswith("  ... ")]


def test_video_is_read_by_the_sources_reader_with_its_bounds(tmp_path, capsys):
    import os
    import struct

    # a header announcing 30000x30000 frames: refused before a frame is decoded
    d = bytearray(_avi(tmp_path / "small.avi", n=3).read_bytes())
    struct.pack_into("<II", d, d.find(b"avih") + 8 + 32, 30000, 30000)
    struct.pack_into("<ii", d, d.find(b"strf") + 8 + 4, 30000, 30000)
    huge = tmp_path / "huge.avi"
    huge.write_bytes(bytes(d))
    assert _bench_err(capsys, "--video", str(huge)) == (2, [
        f"drovisio bench: {huge}: --video: its header announces frames of 30000x30000 "
        "(900 Mpx), more than the 50 Mpx (and 20000 pixels a side) Drovisio decodes; "
        "re-encode it smaller (or set DROVISIO_MAX_IMAGE_MPX)"])
    # a pipe is never opened (reading it would wait for a writer forever)
    fifo = tmp_path / "clip.mp4"
    os.mkfifo(fifo)
    assert _bench_err(capsys, "--video", str(fifo)) == (2, [
        f"drovisio bench: {fifo}: --video: not a regular file (a folder, a pipe or a device)"])
    # a text file is no video
    text = tmp_path / "passwd"
    text.write_text("root:x:0:0:root:/root:/bin/bash\n")
    assert _bench_err(capsys, "--video", str(text)) == (2, [
        f"drovisio bench: {text}: --video: cannot open the video (unknown format, or a "
        "damaged or cut-short file)"])


def test_a_cut_short_video_is_timed_up_to_where_it_ends_said_in_one_line(tmp_path, capsys):
    data = _avi(tmp_path / "whole.avi").read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[:len(data) // 2])
    out = tmp_path / "cut.json"
    rc, err = _bench_err(capsys, "--video", str(cut), "--json", str(out))
    assert rc == 0
    assert len(err) == 1 and err[0].startswith(f"drovisio bench: {cut} frame 14: the video "
                                               "ends at frame 14, 16 frames before the 30 "
                                               "its header announces"), err
    assert err[0].endswith("; timing the 14 frame(s) before it")
    assert json.loads(out.read_text())["frames"] == 14


def test_frames_over_the_work_cap_are_refused_before_they_are_held(tmp_path, capsys,
                                                                    monkeypatch):
    from drovisio.errors import LIMITS

    clip = _avi(tmp_path / "clip.avi", n=30, size=(320, 240))
    monkeypatch.setattr(LIMITS, "max_work_bytes", 2**20)
    rc, err = _bench_err(capsys, "--video", str(clip))
    assert rc == 2 and err == [
        f"drovisio bench: {clip}: --max-frames: 30 frames of 320x240 held at once need "
        "0.0 GiB, more than the 0.0 GiB cap; give fewer --max-frames (DROVISIO_MAX_WORK_MIB "
        "raises the cap)"]
    assert _bench_err(capsys, "--video", str(clip), "--max-frames", "3")[0] == 0
    rc, err = _bench_err(capsys, "--video", str(clip), "--max-frames", "9" * 40)
    assert rc == 2 and len(err) == 1 and "--max-frames" in err[0], err
