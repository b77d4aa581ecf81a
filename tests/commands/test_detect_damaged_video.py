"""``drovisio detect`` on a cut-short video: one line says where it ended, not one per frame
its header announced."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import cv2

from drovisio.cli import main
from drovisio.layout import shipped_layouts_dir
from drovisio.sources import VideoFileReader

SAMPLES = Path(__file__).resolve().parents[2] / "sample_sessions"
CENTRE = str(shipped_layouts_dir() / "drick-aruco-centre.json")
_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl", b"edts", b"dinf"}


def _boxes(d, start, end):
    i = start
    while i + 8 <= end:
        size, typ = struct.unpack(">I4s", d[i:i + 8])
        if size < 8:
            return
        yield typ, i, size
        i += size


def _shift_chunk_offsets(moov: bytearray, delta: int, start: int, end: int) -> None:
    for typ, i, size in _boxes(moov, start, end):
        if typ in _CONTAINERS:
            _shift_chunk_offsets(moov, delta, i + 8, i + size)
        elif typ in (b"stco", b"co64"):
            w = 4 if typ == b"stco" else 8
            fmt = ">I" if w == 4 else ">Q"
            for k in range(struct.unpack(">I", moov[i + 12:i + 16])[0]):
                o = i + 16 + w * k
                moov[o:o + w] = struct.pack(fmt, struct.unpack(fmt, moov[o:o + w])[0] + delta)


def _faststart(data: bytes) -> bytes:
    """The same MP4 with its index (moov) before the media data, as cameras and streaming
    tools write it: a copy cut short then still opens, and its header announces every
    frame."""
    top = list(_boxes(data, 0, len(data)))
    ftyp = next((i, s) for t, i, s in top if t == b"ftyp")
    mi, ms = next((i, s) for t, i, s in top if t == b"moov")
    moov = bytearray(data[mi:mi + ms])
    _shift_chunk_offsets(moov, ms, 8, ms)
    rest = b"".join(data[i:i + s] for t, i, s in top if t not in (b"moov", b"ftyp"))
    return data[ftyp[0]:ftyp[0] + ftyp[1]] + bytes(moov) + rest


def _cut_clip(tmp_path: Path) -> tuple[Path, int, int]:
    fast = _faststart((SAMPLES / "approach" / "approach.mp4").read_bytes())
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(fast[: len(fast) * 45 // 100])
    cap = cv2.VideoCapture(str(cut))
    announced = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    readable = 0
    while cap.read()[0]:
        readable += 1
    cap.release()
    return cut, announced, readable


def test_cut_short_video_ends_with_one_line_saying_where(tmp_path, capsys):
    cut, announced, readable = _cut_clip(tmp_path)
    assert announced == 150 and 20 < readable < announced   # the clip really is cut short
    rc = main(["detect", "--camera", str(SAMPLES / "camera.yaml"), "--layout", CENTRE,
               str(cut)])
    out, err = capsys.readouterr()
    lines = [json.loads(x) for x in out.splitlines()]
    assert rc == 1 and "Traceback" not in err
    # one JSON line per decoded frame, then one for the end
    assert [x["frame"] for x in lines] == list(range(readable + 1))
    assert all("error" not in x for x in lines[:-1])
    assert lines[-1]["bricks"] == []
    assert f"ends at frame {readable}" in lines[-1]["error"]
    assert f"{announced - readable} frames before the {announced}" in lines[-1]["error"]
    # stderr: that one line and the summary, not one line per missing frame
    said = [x for x in err.splitlines() if x.startswith("drovisio detect:")]
    assert len(said) == 2, said
    assert f"frame {readable}: the video ends at frame {readable}" in said[0]


def test_a_damaged_frame_in_the_middle_is_one_error_and_decoding_goes_on(tmp_path):
    """Frames after a damaged stretch decode again: those are reported one by one."""
    fast = bytearray(_faststart((SAMPLES / "approach" / "approach.mp4").read_bytes()))
    n = len(fast)
    fast[n // 2: n // 2 + 4000] = bytes(4000)      # a burst of zeros inside the media data
    clip = tmp_path / "damaged.mp4"
    clip.write_bytes(bytes(fast))
    r = VideoFileReader(clip)
    r.open()
    frames = []
    while True:
        try:
            f = r.read()
        except Exception:  # noqa: BLE001 - EndOfStream
            break
        if f is None:
            break
        frames.append(f)
    r.close()
    assert [f.index for f in frames] == list(range(len(frames)))
    assert len(frames) == 150 and r.ended_early is None
    assert sum(f.image is not None for f in frames) >= 140
