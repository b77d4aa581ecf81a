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
import shutil
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import cv2

from drovisio.fileio import atomic_write_text

__all__ = ["RECORDING_SCHEMA", "Recorder", "read_index"]

RECORDING_SCHEMA = "drovisio/recording@1"


class Recorder:
    def __init__(self, folder: str | Path, source: str = "", camera_file: str | Path | None = None,
                 mount_file: str | Path | None = None, jpeg_quality: int = 95,
                 max_queue: int = 30):
        self.folder = Path(folder)
        (self.folder / "frames").mkdir(parents=True, exist_ok=True)
        manifest = {"schema": RECORDING_SCHEMA,
                    "created": datetime.now(UTC).isoformat(timespec="seconds"),
                    "source": source, "camera": None, "mount": None}
        for key, f in (("camera", camera_file), ("mount", mount_file)):
            if f:
                dst = self.folder / (key + "".join(Path(f).suffixes[-1:]))
                try:
                    shutil.copyfile(f, dst)
                    manifest[key] = dst.name
                except OSError:
                    pass
        atomic_write_text(self.folder / "recording.json", json.dumps(manifest, indent=1))
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
            name = f"frames/{seq:06d}.jpg"
            try:
                ok = cv2.imwrite(str(self.folder / name), img,
                                 [cv2.IMWRITE_JPEG_QUALITY, self.quality])
                if not ok:
                    raise OSError("cv2.imwrite failed")
                self._index.write(json.dumps({"frame": index, "seq": seq, "t": round(t, 6),
                                              "image": name, "output": js},
                                             separators=(",", ":")) + "\n")
                self._index.flush()
                self.written += 1
            except (OSError, ValueError) as e:
                self.errors += 1
                self.last_error = str(e)

    def close(self, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._q.put(None, timeout=0.1)
                break
            except queue.Full:
                if time.monotonic() > deadline:
                    break
        self._thread.join(max(0.0, deadline - time.monotonic()))
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
