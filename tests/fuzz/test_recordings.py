"""Class: writers that stream (recordings) and the crash report.

* ``--record DIR`` that already holds a recording, or ``--record FILE.mcap`` that exists, is
  refused at start-up in one line (exit 2) and nothing in it changes.
* A :class:`~drovisio.recording.Recorder` that meets an existing recording (the web tool's
  pipeline restarted on the same ``--record``) continues it: no file already there is
  replaced, new frames are numbered after the old ones, the index only grows.
* An MCAP recorder never truncates an existing file: it writes the next free ``STEM-N.mcap``.
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


def _record(folder: Path, levels: list[int], seq0: int = 0) -> Recorder:
    rec = Recorder(folder, source="test", camera_file=CAMERA)
    for i, v in enumerate(levels):
        frame = SimpleNamespace(image=np.full((24, 32, 3), v, np.uint8), index=i,
                                seq=seq0 + i, t_wall=1000.0 + i)
        rec.add(frame, _Out(i))
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
    rec.close()
    assert old.read_bytes() == b"an older flight" * 10
    assert rec.path == tmp_path / "flight-2.mcap" and rec.path.stat().st_size > 0


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
def test_a_broken_bench_cache_entry_is_a_miss_not_a_crash(tmp_path, meta, ledger):
    """bench dots' cache: an entry half written by an older version or a killed run (its
    JSON broken) is rendered again; a sound entry is read back as written."""
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


def test_a_stale_bench_aruco_cache_file_is_rendered_again_and_replaced_whole(tmp_path,
                                                                            ledger):
    """bench aruco's cache: a pickle of a class that no longer exists (or a cut file) is a
    miss; the fresh frame is written beside and renamed (no half pickle is ever left)."""
    import pickle

    from drovisio.bench.aruco import _frames
    from drovisio.layout import load_layout
    from drovisio.resources import layouts_dir

    ledger.tried_one("writers: bench cache")
    lay = load_layout(layouts_dir() / "drick-aruco-centre.json")
    seed = 0 + 100_000 * 2 + 0
    path = tmp_path / f"t-{lay.name}-b1-s{seed}-ss1.pkl"
    from collections import OrderedDict

    # a pickle of a class whose module is gone (same length: the opcodes stay valid)
    path.write_bytes(pickle.dumps(OrderedDict()).replace(b"collections", b"no_such_mod"))
    with pytest.raises(ImportError):
        pickle.loads(path.read_bytes())
    fr = next(_frames("t", 1, 1, 0, [lay], 1, tmp_path))
    again = pickle.loads(path.read_bytes())
    assert np.array_equal(again.image, fr.image) and again.image.ndim == 3
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left beside
