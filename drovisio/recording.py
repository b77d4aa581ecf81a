"""``--record DIR``: save the frames and the poses of a run; a recording plays back as a source.

Layout of a recording folder::

    DIR/recording.json    {"schema": "drovisio/recording@1", "created": ..., "source": ...,
                           "camera": "camera.yaml" | null, "mount": "mount.json" | null}
    DIR/frames.jsonl      one line per recorded frame:
                          {"frame": N, "seq": S, "t": UNIX_S, "image": "frames/000123.jpg",
                           "output": {...the frame's JSON output (as jsonl:...)...}}
    DIR/frames/*.jpg      the frames (JPEG, quality 95 by default)
    DIR/camera.yaml       copy of the camera file (when given), mount.json likewise

Writing happens in a background thread with a bounded queue: a slow disk drops frames from
the recording (counted in :meth:`Recorder.status`) but never slows the pipeline. Play a
recording with ``--source DIR`` (:class:`drovisio.sources.RecordingReader`): frames come at
their recorded timing.

A recording a run made and that holds no frame when it closes (the source failed at its first
read, Ctrl+C before the first frame, a stream that never delivered) is removed again, as both
recorders (this folder and the ``.mcap`` file) do through :class:`drovisio.fileio.MadeFiles`: only what the
recorder itself made, each file checked by its inode, a folder only when it is then empty.
The status says so (``"removed"``) and :func:`end_lines` says it, with the frames a recorder
could not write or dropped, one line each.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import queue
import re
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple

import cv2

from drovisio._threads import STOP_WAIT_S, join_thread
from drovisio.bounds import check_number, check_whole
from drovisio.errors import InputError
from drovisio.fileio import MadeFiles, atomic_write_bytes
from drovisio.textfile import check_regular_file, name_inside, parse_json

__all__ = ["MAX_FRAMES", "MAX_INDEX_BYTES", "MAX_LINE_BYTES", "MAX_TIME_S", "RECORDING_SCHEMA",
           "RecordedFrame", "Recorder", "end_lines", "holds_recording", "read_index",
           "removed_line", "stop_writer"]

RECORDING_SCHEMA = "drovisio/recording@1"


def _place(status: dict) -> str:
    return status.get("folder") or status.get("file") or "--record"


def end_lines(status: dict) -> list[str]:
    """What a closed recorder's status has to say where it did not record every frame, one
    line each: frames it could not write (a failing output, as a failing sink), frames a slow
    disk made it drop, and that it held no frame and was removed (:func:`removed_line`)."""
    out = []
    errors = int(status.get("errors") or 0)
    if errors and status.get("removed") is None:   # a removed recording's line says its error
        out.append(f"{_place(status)}: {errors} frames could not be recorded "
                   f"({status.get('written', 0)} were)"
                   + (f" (last: {status['last_error']})" if status.get("last_error") else ""))
    if status.get("dropped"):
        out.append(f"{_place(status)}: {status['dropped']} frames not recorded: the disk was "
                   "slower than the camera")
    line = removed_line(status)
    return out + ([line] if line else [])


def removed_line(status: dict) -> str | None:
    """What a closed recorder's status (``"removed"``) has to say, in one line: that the
    recording it made held no frame and was removed (or could not be, wholly); None when it
    was kept."""
    removed = status.get("removed")
    if removed is None:
        return None
    where = _place(status)
    why = f" (last error: {status['last_error']})" if status.get("last_error") else ""
    if removed:
        return f"{where}: no frame was recorded{why}; the empty recording was removed"
    return (f"{where}: no frame was recorded{why}; the empty recording could not be removed "
            "whole (something in it changed meanwhile): remove it by hand")


def holds_recording(folder: str | Path) -> bool:
    """Whether ``folder`` already holds (part of) a recording: a manifest, an index or a
    frame. ``run`` and ``serve`` refuse such a ``--record`` folder at start-up, so that a new
    recording never mixes into, or overwrites, an older one."""
    f = Path(folder)
    if (f / "recording.json").exists() or (f / "frames.jsonl").exists():
        return True
    try:
        return (f / "frames").is_dir() and any((f / "frames").iterdir())
    except OSError:
        return True


def _next_frame_number(frames: Path) -> int:
    """One past the highest ``NNNNNN.jpg`` in ``frames`` (0 when none)."""
    top = -1
    try:
        for e in frames.iterdir():
            stem = e.name.partition(".")[0]
            if stem.isdigit():
                top = max(top, int(stem))
    except OSError:
        pass
    return top + 1


def stop_writer(q: queue.Queue, thread: threading.Thread, timeout: float = STOP_WAIT_S
                ) -> None:
    """End a recorder's writer thread: queue the end mark (``None``) behind what is waiting,
    then wait for the thread to write it all (it encodes in OpenCV), both within ``timeout``
    seconds in all, a bound that only turns a hang into a warning."""
    deadline = time.monotonic() + timeout
    while thread.is_alive():
        try:
            q.put(None, timeout=0.1)
            break
        except queue.Full:
            if time.monotonic() > deadline:
                break
    join_thread(thread, "writing the recording's queued frames",
                max(0.0, deadline - time.monotonic()))


def _drop_cut_line(index: Path) -> None:
    """Before a recording is continued, cut its index back to its last whole line: a line
    cut by a crash (no line end) would otherwise be glued to the next entry, and the index
    could no longer be read past it."""
    try:
        with open(index, "rb+") as f:
            size = f.seek(0, os.SEEK_END)
            if size == 0:
                return
            f.seek(size - 1)
            if f.read(1) == b"\n":
                return
            start = max(0, size - MAX_LINE_BYTES - 2)
            f.seek(start)
            tail = f.read()
            nl = tail.rfind(b"\n")
            f.truncate(start + nl + 1 if nl >= 0 else 0 if start == 0 else size)
    except FileNotFoundError:
        return


class Recorder:
    """Writes a recording folder (see the module doc) without ever replacing a file in it.

    A folder that already holds a recording (the web tool's pipeline restarted on the same
    ``--record``) is continued: its manifest and copies are kept, the index is appended to,
    and new frames are numbered after the highest one there. Each frame file is created
    exclusively (never over an existing name) and streamed; its index line is written only
    once the file is complete, so a run killed mid-frame leaves at most one unindexed file,
    which playback never reads.

    A recording this recorder made (not continued) that holds no frame at :meth:`close` is
    removed: the files it wrote, then the folders it made once empty (a folder that was
    there before stays, with whatever else is in it).
    """

    def __init__(self, folder: str | Path, source: str = "", camera_file: str | Path | None = None,
                 mount_file: str | Path | None = None, jpeg_quality: int = 95,
                 max_queue: int = 30):
        self.folder = Path(folder)
        self._made = MadeFiles()
        self._own = False
        """This recorder made the recording (its manifest): removed at close if empty."""
        self.removed: bool | None = None
        """Set at close when the recording it made held no frame: whether it is gone."""
        try:
            self._start(source, camera_file, mount_file)
        except BaseException:
            self._made.remove()   # nothing is recorded: what was made is not left behind
            raise
        self.quality = int(jpeg_quality)
        self._q: queue.Queue = queue.Queue(maxsize=max_queue)
        self.written = 0
        self.dropped = 0
        self.errors = 0
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._writer, daemon=True, name="recorder")
        self._thread.start()

    def _write_new(self, path: Path, data: bytes) -> None:
        """``path`` written (never over a file), noted as made here by what was written."""
        written: list[os.stat_result] = []
        atomic_write_bytes(path, data, overwrite=False,
                           verify=lambda tmp: written.append(tmp.lstat()))
        self._made.add(path, written[-1])

    def _start(self, source: str, camera_file: str | Path | None,
               mount_file: str | Path | None) -> None:
        self._made.make_folder(self.folder / "frames")
        self._number = _next_frame_number(self.folder / "frames")
        self.continued = (self.folder / "recording.json").exists()
        manifest = {"schema": RECORDING_SCHEMA,
                    "created": datetime.now(UTC).isoformat(timespec="seconds"),
                    "source": source, "camera": None, "mount": None}
        for key, f in (("camera", camera_file), ("mount", mount_file)):
            if f:
                dst = self.folder / (key + "".join(Path(f).suffixes[-1:]))
                if self.continued or dst.exists():
                    continue  # the recording's own copies are kept
                try:
                    self._write_new(dst, Path(f).read_bytes())
                    manifest[key] = dst.name
                except OSError:
                    pass
        if not self.continued:
            try:
                self._write_new(self.folder / "recording.json",
                                json.dumps(manifest, indent=1).encode("utf-8"))
                self._own = True
            except FileExistsError:
                self.continued = True  # made meanwhile by another writer: kept
        index = self.folder / "frames.jsonl"
        _drop_cut_line(index)
        try:   # made here (noted), else appended to
            fd = os.open(index, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_EXCL, 0o666)
            self._made.add(index, os.fstat(fd))
        except FileExistsError:
            fd = os.open(index, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        self._index = open(fd, "ab", buffering=0)   # one write per line (see _append_line)

    def add(self, frame, output) -> None:
        """Queue a frame and its output (never blocks)."""
        try:
            self._q.put_nowait((frame.image, frame.index, frame.seq, frame.t_wall,
                                output.to_json()))
        except queue.Full:
            self.dropped += 1

    def _writer(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                break
            img, index, seq, t, js = item
            name = f"frames/{self._number:06d}.jpg"
            path = self.folder / name
            made = advanced = indexed = False
            try:
                ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
                if not ok:
                    raise OSError("OpenCV could not encode the frame as JPEG")
                # "x": a new file, never over one (streamed: a frame is indexed once whole)
                with open(path, "xb") as fh:
                    made = True
                    if self.written == 0:   # removed with the rest if no frame is recorded
                        self._made.add(path, os.fstat(fh.fileno()))
                    fh.write(buf.tobytes())
                self._number += 1
                advanced = True
                self._append_line(json.dumps({"frame": index, "seq": seq, "t": round(t, 6),
                                              "image": name, "output": js},
                                             separators=(",", ":")))
                indexed = True
                self.written += 1
            except (OSError, ValueError) as e:
                self.errors += 1
                self.last_error = str(e)
                # a name taken, or a frame cut short (a full disk): never indexed, and the
                # next frame takes the next name, or every later frame would fail on this one
                if (isinstance(e, FileExistsError) or made) and not advanced:
                    self._number += 1
                if made and not indexed:   # a frame no index line names is never played
                    with contextlib.suppress(OSError):
                        path.unlink()

    def _append_line(self, line: str) -> None:
        """Add one line to the index in one write; a line a full disk cut short is cut off
        again at once (:func:`_drop_cut_line`), or the next line would be glued to it and the
        index could not be read past it."""
        data = (line + "\n").encode("utf-8")
        try:
            if self._index.write(data) != len(data):
                raise OSError(errno.ENOSPC, "the index line was cut short (disk full?)")
        except OSError:
            _drop_cut_line(self.folder / "frames.jsonl")
            raise

    def close(self, timeout: float = STOP_WAIT_S) -> None:
        """Write what is queued; then a recording this recorder made that holds no frame is
        removed (:attr:`removed`)."""
        stop_writer(self._q, self._thread, timeout)
        try:   # another recorder on the same folder (a second run) wrote to it: it stays
            others = (os.fstat(self._index.fileno()).st_size > 0
                      or any((self.folder / "frames").iterdir()))
        except (OSError, ValueError):
            others = True
        self._index.close()
        if self._own and self.written == 0 and not others and not self._thread.is_alive() \
                and self.removed is None:
            self.removed = self._made.remove()

    def status(self) -> dict:
        """``removed``: None while kept, else whether the empty recording is gone."""
        return {"folder": str(self.folder), "written": self.written, "dropped": self.dropped,
                "errors": self.errors, "last_error": self.last_error, "removed": self.removed}


class RecordedFrame(NamedTuple):
    """One frame of a recording's index, as played back."""

    frame: int
    """The frame's number in its source."""
    t: float
    """Its capture time, UNIX seconds."""
    image: str
    """Its picture, relative to the recording folder."""


