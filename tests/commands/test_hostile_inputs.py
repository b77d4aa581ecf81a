"""Every command given what a hostile or unlucky user gives it: one line naming the file, the
field and the fix, a non-zero exit, no traceback, no hang, nothing already saved lost.

Each test is named after what it protects.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.cli import main
from drovisio.resources import layouts_dir, sample_sessions_dir

SAMPLE = sample_sessions_dir()
CAMERA = SAMPLE / "camera.yaml"
VIDEO = SAMPLE / "approach" / "approach.mp4"
CENTRE = layouts_dir() / "drick-aruco-centre.json"
PYRAMIDS = layouts_dir() / "drick-aruco-pyramids.json"


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "Traceback" not in out
    return rc, out, err


def subprocess_cli(*argv, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "drovisio", *map(str, argv)], capture_output=True,
                       text=True, timeout=timeout, stdin=subprocess.DEVNULL, **kw)
    assert "Traceback" not in r.stderr, r.stderr
    return r


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> Path:
    """Three frames of the sample approach video (bricks in view) as PNG files."""
    d = tmp_path_factory.mktemp("frames")
    cap = cv2.VideoCapture(str(VIDEO))
    k = 0
    for i in range(101):
        ok, img = cap.read()
        assert ok
        if i in (97, 99, 100):
            cv2.imwrite(str(d / f"f{k}.png"), img)
            k += 1
    cap.release()
    return d


def huge_jpeg_header() -> bytes:
    """A small JPEG whose header claims 65000 x 65000 pixels."""
    ok, buf = cv2.imencode(".jpg", np.full((16, 16, 3), 128, np.uint8))
    data = bytearray(buf.tobytes())
    i = data.index(b"\xff\xc0")                     # start of frame: height, width at +5
    data[i + 5:i + 9] = (65000).to_bytes(2, "big") * 2
    return bytes(data)


def damaged_videos(d: Path) -> dict[str, int]:
    """A 60-frame MP4 with its middle overwritten, and a 60-frame AVI cut in half."""
    def make(path: Path, fourcc: str) -> None:
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 15, (640, 480))
        for i in range(60):
            img = np.full((480, 640, 3), 40, np.uint8)
            cv2.putText(img, str(i), (200, 300), 0, 6, (255, 255, 255), 9)
            w.write(img)
        w.release()

    make(d / "a.mp4", "mp4v")
    make(d / "a.avi", "MJPG")
    m = bytearray((d / "a.mp4").read_bytes())
    mid = len(m) // 2
    m[mid:mid + len(m) // 8] = os.urandom(len(m) // 8)
    (d / "mid.mp4").write_bytes(bytes(m))
    a = (d / "a.avi").read_bytes()
    (d / "cut.avi").write_bytes(a[:len(a) // 2])
    return {"mid.mp4": 60, "cut.avi": 60}


# ------------------------------------------------------------------ drovisio detect


def test_detect_survives_a_jpeg_claiming_65000_squared_pixels(capsys, frames, tmp_path):
    bomb = tmp_path / "bomb.jpg"
    bomb.write_bytes(huge_jpeg_header())
    rc, out, err = run_cli(capsys, "detect", "--camera", CAMERA, "--layout", CENTRE,
                           "--layout", PYRAMIDS, bomb, frames / "f0.png")
    lines = [json.loads(x) for x in out.splitlines()]
    assert rc == 1 and len(lines) == 2
    assert "4225 Mpx" in lines[0]["error"] and "DROVISIO_MAX_IMAGE_MPX" in lines[0]["error"]
    assert "error" not in lines[1] and lines[1]["bricks"]      # the next file still runs


def test_detect_says_a_damaged_image_in_its_own_line_without_the_decoders_noise(
        capfd, frames, tmp_path):
    png = (frames / "f0.png").read_bytes()
    cut = tmp_path / "cut.png"
    cut.write_bytes(png[: len(png) // 2])          # libpng: "PNG input buffer is incomplete"
    ok, jpg = cv2.imencode(".jpg", cv2.imread(str(frames / "f0.png")))
    holed = tmp_path / "holed.jpg"                 # its end marker kept: decoded, partly grey
    holed.write_bytes(jpg.tobytes()[: len(jpg) // 2] + b"\xff\xd9")
    rc = main(["detect", "--camera", str(CAMERA), "--layout", str(CENTRE), str(cut),
               str(holed)])
    out, err = capfd.readouterr()
    lines = [json.loads(x) for x in out.splitlines()]
    assert rc == 1 and len(lines) == 2
    assert lines[0]["error"] == ("cannot be read as an image (corrupt, truncated or not an "
                                 "image: libpng error: PNG input buffer is incomplete)")
    assert "error" not in lines[1]
    # every line on stderr is Drovisio's own, naming the file
    assert all(ln.startswith("drovisio detect: ") for ln in err.splitlines()), err
    assert (f"drovisio detect: {holed}: damaged image, decoded with the decoder's warning: "
            "Corrupt JPEG data: premature end of data segment") in err.splitlines()


def test_only_the_decoders_lines_are_kept_off_stderr_while_decoding(capfd):
    from drovisio.images import _library_messages

    with _library_messages() as said:      # another thread's line may land in the window
        os.write(2, b"libpng error: IDAT: CRC error\ndrovisio run: 12 fps\n"
                    b"Warning: a thread's own warning\n"
                    b"[ WARN:0@1.2] global cap_v4l.cpp:999 open VIDEOIO(V4L2:/dev/video0)\n"
                    + b"x" * 100_000 + b"\n")
    assert said == ["libpng error: IDAT: CRC error"]
    assert capfd.readouterr().err == ("drovisio run: 12 fps\nWarning: a thread's own warning\n"
                                      "[ WARN:0@1.2] global cap_v4l.cpp:999 open "
                                      "VIDEOIO(V4L2:/dev/video0)\n" + "x" * 100_000 + "\n")


def test_detect_never_reads_a_pipe(tmp_path):
    fifo = tmp_path / "frame.png"
    os.mkfifo(fifo)
    r = subprocess_cli("detect", "--camera", CAMERA, "--layout", CENTRE, fifo, timeout=60)
    assert r.returncode == 1
    assert json.loads(r.stdout)["error"] == "not a regular file (a pipe or a device)"


def test_detect_out_may_not_overwrite_an_input_or_the_camera_file(capsys, frames, tmp_path):
    cam = tmp_path / "camera.yaml"
    shutil.copy(CAMERA, cam)
    before = cam.read_bytes()
    for target in (cam, frames / "f0.png"):
        keep = target.read_bytes()
        rc, out, err = run_cli(capsys, "detect", "--camera", cam, "--layout", CENTRE,
                               "--out", target, frames / "f0.png")
        assert rc == 2 and "same file as" in err and err.count("\n") == 1
        assert target.read_bytes() == keep
    assert cam.read_bytes() == before


def test_detect_out_is_replaced_only_when_the_run_ends(capsys, frames, tmp_path):
    out_file = tmp_path / "poses.jsonl"
    out_file.write_text("previous run\n")
    rc, _, _ = run_cli(capsys, "detect", "--camera", CAMERA, "--layout", CENTRE, "--layout",
                       PYRAMIDS, "--out", out_file, frames)
    assert rc == 0 and len(out_file.read_text().splitlines()) == 3
    assert [p.name for p in tmp_path.iterdir()] == ["poses.jsonl"]   # no temporary left


def test_detect_piped_into_head_ends_quietly(frames):
    p = subprocess.Popen([sys.executable, "-m", "drovisio", "detect", "--camera", str(CAMERA),
                          "--layout", str(CENTRE), str(VIDEO)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
    first = p.stdout.readline()
    p.stdout.close()                                  # what `| head -1` does
    err = p.stderr.read().decode()
    rc = p.wait(timeout=120)
    assert json.loads(first)["frame"] == 0
    assert "Traceback" not in err and "BrokenPipe" not in err
    assert rc in (0, 141)


def test_detect_reports_every_frame_of_a_damaged_video(capsys, tmp_path):
    counts = damaged_videos(tmp_path)
    for name, n in counts.items():
        rc, out, err = run_cli(capsys, "detect", "--camera", CAMERA, "--layout", CENTRE,
                               tmp_path / name)
        lines = [json.loads(x) for x in out.splitlines()]
        frames_seen = {x["frame"] for x in lines if "error" not in x}
        bad = [x for x in lines if "error" in x]
        covered = set(frames_seen)
        for x in bad:                     # an error line covers one frame (or the rest)
            covered.add(x["frame"])
            if "the video ends at frame" in x["error"] or "no frame of the" in x["error"]:
                covered.update(range(x["frame"], n))
                assert x is bad[-1], name   # one line for the cut-short end, and it is last
        assert rc == 1 and bad, name
        assert covered == set(range(n)), (name, sorted(set(range(n)) - covered))
        assert all("could not be decoded" in x["error"] or "the video ends at frame"
                   in x["error"] or "no frame of the" in x["error"] for x in bad), name
        assert len(bad) <= 10, (name, len(bad))   # never one line per missing frame


def test_detect_takes_the_image_size_when_the_camera_file_has_none(capsys, frames, tmp_path):
    text = CAMERA.read_text().splitlines()
    cam = tmp_path / "no-size.yaml"
    cam.write_text("\n".join(t for t in text if not t.startswith("image_")) + "\n")
    rc, out, err = run_cli(capsys, "detect", "--camera", cam, "--layout", CENTRE, "--layout",
                           PYRAMIDS, frames / "f1.png")
    res = json.loads(out)
    assert rc == 0 and "error" not in res and res["bricks"]


def test_detect_with_a_layout_without_dimensions(capsys, frames, tmp_path):
    data = json.loads(CENTRE.read_text())
    data.pop("dimensions")
    data.pop("mesh", None)
    lay = tmp_path / "plain-code.json"
    lay.write_text(json.dumps(data))
    rc, out, err = run_cli(capsys, "detect", "--camera", CAMERA, "--layout", lay,
                           frames / "f1.png")
    assert rc == 0 and json.loads(out)["bricks"]
    from drovisio.layout import load_layout

    dims = load_layout(lay).dimensions_m       # from the code square: 6.5 cm, 1 mm thick
    assert dims[0] == pytest.approx(0.065) and dims[1] == pytest.approx(0.065)
    assert dims[2] == pytest.approx(0.001)


# ------------------------------------------------------------------ drovisio run


@pytest.mark.parametrize("make_source,needle", [
    (lambda d: d / "missing.mp4", "no such file or folder"),
    (lambda d: [(d / "a.mp4").symlink_to(d / "b.mp4"), (d / "b.mp4").symlink_to(d / "a.mp4"),
                d / "a.mp4"][2], "--source: a loop of symbolic links"),
    (lambda d: (d / "empty").mkdir() or d / "empty", "no images in the folder"),
    (lambda d: [(d / "cut.mp4").write_bytes(VIDEO.read_bytes()[:20000]), d / "cut.mp4"][1],
     "cannot open the video"),
])
def test_run_ends_at_once_on_a_finite_source_that_cannot_be_read(tmp_path, make_source, needle):
    src = make_source(tmp_path)
    # a source retried forever would hang: the timeout is a bound for that failure only (a
    # loaded machine starts the process slowly, not wrongly)
    r = subprocess_cli("run", "--source", src, "--camera", CAMERA, "--layout", CENTRE,
                       "--sink", f"jsonl:{tmp_path / 'out.jsonl'}", "--quiet", timeout=120)
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr and str(src) in r.stderr


@pytest.mark.parametrize("argv,needle", [
    (["--frames", "0"], "--frames"),
    (["--max-age", "nan"], "--max-age"),
    (["--max-age", "-1"], "--max-age"),
    (["--sink", "mavlink:udpout:no.such.host.invalid:14550"], "unknown host"),
    (["--sink", "teapot:5"], "unknown sink"),
    (["--target", "a:b"], "--target"),
])
def test_run_refuses_bad_options_in_one_line(capsys, argv, needle):
    rc, out, err = run_cli(capsys, "run", "--source", VIDEO, "--camera", CAMERA, "--layout",
                           CENTRE, *argv)
    assert rc == 2 and needle in err


def test_run_reports_a_failing_sink_and_exits_non_zero(tmp_path):
    r = subprocess_cli("run", "--source", VIDEO, "--camera", CAMERA, "--layout", CENTRE,
                       "--pace", "max", "--frames", "20", "--sink", "jsonl:/dev/full",
                       timeout=120)
    assert r.returncode == 1
    assert "sink jsonl:/dev/full: 20 sends failed" in r.stderr
    assert "No space left on device" in r.stderr


def test_run_outputs_never_land_in_an_input_folder_nor_on_each_other(capsys, frames, tmp_path):
    folder = tmp_path / "frames"
    shutil.copytree(frames, folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    cases = [
        (["--source", folder, "--sink", f"jsonl:{folder / 'f0.png'}"],
         f"{folder / 'f0.png'}: --sink jsonl:PATH would land among what the command reads "
         f"from --source {folder}; choose another folder"),
        (["--source", folder, "--sink", f"jsonl:{folder / 'x.jpg'}"],
         f"{folder / 'x.jpg'}: --sink jsonl:PATH would land among what the command reads "
         f"from --source {folder}; choose another folder"),
        (["--source", VIDEO, "--record", tmp_path / "r.mcap", "--sink",
          f"jsonl:{tmp_path / 'r.mcap'}"],
         f"{tmp_path / 'r.mcap'}: --sink jsonl:PATH is the same file as --record; give each "
         "output its own name"),
        (["--source", VIDEO, "--record", tmp_path / "rec", "--sink",
          f"jsonl:{tmp_path / 'rec' / 'frames.jsonl'}"],
         f"{tmp_path / 'rec' / 'frames.jsonl'}: --sink jsonl:PATH lies inside --record's "
         f"folder {tmp_path / 'rec'}; give it a place outside"),
        (["--source", VIDEO, "--sink", f"jsonl:{tmp_path / 'x'}", "--sink",
          f"jsonl:{tmp_path / 'x'}"],
         f"{tmp_path / 'x'}: --sink jsonl:PATH is given twice; give each output its own name"),
    ]
    for argv, line in cases:
        rc, _, err = run_cli(capsys, "run", "--camera", CAMERA, "--layout", CENTRE, "--quiet",
                             *argv)
        assert rc == 2 and err == f"drovisio run: {line}\n"
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames"]


def test_detect_out_may_not_replace_an_image_of_an_input_folder(capsys, frames, tmp_path):
    folder = tmp_path / "frames"
    shutil.copytree(frames, folder)
    keep = (folder / "f0.png").read_bytes()
    rc, _, err = run_cli(capsys, "detect", "--camera", CAMERA, "--layout", CENTRE, "--out",
                         folder / "f0.png", folder)
    assert rc == 2 and err == (f"drovisio detect: {folder / 'f0.png'}: --out would land among "
                               f"what the command reads from input {folder}; choose another "
                               "folder\n")
    assert (folder / "f0.png").read_bytes() == keep


def test_run_says_frames_that_do_not_fit_the_camera_file_and_exits_2(capsys, frames, tmp_path):
    small = tmp_path / "small"
    small.mkdir()
    for f in sorted(frames.iterdir()):
        cv2.imwrite(str(small / f.name), cv2.resize(cv2.imread(str(f)), (320, 240)))
    rc, _, err = run_cli(capsys, "run", "--source", small, "--camera", CAMERA, "--layout",
                         CENTRE, "--sink", f"jsonl:{tmp_path / 'o.jsonl'}", "--quiet",
                         "--pace", "max")
    assert rc == 2
    assert err.splitlines()[-1] == (
        f"drovisio run: {CAMERA}: frames not measured: 3 of 3, image is 320x240 but the "
        "camera file is for 640x480; give the camera file of this camera at this resolution")
    # the live page's status says them too
    from drovisio.pipeline_config import PipelineConfig
    from drovisio.startup import build_pipeline

    p = build_pipeline(PipelineConfig(source=str(small), camera=str(CAMERA),
                                      layouts=[str(CENTRE)], sinks=[], pace="max"),
                       default_sinks=())
    try:
        p.run()
        st = p.status()
    finally:
        p.close()
    assert st["unfit_frames"] == 3 and "image is 320x240" in st["unfit"]


def test_run_refuses_a_layout_the_dot_detector_cannot_use_before_writing(capsys, tmp_path):
    """Three dots load as a layout, but the dot detector needs four: refused by the start-up
    check in one line naming the file, not as an internal error once the sinks are open."""
    doc = json.loads((layouts_dir() / "drick-dots-2x3.json").read_text())
    doc.update(name="three-dots", symmetry="none", markers=doc["markers"][:3])
    layout = tmp_path / "three.json"
    layout.write_text(json.dumps(doc))
    rc, out, err = run_cli(capsys, "run", "--source", VIDEO, "--camera", CAMERA, "--layout",
                           layout, "--sink", f"jsonl:{tmp_path / 'o.jsonl'}", "--quiet")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["three.json"]
    assert (rc, out) == (2, "")
    assert err == (f"drovisio run: {layout}: markers: the dot detector needs at least 4 dots, "
                   "it has 3; put at least 4 dots on one flat face, or remove them\n")


def test_run_refuses_a_camera_index_no_device_has(capsys):
    digits = "123456789012345678901234567890123"
    rc, _, err = run_cli(capsys, "run", "--source", digits, "--camera", CAMERA, "--layout",
                         CENTRE)
    assert rc == 2 and err == (f"drovisio run: {digits}: --source: not a camera index (0 to "
                               f"255, for /dev/videoN); a file or folder of that name is "
                               f"./{digits}\n")


def test_a_lost_source_is_said_even_with_quiet(capsys):
    """--quiet hides the status line, never a failure: each loss is said once."""
    from types import SimpleNamespace

    from drovisio.commands.run import Alarms, _run_until_done

    def status(state: str, unfit: int = 0):
        return SimpleNamespace(source=SimpleNamespace(state=state, label="camera 7",
                                                      error="cannot open camera 7"),
                               unfit_frames=unfit, unfit="image is 320x240", sinks=[])

    class Pipeline:
        said = [status("lost"), status("lost"), status("live"), status("lost", unfit=2),
                status("lost", unfit=3)]

        def run(self, max_frames=None, on_status=None):
            for st in self.said:
                on_status(st)
            return 0

        def snapshot(self):
            return self.said[-1]

        def close(self):
            pass

    _run_until_done(Pipeline(), None, True, 0.0, Alarms("cam.yaml"))
    lost = ("drovisio run: source camera 7 lost (cannot open camera 7); retrying until it "
            "comes back")
    assert capsys.readouterr().err.splitlines() == [
        lost, lost, "drovisio run: cam.yaml: frames not measured: image is 320x240; give the "
                    "camera file of this camera at this resolution"]


# ------------------------------------------------------------------ drovisio calibrate


def test_calibrate_refuses_out_equal_to_report(capsys, tmp_path):
    cam = tmp_path / "camera.yaml"
    shutil.copy(CAMERA, cam)
    before = cam.read_bytes()
    rc, _, err = run_cli(capsys, "calibrate", "--board", "chessboard:9x6", "--square", "0.025",
                         "--out", cam, "--report", cam, SAMPLE / "calibration")
    assert rc == 2 and "--report" in err and "same file" in err
    assert cam.read_bytes() == before


def test_calibrate_refuses_the_same_picture_twice(capsys, tmp_path):
    for i in range(20):
        shutil.copy(SAMPLE / "calibration" / "view_00.jpg", tmp_path / f"copy_{i:02d}.jpg")
    rc, _, err = run_cli(capsys, "calibrate", "--board", "chessboard:9x6", "--square", "0.025",
                         "--out", tmp_path / "cam.yaml", tmp_path)
    assert rc == 1 and err.count("the same picture as copy_00.jpg") == 19
    assert "only 1 usable view" in err and not (tmp_path / "cam.yaml").exists()


# ------------------------------------------------------------------ other commands


def test_mission_refuses_a_negative_brick_count(capsys, tmp_path):
    rc, _, err = run_cli(capsys, "mission", "simulate", "wall-2-courses", "--record",
                         tmp_path / "r", "--bricks", "-1")
    assert rc == 2 and "--bricks" in err


def test_mission_refuses_a_yaml_alias_bomb_quickly(capsys, tmp_path):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"a{i}: &a{i} [*a{i - 1 if i else ''}, *a{i - 1 if i else ''}, "
        f"*a{i - 1 if i else ''}]\n".replace("*a-1", "*a") for i in range(40)))
    t0 = time.monotonic()
    rc, _, err = run_cli(capsys, "mission", "check", bomb)
    assert rc == 2 and "aliases" in err and err.count("\n") == 1
    assert time.monotonic() - t0 < 60      # expanded, 3**40 lists would never end


def test_serve_refuses_a_port_that_is_not_one(capsys):
    rc, _, err = run_cli(capsys, "serve", "--port", "99999")
    assert rc == 2 and "99999 is not a port" in err


def test_serve_refuses_a_bad_camera_file_before_starting(capsys, tmp_path):
    bad = tmp_path / "cam.yaml"
    bad.write_text("image_width: abc\n")
    rc, _, err = run_cli(capsys, "serve", "--camera", bad)
    assert rc == 2 and str(bad) in err and err.count("\n") == 1


def test_serve_that_cannot_start_leaves_no_empty_sink_file(capsys, tmp_path):
    """Serve's start-up check opens and closes every sink: a jsonl:PATH file it made, and
    never wrote to, is removed again (here the port is taken, so serve ends at once)."""
    import socket

    kept = tmp_path / "kept.jsonl"
    kept.write_bytes(b'{"file":"earlier.png","frame":0,"bricks":[]}\n')
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        rc, _, err = run_cli(capsys, "serve", "--port", taken.getsockname()[1], "--camera",
                             CAMERA, "--layout", CENTRE, "--sink", f"jsonl:{kept}", "--sink",
                             f"jsonl:{tmp_path / 'out' / 'new.jsonl'}", "--data",
                             tmp_path / "data")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.jsonl"]
    assert kept.read_bytes() == b'{"file":"earlier.png","frame":0,"bricks":[]}\n'
    assert rc == 2 and "cannot listen" in err and err.count("\n") == 1


def test_serial_mavlink_has_its_module():
    """mavlink:/dev/ttyAMA0,921600 needs pyserial (a dependency): the error names the port,
    not a missing module."""
    from drovisio.sinks.base import SinkError
    from drovisio.sinks.mavlink import MavlinkSink

    with pytest.raises(SinkError) as e:
        MavlinkSink("/dev/ttyDROVISIO-NONE,921600")
    assert "No module named" not in str(e.value)


def test_unexpected_errors_leave_one_line_and_a_traceback_file(capsys, monkeypatch, frames):
    import drovisio.commands.detect as detect

    def boom(args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(detect, "run", boom)
    rc, _, err = run_cli(capsys, "detect", "--camera", CAMERA, "--layout", CENTRE,
                         frames / "f0.png")
    assert rc == 1 and err.count("\n") == 1 and "internal error: ZeroDivisionError" in err
    path = Path(err.split("full traceback in ")[1].split(";")[0])
    assert "ZeroDivisionError" in path.read_text()
    path.unlink()




@pytest.mark.parametrize("bench", ["aruco", "dots", "lens"])
def test_bench_json_where_it_cannot_be_written_is_refused_before_the_work(capsys, tmp_path,
                                                                          bench):
    rc, _, err = run_cli(capsys, "bench", bench, "--json", tmp_path / "missing" / "x.json")
    assert rc == 2 and "--json: the folder does not exist" in err
    rc, _, err = run_cli(capsys, "bench", bench, "--json", tmp_path)
    assert rc == 2 and "--json is a folder" in err
    assert list(tmp_path.iterdir()) == []
