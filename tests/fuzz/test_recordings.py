"""Class: writers that stream (recordings) and the crash report.

* ``--record DIR`` that already holds a recording, or ``--record FILE.mcap`` that exists, is
  refused at start-up in one line (exit 2) and nothing in it changes.
* A :class:`~drovisio.recording.Recorder` that meets an existing recording (the web tool's
  pipeline restarted on the same ``--record``) continues it: no file already there is
  replaced, new frames are numbered after the old ones, the index only grows.
* An MCAP recorder never truncates an existing file: it writes the next free ``STEM-N.mcap``.
* A recording a run made that got no frame (a source whose only frame cannot be decoded, a
  stream that never delivered) is removed at close, said in one line: the next run may record
  to the same ``--record``. Only what the recorder made goes: a folder that was there stays,
  with what else is in it; a file replaced meanwhile stays too.
* The crash report is created exclusively (a symlink planted at its name in a shared /tmp is
  not followed) and readable by its owner only.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from drovisio.recording import Recorder, holds_recording, read_index

REPO = Path(__file__).resolve().parents[2]
CAMERA = REPO / "sample_sessions" / "camera.yaml"
LAYOUT = REPO / "marker_layouts" / "drick-aruco-centre.json"
VIDEO = REPO / "sample_sessions" / "approach" / "approach.mp4"


def _digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


class _Out:
    def __init__(self, k: int):
        self.k = k

    def to_json(self) -> dict:
        return {"frame": self.k, "bricks": []}


class _McapOut(_Out):
    """An output as the MCAP recorder reads it (its time, bricks and target)."""

    def __init__(self, k: int = 0):
        super().__init__(k)
        self.t, self.bricks, self.target, self.detections = 1000.0 + k, [], None, []


def _frame(i: int, v: int, seq0: int = 0) -> SimpleNamespace:
    return SimpleNamespace(image=np.full((24, 32, 3), v, np.uint8), index=i, seq=seq0 + i,
                           t_wall=1000.0 + i)


def _record(folder: Path, levels: list[int], seq0: int = 0) -> Recorder:
    rec = Recorder(folder, source="test", camera_file=CAMERA)
    for i, v in enumerate(levels):
        rec.add(_frame(i, v, seq0), _Out(i))
    rec.close()
    return rec


def test_a_restarted_recorder_continues_and_replaces_nothing(tmp_path, ledger):
    ledger.tried_one("writers: recording folder")
    folder = tmp_path / "rec"
    first = _record(folder, [10, 60, 110])
    assert first.written == 3 and not first.continued
    before = _digests(folder)
    manifest = json.loads((folder / "recording.json").read_text())
    # the pipeline restarts: its frame counter (seq) starts at 0 again
    second = _record(folder, [200, 250])
    assert second.written == 2 and second.continued and second.errors == 0
    after = _digests(folder)
    for name, digest in before.items():
        if name != "frames.jsonl":  # the index is appended to, the rest stays as it was
            assert after[name] == digest, name
    assert (folder / "frames.jsonl").read_bytes().startswith(
        b"".join(ln + b"\n" for ln in
                 (folder / "frames.jsonl").read_bytes().splitlines()[:3]))
    assert json.loads((folder / "recording.json").read_text()) == manifest
    index = read_index(folder)
    assert [e.image for e in index] == [f"frames/{k:06d}.jpg" for k in range(5)]
    # each indexed picture is the one that was recorded (JPEG: within a few grey levels)
    import cv2

    levels = [int(cv2.imread(str(folder / e.image))[5, 5, 0]) for e in index]
    assert np.allclose(levels, [10, 60, 110, 200, 250], atol=3)


def test_run_refuses_a_folder_or_file_that_holds_a_recording(tmp_path, ledger):
    folder = tmp_path / "rec"
    _record(folder, [10, 60])
    assert holds_recording(folder) and not holds_recording(tmp_path / "new")
    mcap = tmp_path / "old.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n" + bytes(100))
    before = _digests(tmp_path)
    for target in (folder, mcap):
        ledger.tried_one("writers: recording folder")
        r = subprocess.run([sys.executable, "-m", "drovisio", "run", "--source", str(VIDEO),
                            "--camera", str(CAMERA), "--layout", str(LAYOUT), "--sink",
                            "jsonl:-", "--frames", "3", "--quiet", "--record", str(target)],
                           capture_output=True, text=True, timeout=120, cwd=REPO)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "--record" in lines[0] and str(target) in lines[0]
        assert "never written over" in lines[0] and "Traceback" not in r.stderr
    assert _digests(tmp_path) == before


def test_an_mcap_recorder_never_truncates_an_existing_file(tmp_path, ledger):
    ledger.tried_one("writers: recording folder")
    pytest.importorskip("mcap")
    from drovisio.camera_file import load_camera
    from drovisio.ros.mcap_recorder import McapRecorder
    from drovisio.ros.messages import RosMessages

    old = tmp_path / "flight.mcap"
    old.write_bytes(b"an older flight" * 10)
    rec = McapRecorder(old, RosMessages(load_camera(CAMERA), None, []))
    rec.add(_frame(0, 10), _McapOut())
    rec.close()
    assert old.read_bytes() == b"an older flight" * 10
    assert rec.path == tmp_path / "flight-2.mcap" and rec.path.stat().st_size > 0
    assert rec.written == 1 and rec.status()["removed"] is None
    # one that got no frame is removed again; the older file is still not touched
    empty = McapRecorder(old, RosMessages(load_camera(CAMERA), None, []))
    assert empty.path == tmp_path / "flight-3.mcap" and empty.path.exists()
    empty.close()
    assert empty.status()["removed"] is True and not empty.path.exists()
    assert old.read_bytes() == b"an older flight" * 10 and rec.path.stat().st_size > 0


def test_the_crash_report_does_not_follow_a_planted_symlink(tmp_path, monkeypatch, ledger):
    ledger.tried_one("writers: crash report")
    import tempfile
    import time

    from drovisio import cli

    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(time, "strftime", lambda *_: "20260101-000000")
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    name = f"drovisio-detect-20260101-000000-{os.getpid()}.txt"
    (tmp_path / name).symlink_to(victim)
    try:
        raise RuntimeError("boom")
    except RuntimeError as e:
        assert cli._crash_report("detect", e) is None  # the name is taken: not written
    assert victim.read_text() == "keep me"
    (tmp_path / name).unlink()
    try:
        raise RuntimeError("boom")
    except RuntimeError as e:
        path = cli._crash_report("detect", e)
    assert path == str(tmp_path / name)
    text = Path(path).read_text()
    assert "RuntimeError: boom" in text and text.startswith("drovisio ")
    assert (Path(path).stat().st_mode & 0o777) == 0o600


@pytest.mark.parametrize("meta", ["", "{", "[]", '{"gravity": [0, 0, 1]}',
                                  '{"gravity": "x", "bricks": [{"nope": 1}]}'])
def test_a_broken_bench_cache_entry_is_a_miss_not_a_crash(tmp_path, meta, ledger, capsys):
    """bench dots' cache: an entry half written by an older version or a killed run (its
    JSON broken) is rendered again, said once in one line naming it; a sound entry is read
    back as written."""
    import cv2

    from drovisio.bench.dots import FrameSource
    from drovisio.layout import load_layout
    from drovisio.resources import layouts_dir

    ledger.tried_one("writers: bench cache")
    src = FrameSource(load_layout(layouts_dir() / "drick-dots-2x3.json"), tmp_path)
    png, js = tmp_path / "k-1-t.png", tmp_path / "k-1-t.json"
    cv2.imwrite(str(png), np.full((8, 8, 3), 7, np.uint8))
    js.write_text(meta)
    hit, p, j = src._cached("k", 1, "t")
    assert hit is None and (p, j) == (png, js)
    said = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(said) == 1 and said[0].startswith("bench dots --cache: ")
    assert str(js) in said[0] and "rendering the frame again" in said[0]
    assert src._cached("k", 1, "t")[0] is None and not capsys.readouterr().err   # once
    js.write_text(json.dumps({"gravity": [0.0, 0.0, 1.0], "bricks": []}))
    hit, _, _ = src._cached("k", 1, "t")
    assert hit is not None and hit.image.shape == (8, 8, 3) and int(hit.image[0, 0, 0]) == 7
    assert hit.gravity.tolist() == [0.0, 0.0, 1.0]


def test_a_bench_cache_picture_is_read_within_the_image_bounds(tmp_path, monkeypatch, ledger):
    """bench dots' cache folder is the user's: its pictures go through the image reader (its
    pixel cap, never a pipe opened); an entry it refuses is a miss, rendered again."""
    import cv2

    from drovisio.bench.dots import FrameSource
    from drovisio.errors import LIMITS
    from drovisio.layout import load_layout
    from drovisio.resources import layouts_dir

    ledger.tried["writers: bench cache"] += 2
    src = FrameSource(load_layout(layouts_dir() / "drick-dots-2x3.json"), tmp_path)
    png, js = tmp_path / "k-1-t.png", tmp_path / "k-1-t.json"
    js.write_text(json.dumps({"gravity": [0.0, 0.0, 1.0], "bricks": []}))
    cv2.imwrite(str(png), np.full((48, 64, 3), 7, np.uint8))
    assert src._cached("k", 1, "t")[0] is not None
    monkeypatch.setattr(LIMITS, "max_image_pixels", 1000)     # 64x48 is over it now
    assert src._cached("k", 1, "t")[0] is None
    monkeypatch.undo()
    png.unlink()
    os.mkfifo(png)     # opening it would wait for a writer forever
    assert src._cached("k", 1, "t")[0] is None


def _aruco_frames(tmp_path, capsys):
    """bench aruco's one frame of one brick, from its cache in ``tmp_path``: (frame, files
    of the entry, what was said on stderr)."""
    from drovisio.bench.aruco import _frames
    from drovisio.layout import load_layout
    from drovisio.resources import layouts_dir

    lay = load_layout(layouts_dir() / "drick-aruco-centre.json")
    fr = next(_frames("t", 1, 1, 0, [lay], 1, tmp_path))
    stem = tmp_path / f"t-{lay.name}-b1-s{100_000 * 2}-ss1"
    return fr, (Path(f"{stem}.png"), Path(f"{stem}.json"), Path(f"{stem}.pkl")), \
        capsys.readouterr().err


def test_a_bench_aruco_cache_entry_reads_back_the_frame_it_wrote(tmp_path, capsys, ledger):
    """bench aruco's cache: a picture (PNG) and its truth (JSON) that read back exactly."""
    ledger.tried_one("writers: bench cache")
    fr, (png, js, _), err = _aruco_frames(tmp_path, capsys)
    assert err == "" and sorted(p.name for p in tmp_path.iterdir()) == [js.name, png.name]
    before = {p: p.read_bytes() for p in (png, js)}
    again, _, err = _aruco_frames(tmp_path, capsys)
    assert err == "" and {p: p.read_bytes() for p in (png, js)} == before   # read, not made
    assert np.array_equal(again.image, fr.image) and again.image.dtype == np.uint8
    assert np.array_equal(again.gravity, fr.gravity) and again.blur == fr.blur
    assert again.visible == fr.visible and len(again.bricks) == len(fr.bricks) == 1
    a, b = again.bricks[0], fr.bricks[0]
    assert (a.layout, a.instance, a.code_ids) == (b.layout, b.instance, b.code_ids)
    assert np.array_equal(a.camera_from_brick, b.camera_from_brick)
    assert np.array_equal(a.dot_centers_px, b.dot_centers_px) and a.dot_centers_px.shape[1] == 2
    assert a.code_corners_px.keys() == b.code_corners_px.keys()
    assert all(np.array_equal(a.code_corners_px[k], b.code_corners_px[k])
               for k in a.code_corners_px)