MAX_FRAMES = 500_000
"""Most frames a recording's index may hold (over 4.5 hours at 30 fps)."""
MAX_LINE_BYTES = 1 << 20
"""Longest line of the index (a frame's output with hundreds of bricks is far shorter)."""
MAX_INDEX_BYTES = 1 << 30
"""Largest index read (a frame's line is a few hundred bytes to a few KiB)."""
MAX_TIME_S = 1e10
"""Latest capture time read (UNIX seconds; the year 2286)."""


_RECORDED_NAME = re.compile(r"frames/[0-9]{6,12}\.jpg")
"""The picture names :class:`Recorder` writes (inside the folder by their form)."""


def _entry(e: object, folder: Path, where: str) -> RecordedFrame:
    """One line of the index, parsed, every field checked (``where``: ``FILE, line N``)."""
    if not isinstance(e, dict):
        raise InputError(f'{where}: expected an object with "frame", "t" and "image"; this '
                         "is not a recording's index")
    frame = check_whole(e.get("frame"), f"{where}: frame", 0, 10**12)
    t = check_number(e.get("t"), f"{where}: t", 0.0, MAX_TIME_S, unit="s")
    image = e.get("image")
    if not (isinstance(image, str) and _RECORDED_NAME.fullmatch(image)):   # not ours: checked
        name_inside(folder, image, f"{where}: image", "frame image")
    return RecordedFrame(frame, t, str(image))   # a text name: checked above


