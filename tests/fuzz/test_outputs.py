"""Class: what a command writes — outputs that are also inputs, names the file system cannot
hold, read-only folders and full disks, for every writer.

* Every writing command refuses, before any work, an output that is one of its inputs
  (``calibrate mount --camera cam.yaml --out cam.yaml``), a name of 300 bytes, a NUL byte or a
  line break in a name, a folder given as a file and a file given as a folder: exit 2, one
  line naming the option; the input is unchanged.
* Every artefact (JSON, figures, videos, images, mount files, mission recordings) goes
  through the verified writer: with the disk full (``fsync`` answering ENOSPC inside the
  writer) or the folder read-only, the old file is byte for byte what it was.
"""

from __future__ import annotations

import errno
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from drovisio.errors import WriteError


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _settings(n: int):
    from hypothesis import HealthCheck, settings

    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


def _writers(f: dict, tmp: Path, out: str) -> dict[str, list[str]]:
    """Each writing command, its output option set to ``out``."""
    cam, lay = str(tmp / "cam.yaml"), str(tmp / "lay.json")
    return {
        "calibrate --out": ["calibrate", "--board", "chessboard:9x6", "--square", "0.025",
                            "--out", out, str(f["images"])],
        "calibrate --report": ["calibrate", "--board", "chessboard:9x6", "--square", "0.025",
                               "--out", str(tmp / "c.yaml"), "--report", out,
                               str(f["images"])],
        "calibrate board --pdf": ["calibrate", "board", "--pdf", out],
        "calibrate mount --out": ["calibrate", "mount", "--camera", cam, "--layout", lay,
                                  "--out", out, str(f["images"])],
        "detect --out": ["detect", "--camera", cam, "--layout", lay, "--out", out,
                         str(f["video"])],
        "run --sink jsonl": ["run", "--source", str(f["video"]), "--camera", cam, "--layout",
                             lay, "--sink", f"jsonl:{out}", "--frames", "1", "--quiet"],
        "mission check --json": ["mission", "check", "wall-2-courses", "--json", out],
        "mission diagram --out": ["mission", "diagram", "--out", out],
        "bench lens --json": ["bench", "lens", "--json", out, "--views", "2"],
    }


#: output names no file system holds, or that are inputs
BAD_OUTPUTS = ["camera", "layout", "long", "nul", "newline", "folder", "tab"]


def _bad_output(kind: str, tmp: Path) -> str:
    return {"camera": str(tmp / "cam.yaml"), "layout": str(tmp / "lay.json"),
            "long": str(tmp / ("o" * 300 + ".json")), "nul": str(tmp / "o\x00.json"),
            "newline": str(tmp / "o\n.json"), "folder": str(tmp),
            "tab": str(tmp / "a\tb.json")}[kind]


@_settings(80)
@given(writer=st.sampled_from(sorted(_writers({"images": "", "video": ""}, Path("."), ""))),
       kind=st.sampled_from(BAD_OUTPUTS))
def test_every_writer_refuses_an_output_that_is_an_input_or_no_name(
        cli, hostile_files, tmp_path_factory, writer, kind):
    # commands that read no camera or layout: a file of that name is just an output
    assume(not (kind in ("camera", "layout") and writer in (
        "calibrate board --pdf", "mission diagram --out", "mission check --json",
        "bench lens --json")))
    tmp = tmp_path_factory.mktemp("out")
    (tmp / "cam.yaml").write_bytes(Path(hostile_files["camera"]).read_bytes())
    (tmp / "lay.json").write_bytes(Path(hostile_files["pad"]).read_bytes())
    before = {p.name: _digest(p) for p in tmp.iterdir()}
    argv = _writers(hostile_files, tmp, _bad_output(kind, tmp))[writer]
    rc, out, err = cli(*argv, cls="outputs: bad names and inputs")
    assert rc == 2, (writer, kind, err[-300:])
    assert "Traceback" not in err and "internal error" not in err
    after = {p.name: _digest(p) for p in tmp.iterdir()}
    assert after == before, "nothing already saved is changed"


def test_calibrate_mount_refuses_to_overwrite_its_camera_file(cli, hostile_files, tmp_path):
    cam = tmp_path / "cam.yaml"
    cam.write_bytes(Path(hostile_files["camera"]).read_bytes())
    before = _digest(cam)
    rc, _, err = cli("calibrate", "mount", "--camera", cam, "--out", cam,
                     hostile_files["images"], cls="outputs: bad names and inputs")
    assert rc == 2 and "--out is the same file as --camera" in err
    assert _digest(cam) == before


