"""A recording folder played as ``--source``: its index is read once, bounded and checked in
one place (:func:`drovisio.recording.read_index`); a bad line is one line naming the file,
the line and the field, and the run ends at once (exit 2), never hangs as a lost source."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio import recording
from drovisio.cli import main
from drovisio.errors import InputError
from drovisio.recording import RecordedFrame, read_index
from drovisio.sources import FrameSource, RecordingReader, SourceState

REPO = Path(__file__).resolve().parents[2]
CAMERA = REPO / "sample_sessions" / "camera.yaml"
LAYOUT = REPO / "marker_layouts" / "drick-aruco-centre.json"


def _recording(folder: Path, lines: list[str] | bytes, frames: int = 2) -> Path:
    (folder / "frames").mkdir(parents=True)
    (folder / "recording.json").write_text(json.dumps({"schema": "drovisio/recording@1"}))
    for k in range(frames):
        cv2.imwrite(str(folder / "frames" / f"{k:06d}.jpg"), np.zeros((480, 640, 3), np.uint8))
    data = lines if isinstance(lines, bytes) else "".join(ln + "\n" for ln in lines).encode()
    (folder / "frames.jsonl").write_bytes(data)
    return folder


def _line(**fields) -> str:
    e = {"frame": 0, "seq": 0, "t": 1000.0, "image": "frames/000000.jpg", "output": {}}
    e.update(fields)
    return json.dumps(e)


@pytest.mark.parametrize("line,words", [
    (_line(frame="x"), "line 1: frame: 'x' is not a whole number"),
    (_line(t="abc"), "line 1: t: 'abc' is not a number"),
    (_line(t=float("nan")), "line 1: t: nan is not a finite number"),
    (_line(t=1e308), "line 1: t: 1e+308 is out of range: give a number from 0 to 1e+10 s"),
    (_line(t=-1e308), "line 1: t: -1e+308 is out of range"),
    (_line(image=5), "line 1: image: give the frame image's name as text"),
    (_line(image="/etc/passwd"), "line 1: image: '/etc/passwd' is an absolute path"),
    (_line(image="../../img/full.png"), "line 1: image: '../../img/full.png' is outside the "
                                        "folder"),
    ('"image and t"', 'line 1: expected an object with "frame", "t" and "image"'),
    ("[" * 100_000 + "]" * 100_000, "line 1: nested too deeply to be a Drovisio file"),
])
def test_a_bad_index_line_is_named_by_file_line_and_field(tmp_path, line, words):
    rec = _recording(tmp_path / "rec", [line])
    with pytest.raises(InputError) as e:
        read_index(rec)
    assert str(e.value).startswith(f"{rec / 'frames.jsonl'}, ") and words in str(e.value)
    assert "\n" not in str(e.value)


def test_an_index_that_is_not_utf8_is_one_line(tmp_path):
    rec = _recording(tmp_path / "rec", b"\xff\xfe garbage\n")
    with pytest.raises(InputError, match=r"frames.jsonl, line 1: not UTF-8 text"):
        read_index(rec)


def test_the_index_is_bounded(tmp_path, monkeypatch):
    rec = _recording(tmp_path / "rec", [_line(frame=k) for k in range(4)])
    monkeypatch.setattr(recording, "MAX_FRAMES", 3)
    with pytest.raises(InputError) as e:
        read_index(rec)
    assert str(e.value) == f"{rec / 'frames.jsonl'}: more than 3 frames; split the recording"
    monkeypatch.setattr(recording, "MAX_FRAMES", 10)
    monkeypatch.setattr(recording, "MAX_LINE_BYTES", 100)
    long = _recording(tmp_path / "long", [_line(output={"x": "y" * 200})])
    with pytest.raises(InputError, match=r"line 1: longer than"):
        read_index(long)
    monkeypatch.setattr(recording, "MAX_INDEX_BYTES", 10)
    with pytest.raises(InputError, match=r"more than a recording's index may be"):
        read_index(rec)


def test_a_last_line_cut_by_a_crash_is_left_out(tmp_path):
    data = (_line() + "\n" + _line(frame=1)[:20]).encode()
    rec = _recording(tmp_path / "rec", data)
    assert read_index(rec) == [RecordedFrame(0, 1000.0, "frames/000000.jpg")]


def test_a_recording_continued_after_a_crash_drops_the_cut_line(tmp_path):
    from types import SimpleNamespace

    data = (_line() + "\n" + _line(frame=1)[:20]).encode()
    rec = _recording(tmp_path / "rec", data)
    r = recording.Recorder(rec)
    r.add(SimpleNamespace(image=np.zeros((48, 64, 3), np.uint8), index=7, seq=7,
                          t_wall=1001.0), SimpleNamespace(to_json=lambda: {}))
    r.close()
    frames = read_index(rec)
    assert [f.frame for f in frames] == [0, 7], frames   # the new entry not glued to the cut
    assert (rec / "frames.jsonl").read_bytes().startswith((_line() + "\n").encode())


def test_a_line_of_exactly_the_limit_is_read(tmp_path, monkeypatch):
    line = _line()
    monkeypatch.setattr(recording, "MAX_LINE_BYTES", len(line))
    assert len(read_index(_recording(tmp_path / "rec", [line]))) == 1


def test_a_picture_linked_out_of_the_folder_is_an_error_frame(tmp_path):
    outside = tmp_path / "secret.jpg"
    cv2.imwrite(str(outside), np.zeros((48, 64, 3), np.uint8))
    rec = _recording(tmp_path / "rec", [_line(image="frames/link.jpg")])
    (rec / "frames" / "link.jpg").symlink_to(outside)
    reader = RecordingReader(rec)
    reader.open()
    raw = reader.read()
    assert raw.image is None and "is outside the folder" in raw.error


def test_a_recording_whose_reader_fails_while_read_ends(tmp_path, monkeypatch):
    rec = _recording(tmp_path / "rec", [_line(frame=k, t=1000.0 + k) for k in range(2)])
    reader = RecordingReader(rec)

    def broken(_self):
        raise InputError("the disk went away")

    monkeypatch.setattr(RecordingReader, "read", broken)
    src = FrameSource(reader, pace="max").start()
    assert src.get(5.0) is None
    src.stop()
    assert src.state == SourceState.FAILED and src.status().error == "the disk went away"


def test_run_refuses_a_bad_recording_at_once_and_reads_its_index_once(tmp_path, capsys,
                                                                      monkeypatch):
    bad = _recording(tmp_path / "bad", [_line(frame=0), _line(frame="x")])
    rc = main(["run", "--source", str(bad), "--camera", str(CAMERA), "--layout", str(LAYOUT),
               "--sink", f"jsonl:{tmp_path / 'out.jsonl'}", "--quiet", "--pace", "max"])
    err = capsys.readouterr().err
    assert rc == 2 and err == (f"drovisio run: {bad / 'frames.jsonl'}, line 2: frame: 'x' is "
                               "not a whole number\n")
    good = _recording(tmp_path / "good", [_line(frame=k, t=1000.0 + k / 10) for k in range(2)])
    reads = []
    real = recording.read_index
    monkeypatch.setattr(recording, "read_index", lambda f: reads.append(f) or real(f))
    out = tmp_path / "good.jsonl"
    rc = main(["run", "--source", str(good), "--camera", str(CAMERA), "--layout",
               str(LAYOUT), "--sink", f"jsonl:{out}", "--quiet", "--pace", "max"])
    capsys.readouterr()
    assert rc == 0 and len(reads) == 1
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert [x["frame"] for x in lines] == [0, 1]