def read_index(folder: str | Path) -> list[RecordedFrame]:
    """The frames of a recording, in order, read once and checked: an index of at most
    :data:`MAX_INDEX_BYTES`, :data:`MAX_FRAMES` lines of at most :data:`MAX_LINE_BYTES`, each
    a JSON object with a whole ``frame``, a finite ``t`` within ``0..MAX_TIME_S`` and an
    ``image`` named inside the folder. A last line cut by a crash (no line end, not JSON) is
    left out; an empty or missing index holds no frames.

    Raises:
        InputError: one line naming the index, the line and the field.
    """
    folder = Path(folder)
    idx = folder / "frames.jsonl"
    if not idx.exists():
        return []
    size = check_regular_file(idx, "recording index").stat().st_size
    if size > MAX_INDEX_BYTES:
        raise InputError(f"{idx}: {size >> 20} MiB, more than a recording's index may be "
                         f"({MAX_INDEX_BYTES >> 20} MiB); split the recording")
    out: list[RecordedFrame] = []
    try:
        with open(idx, "rb") as f:
            for n, line in enumerate(iter(lambda: f.readline(MAX_LINE_BYTES + 2), b""), 1):
                where = f"{idx}, line {n}"
                if len(line.rstrip(b"\r\n")) > MAX_LINE_BYTES:
                    raise InputError(f"{where}: longer than {MAX_LINE_BYTES >> 20} MiB; this "
                                     "is not a recording's index")
                if not line.strip():
                    continue
                if len(out) >= MAX_FRAMES:
                    raise InputError(f"{idx}: more than {MAX_FRAMES} frames; split the "
                                     "recording")
                try:   # a NaN is parsed, to be named by its field
                    e = parse_json(line, where, parse_constant=float)
                except InputError:
                    if line.endswith(b"\n"):
                        raise
                    break   # the last line (no line end), cut by a crash while written
                out.append(_entry(e, folder, where))
    except OSError as e:
        raise InputError(f"{idx}: cannot read the recording index ({e.strerror or e})") \
            from None
    return out