class _Planted:
    """A pickle that writes a file when loaded (what anyone who can write to the cache
    folder could plant in the old format)."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


def test_an_old_pickle_in_the_bench_aruco_cache_is_never_loaded(tmp_path, capsys, ledger):
    import pickle

    ledger.tried_one("writers: bench cache")
    _, (png, js, pkl), _ = _aruco_frames(tmp_path / "ref", capsys)   # the entry's name
    pkl = tmp_path / pkl.name
    planted = tmp_path / "ran"
    pkl.write_bytes(pickle.dumps(_Planted(planted)))
    fr, (png, js, _), err = _aruco_frames(tmp_path, capsys)
    assert err == (f"bench aruco --cache: {pkl}: a cache entry of an older version (a pickle: "
                   "never read, loading one can run code); rendering the frame again (and "
                   "any other stale entry)\n")
    assert not planted.exists() and png.is_file() and js.is_file()
    assert pickle.dumps(_Planted(planted)) == pkl.read_bytes()      # left as it was


@pytest.mark.parametrize("case", ["schema", "truth", "nan", "picture", "size", "huge"])
def test_an_unknown_bench_aruco_cache_entry_is_stale_and_rendered_again(tmp_path, capsys,
                                                                        case, ledger):
    import cv2

    from drovisio.bench.aruco import CACHE_SCHEMA

    ledger.tried_one("writers: bench cache")
    fr, (png, js, _), _ = _aruco_frames(tmp_path, capsys)
    truth = json.loads(js.read_text())
    why = {"schema": f"{js}: not a {CACHE_SCHEMA} entry",
           "truth": f"{js}: not a {CACHE_SCHEMA} entry",
           "nan": f"{js}: a number that is not finite",
           "picture": f"{png}: cannot be read as an image (corrupt, truncated or not an image)",
           "size": f"{js}: its picture is not 640x480",
           "huge": f"{js}: the bench cache entry is larger than 16384 KiB; is it the right "
                   "file?"}[case]
    if case == "schema":
        truth["schema"] = "drovisio/bench-aruco-frame@0"
    elif case == "truth":
        del truth["bricks"][0]["code_ids"]
    elif case == "nan":
        truth["gravity"] = "G"
    elif case == "picture":
        png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)
    elif case == "size":
        cv2.imwrite(str(png), fr.image[:240, :320])
    if case == "huge":
        with open(js, "wb") as f:
            f.truncate(2**34)    # sparse: 16 GiB, refused from its size
    elif case not in ("picture", "size"):
        js.write_text(json.dumps(truth).replace('"G"', "[0, 0, 1e999]"))   # 1e999: inf
    again, _, err = _aruco_frames(tmp_path, capsys)
    assert err == (f"bench aruco --cache: {why}; rendering the frame again (and any other "
                   "stale entry)\n"), err
    assert np.array_equal(again.image, fr.image)                   # rendered again ...
    assert json.loads(js.read_text())["schema"] == CACHE_SCHEMA    # ... and replaced whole
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([png.name, js.name])

# ------------------------------------------------------------------ a recording with no frame


@pytest.fixture(scope="module")
def undecodable(tmp_path_factory) -> Path:
    """A folder of images whose only image cannot be decoded: the run gets no frame."""
    import cv2

    d = tmp_path_factory.mktemp("undecodable")
    ok, png = cv2.imencode(".png", np.full((480, 640, 3), 90, np.uint8))
    (d / "f0.png").write_bytes(png.tobytes()[: len(png) // 2])
    return d


def _run(capsys, source: Path, record: Path, *extra: str) -> tuple[int, list[str]]:
    from drovisio.cli import main

    rc = main(["run", "--source", str(source), "--camera", str(CAMERA), "--layout",
               str(LAYOUT), "--sink", "jsonl:" + os.devnull, "--quiet", "--pace", "max",
               "--record", str(record), *extra])
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "Traceback" not in out
    return rc, err.splitlines()


def _removed_lines(err: list[str]) -> list[str]:
    return [ln for ln in err if "no frame was recorded" in ln]


def _mcap_images(path: Path) -> int:
    from drovisio.ros.mcap_source import iter_images

    return sum(1 for _ in iter_images(path))


@pytest.mark.parametrize("name", ["rec", "x.mcap", "new/deeper/rec", "new/deeper/x.mcap"])
def test_a_run_that_got_no_frame_leaves_no_recording_and_the_next_one_records(
        tmp_path, capsys, undecodable, name, ledger):
    ledger.tried_one("writers: recording folder")
    target = tmp_path / name
    rc, err = _run(capsys, undecodable, target)
    # a finite source none of whose frames decoded: nothing could be read (exit 1)
    assert rc == 1 and f"drovisio run: {undecodable}: nothing could be read from the source " \
        "(no frame of it decoded)" in err, err
    assert _removed_lines(err) == [f"drovisio run: {target}: no frame was recorded; the empty "
                                   "recording was removed"], err
    assert not target.exists() and not (tmp_path / "new").exists()   # its folders too
    assert sorted(tmp_path.iterdir()) == []
    # the same --record again, with a source that gives frames: recorded, said nothing
    rc, err = _run(capsys, VIDEO, target, "--frames", "3")
    assert rc == 0 and _removed_lines(err) == [], err
    if target.suffix == ".mcap":
        assert _mcap_images(target) == 3
    else:
        assert len(read_index(target)) == 3
        assert len(list((target / "frames").iterdir())) == 3


def test_a_folder_that_was_there_stays_with_what_else_is_in_it(tmp_path, capsys, undecodable,
                                                               ledger):
    ledger.tried_one("writers: recording folder")
    empty, kept = tmp_path / "empty", tmp_path / "kept"
    empty.mkdir()
    (kept / "frames").mkdir(parents=True)            # an empty frames/ holds no recording
    (kept / "notes.txt").write_text("the pilot's notes")
    for folder in (empty, kept):
        rc, err = _run(capsys, undecodable, folder)
        assert _removed_lines(err) == [f"drovisio run: {folder}: no frame was recorded; the "
                                       "empty recording was removed"], err
    assert empty.is_dir() and list(empty.iterdir()) == []
    assert sorted(p.name for p in kept.iterdir()) == ["frames", "notes.txt"]
    assert list((kept / "frames").iterdir()) == []
    assert (kept / "notes.txt").read_text() == "the pilot's notes"


def test_a_recording_with_frames_is_kept_as_written(tmp_path, ledger):
    ledger.tried_one("writers: recording folder")
    rec = _record(tmp_path / "rec", [10, 60])
    assert rec.written == 2 and rec.status()["removed"] is None
    assert sorted(_digests(tmp_path / "rec")) == ["camera.yaml", "frames.jsonl",
                                                  "frames/000000.jpg", "frames/000001.jpg",
                                                  "recording.json"]
    # continued (the web tool's pipeline restarted) and closed without a frame: not its own
    before = _digests(tmp_path / "rec")
    again = _record(tmp_path / "rec", [])
    assert again.continued and again.status()["removed"] is None
    assert _digests(tmp_path / "rec") == before


def test_a_file_replaced_meanwhile_is_not_removed(tmp_path, ledger):
    from drovisio.recording import removed_line

    ledger.tried_one("writers: recording folder")
    folder = tmp_path / "rec"
    rec = Recorder(folder, source="test", camera_file=CAMERA)
    (tmp_path / "other.json").write_text("someone else's")
    os.replace(tmp_path / "other.json", folder / "recording.json")   # another file, same name
    rec.close()
    assert rec.status()["removed"] is False
    assert sorted(p.name for p in folder.iterdir()) == ["recording.json"]
    assert (folder / "recording.json").read_text() == "someone else's"
    line = removed_line(rec.status())
    assert line is not None and line.startswith(f"{folder}: no frame was recorded; ")
    assert "remove it by hand" in line


class _Full:
    """A frame file that the disk fills halfway through."""

    def __init__(self, fh):
        self.fh = fh

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.fh.close()

    def fileno(self):
        return self.fh.fileno()

    def write(self, data):
        import errno

        self.fh.write(data[: len(data) // 2])
        self.fh.flush()
        raise OSError(errno.ENOSPC, "No space left on device")


def _disk_full_once(monkeypatch) -> list[str]:
    """The recorder's first frame file meets a full disk; returns the list of its name."""
    import builtins

    import drovisio.recording as recording

    real_open = builtins.open
    failed: list[str] = []

    def full_once(path, mode="r", *a, **kw):
        fh = real_open(path, mode, *a, **kw)
        if mode == "xb" and not failed:
            failed.append(str(path))
            return _Full(fh)
        return fh

    monkeypatch.setattr(recording, "open", full_once, raising=False)
    return failed