def test_calibrate_mount_offset_is_bounded_like_the_mount_file(cli, hostile_files, tmp_path):
    """One bound: what `calibrate mount` would write, `run --mount` reads."""
    from drovisio.bounds import MOUNT_OFFSET_MAX_M
    from drovisio.mount import Mount, MountError, body_from_camera_angles, load_mount

    rc, _, err = cli("calibrate", "mount", "--camera", hostile_files["camera"], "--offset",
                     "11", "0", "0", "--out", tmp_path / "m.json", hostile_files["images"],
                     cls="outputs: bad names and inputs")
    assert rc == 2 and "--offset" in err and f"{MOUNT_OFFSET_MAX_M:g} m" in err
    assert not (tmp_path / "m.json").exists()
    # the reader holds the same bound
    p = tmp_path / "far.json"
    p.write_text(json.dumps(Mount(body_from_camera_angles(20, 0, 0, (0, 0, 0))).to_file())
                 .replace('"offset_m": [0.0, 0.0, 0.0]', '"offset_m": [11.0, 0.0, 0.0]'))
    with pytest.raises(MountError, match="larger than 10 m"):
        load_mount(p)


# ------------------------------------------------------------------ full disk, read-only


def _figure_writers(tmp: Path):
    from drovisio.study.figures import fps_figure, memory_figure
    from drovisio.study.methods import METHODS

    m = next(iter(METHODS))
    speed = [{"method": m, "layout": "code", "bricks": b, "fps": 30.0 / b} for b in (1, 2, 4)]
    yield "fig-6.10.png", lambda: fps_figure(speed, METHODS, tmp / "fig-6.10.png")
    memory = {m: [(t, 100.0 + t) for t in range(5)]}
    yield "fig-6.11.png", lambda: memory_figure(memory, METHODS, tmp / "fig-6.11.png")


def _all_writers(tmp: Path):
    """(file written, how to write it) for every kind of artefact."""
    from drovisio.fileio import atomic_write_text, write_image, write_video

    yield from _figure_writers(tmp)
    frames = [np.full((48, 64, 3), 40 * k, np.uint8) for k in range(5)]
    yield "v.mp4", lambda: write_video(tmp / "v.mp4", frames, 10.0, (64, 48))
    yield "i.jpg", lambda: write_image(tmp / "i.jpg", frames[2])
    yield "s.json", lambda: atomic_write_text(tmp / "s.json", '{"a": 1}\n')

    def recording():
        from drovisio.mission.record import write_recording
        from drovisio.mission.scenario import load_scenario, shipped_scenario
        from drovisio.mission.sim import SimParams, simulate

        scn = load_scenario(shipped_scenario()).subset(["b1"])
        write_recording(simulate(scn, params=SimParams(seed=1)), tmp / "rec", every=4)

    yield "rec/manifest.json", recording


@pytest.mark.parametrize("case", ["fig-6.10.png", "fig-6.11.png", "v.mp4", "i.jpg", "s.json",
                                  "rec/manifest.json"])
def test_a_full_disk_keeps_every_old_artefact(tmp_path, monkeypatch, ledger, case):
    import drovisio.fileio as fileio

    write = dict(_all_writers(tmp_path))[case]
    write()                                   # the old artefact, written whole
    files = sorted(p for p in tmp_path.rglob("*") if p.is_file())
    before = {p: _digest(p) for p in files}
    assert before and all(p.stat().st_size > 0 for p in files)

    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(fileio.os, "fsync", no_space)
    ledger.tried_one("outputs: full disk")
    with pytest.raises(WriteError, match="disk is full"):
        write()
    after = {p: _digest(p) for p in sorted(p for p in tmp_path.rglob("*") if p.is_file())}
    if after != before:
        ledger.failure("data losses")
    assert after == before, "an old artefact was changed by a write that failed"


@pytest.mark.parametrize("case", ["fig-6.10.png", "v.mp4", "i.jpg", "s.json",
                                  "rec/manifest.json"])
def test_a_read_only_folder_keeps_every_old_artefact(tmp_path, monkeypatch, ledger, case):
    """A read-only file system (EROFS where the writer makes its file beside the target;
    simulated: the tests may run as root, whom chmod does not stop)."""
    import drovisio.fileio as fileio

    write = dict(_all_writers(tmp_path))[case]
    write()
    files = sorted(p for p in tmp_path.rglob("*") if p.is_file())
    before = {p: _digest(p) for p in files}

    def read_only(*a, **kw):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(fileio.tempfile, "mkstemp", read_only)
    ledger.tried_one("outputs: read-only folder")
    with pytest.raises(WriteError, match="not allowed"):
        write()
    assert {p: _digest(p) for p in files} == before


def test_study_example_on_a_full_disk_keeps_the_old_videos(cli, tmp_path, monkeypatch,
                                                           ledger):
    import drovisio.fileio as fileio

    rc, _, err = cli("study", "example", "--out", tmp_path, "--frames", "1",
                     cls="outputs: full disk")
    assert rc == 0, err
    videos = sorted(tmp_path.glob("*.mp4"))
    assert videos
    before = {p: _digest(p) for p in videos}

    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(fileio.os, "fsync", no_space)
    rc, _, err = cli("study", "example", "--out", tmp_path, "--frames", "1",
                     cls="outputs: full disk")
    assert rc == 2 and "disk is full" in err and "Traceback" not in err
    assert {p: _digest(p) for p in videos} == before
