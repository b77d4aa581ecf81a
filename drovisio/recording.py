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
"""

from __future__ import annotations

import json
import queue
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import cv2

from drovisio.fileio import atomic_write_bytes, atomic_write_text

__all__ = ["RECORDING_SCHEMA", "Recorder", "holds_recording", "read_index", "stop_writer"]

RECORDING_SCHEMA = "drovisio/recording@1"


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


def stop_writer(q: queue.Queue, thread: threading.Thread, timeout: float) -> None:
    """End a recorder's writer thread: queue the end mark (``None``) behind what is waiting,
    then wait for the thread, both within ``timeout`` seconds in all."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            q.put(None, timeout=0.1)
            break
        except queue.Full:
            if time.monotonic() > deadline:
                break
    thread.join(max(0.0, deadline - time.monotonic()))


class Recorder:
    """Writes a recording folder (see the module doc) without ever replacing a file in it.

    A folder that already holds a recording (the web tool's pipeline restarted on the same
    ``--record``) is continued: its manifest and copies are kept, the index is appended to,
    and new frames are numbered after the highest one there. Each frame file is created
    exclusively (never over an existing name) and streamed; its index line is written only
    once the file is complete, so a run killed mid-frame leaves at most one unindexed file,
    which playback never reads.
    """

    def __init__(self, folder: str | Path, source: str = "", camera_file: str | Path | None = None,
                 mount_file: str | Path | None = None, jpeg_quality: int = 95,
                 max_queue: int = 30):
        self.folder = Path(folder)
        (self.folder / "frames").mkdir(parents=True, exist_ok=True)
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
                    atomic_write_bytes(dst, Path(f).read_bytes(), overwrite=False)
                    manifest[key] = dst.name
                except OSError:
                    pass
        if not self.continued:
            try:
                atomic_write_text(self.folder / "recording.json",
                                  json.dumps(manifest, indent=1), overwrite=False)
            except FileExistsError:
                self.continued = True  # made meanwhile by another writer: kept
        self._index = open(self.folder / "frames.jsonl", "a", encoding="utf-8")
        self.quality = int(jpeg_quality)
        self._q: queue.Queue = queue.Queue(maxsize=max_queue)
        self.written = 0
        self.dropped = 0
        self.errors = 0
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._writer, daemon=True, name="recorder")
        self._thread.start()

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
            try:
                ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
                if not ok:
                    raise OSError("OpenCV could not encode the frame as JPEG")
                # "x": a new file, never over one (streamed: a frame is indexed once whole)
                with open(self.folder / name, "xb") as fh:
                    fh.write(buf.tobytes())
                self._number += 1
                self._index.write(json.dumps({"frame": index, "seq": seq, "t": round(t, 6),
                                              "image": name, "output": js},
                                             separators=(",", ":")) + "\n")
                self._index.flush()
                self.written += 1
            except (OSError, ValueError) as e:
                self.errors += 1
                self.last_error = str(e)

    def close(self, timeout: float = 10.0) -> None:
        stop_writer(self._q, self._thread, timeout)
        self._index.close()

    def status(self) -> dict:
        return {"folder": str(self.folder), "written": self.written, "dropped": self.dropped,
                "errors": self.errors, "last_error": self.last_error}


def read_index(folder: str | Path) -> list[dict]:
    """The frames of a recording, in order: dicts with ``frame``, ``t``, ``image``, ``output``."""
    folder = Path(folder)
    out: list[dict] = []
    idx = folder / "frames.jsonl"
    if not idx.is_file():
        return out
    with open(idx, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                e = json.loads(line)
            except ValueError:
                continue  # a line cut by a crash
            if "image" in e and "t" in e:
                out.append(e)
    return out