def test_a_frame_cut_short_by_a_full_disk_costs_that_frame_only(tmp_path, monkeypatch, ledger):
    """The disk is full for one frame: its file is made, the write fails. That frame is lost
    (counted, its part removed), and the frames after it are recorded under the next names;
    the name it had is not tried again for ever."""
    ledger.tried_one("writers: recording folder")
    failed = _disk_full_once(monkeypatch)
    folder = tmp_path / "rec"
    rec = _record(folder, [10, 60, 110])
    assert rec.errors == 1 and rec.written == 2 and "No space" in rec.last_error
    frames = read_index(folder)
    assert [f.frame for f in frames] == [1, 2]
    names = sorted(p.name for p in (folder / "frames").iterdir())
    assert names == [Path(f.image).name for f in frames]      # the cut frame is not left
    assert Path(failed[0]).name not in names


def test_run_says_frames_it_could_not_record_and_fails(tmp_path, monkeypatch, capsys, ledger):
    """A recording that could not write a frame is a failing output: said at the end in one
    line, exit status 1, as a failing sink."""
    ledger.tried_one("writers: recording folder")
    _disk_full_once(monkeypatch)
    target = tmp_path / "rec"
    rc, err = _run(capsys, VIDEO, target, "--frames", "3")
    said = [ln for ln in err if "could not be recorded" in ln]
    assert rc == 1 and said == [f"drovisio run: {target}: 1 frames could not be recorded (2 "
                                "were) (last: [Errno 28] No space left on device)"], err
    assert len(read_index(target)) == 2


def test_a_recording_another_recorder_wrote_to_is_not_removed(tmp_path, ledger):
    """Two runs on one --record folder: the first made it and got no frame, the second wrote
    three frames into it. The first's close removes nothing: the index, the manifest and the
    frames stay and play back."""
    ledger.tried_one("writers: recording folder")
    folder = tmp_path / "rec"
    first = Recorder(folder, source="test", camera_file=CAMERA)
    second = Recorder(folder, source="test", camera_file=CAMERA)
    assert second.continued
    for i, v in enumerate([10, 60, 110]):
        second.add(_frame(i, v), _Out(i))
    second.close()
    first.close()
    assert first.written == 0 and first.status()["removed"] is None
    assert (folder / "recording.json").is_file() and len(read_index(folder)) == 3


def test_a_jsonl_file_shared_with_another_writer_keeps_every_line(tmp_path):
    """Two sinks on one jsonl:PATH: the one that got no line closes first; the other's lines
    all stay in the file (a sink never removes a file)."""
    from drovisio.sinks.jsonl import JsonlSink

    class _Line(_Out):
        def to_json(self, with_covariance: bool = True) -> dict:
            return {"frame": self.k}

    path = tmp_path / "log.jsonl"
    idle = JsonlSink(str(path))
    busy = JsonlSink(str(path))
    idle.close()                 # closes before the other writer's first line
    busy.send(_Line(0))
    busy.send(_Line(1))
    busy.close()
    lines = [json.loads(ln) for ln in path.read_text().splitlines()]
    assert [ln["frame"] for ln in lines] == [0, 1]
    # a sink that never got a line made no file
    never = JsonlSink(str(tmp_path / "new" / "never.jsonl"))
    never.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.jsonl"]


def test_an_index_line_cut_short_is_cut_off_and_the_recording_still_plays(tmp_path, ledger):
    """The disk fills during one frame's index line: half of it is written. The half line is
    cut off at once (else the next line is glued to it and the index cannot be read past
    it), that frame's image goes with it, and the frames after it are recorded and play."""
    ledger.tried_one("writers: recording folder")
    folder = tmp_path / "rec"
    rec = Recorder(folder, source="test", camera_file=CAMERA)
    real = rec._index
    calls = []

    class _HalfOnce:
        def write(self, data):
            calls.append(len(data))
            if len(calls) == 2:
                return real.write(data[: len(data) // 2])
            return real.write(data)

        def __getattr__(self, name):
            return getattr(real, name)

    rec._index = _HalfOnce()
    for i, v in enumerate([10, 60, 110]):
        rec.add(_frame(i, v), _Out(i))
    rec.close()
    assert rec.written == 2 and rec.errors == 1 and "cut short" in rec.last_error
    frames = read_index(folder)
    assert [f.frame for f in frames] == [0, 2]
    assert sorted(p.name for p in (folder / "frames").iterdir()) == \
        sorted(Path(f.image).name for f in frames)
