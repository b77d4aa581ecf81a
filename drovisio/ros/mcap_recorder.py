"""``--record FILE.mcap``: the run as one MCAP file (ROS 2 profile) for ros2 bag and Foxglove.

The messages are those of :class:`drovisio.ros.messages.RosMessages` (images as JPEG
``CompressedImage``, camera info, the mount on ``/tf_static``, the bricks, the target and the
JSON output), CDR-encoded with the definitions of :mod:`drovisio.ros.msgdefs`. The file is
*chunked* (zstd) and a chunk is closed and flushed to the operating system at least every
``flush_s`` seconds: a process killed with ``kill -9`` leaves a file without its summary
whose chunks up to the last flush all read back (:mod:`drovisio.ros.mcap_source` replays
such a file; ``mcap recover`` restores its summary for other tools).

Like :class:`drovisio.recording.Recorder`, writing happens in a background thread with a
bounded queue: a slow disk drops frames from the recording (counted in :meth:`status`), never
slows the pipeline; and like it, a file that holds no frame when it closes is removed again
(with the folders made for it, once empty): :class:`drovisio.fileio.MadeFiles`.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import cv2

from drovisio._threads import STOP_WAIT_S
from drovisio.fileio import MadeFiles
from drovisio.recording import stop_writer
from drovisio.ros.messages import RosMessages
from drovisio.ros.msgdefs import encoder, schema_text

__all__ = ["McapRecorder"]


def _open_new(path: Path):
    """``path`` created for writing, never over an existing file: when it exists (the web
    tool's pipeline restarted on the same ``--record``), the first free ``STEM-N.mcap``;
    ``path`` is then the name written. ``run`` refuses an existing file at start-up."""
    stem, suffix = path.stem, path.suffix
    for n in range(1, 10000):
        p = path if n == 1 else path.with_name(f"{stem}-{n}{suffix}")
        try:
            return open(p, "xb")
        except FileExistsError:
            continue
    raise FileExistsError(f"{path}: --record: no free name next to it; give a new FILE.mcap")


class McapRecorder:
    """Writes frames and outputs to ``path`` (see the module doc).

    Args:
        path: The ``.mcap`` file (created; its folder too; both removed again at
            :meth:`close` when no frame was written).
        messages: What to write (:class:`RosMessages` with the camera, mount and layouts).
        source: The run's source, kept in the file's metadata.
        jpeg_quality: JPEG quality of the images.
        image_format: ``jpeg`` or ``png`` (lossless: a replay sees the very frames).
        flush_s: Longest time (s) between two flushed chunks (what ``kill -9`` may lose).
        chunk_size: Bytes after which a chunk is closed anyway.
    """

    def __init__(self, path: str | Path, messages: RosMessages, source: str = "",
                 jpeg_quality: int = 95, image_format: str = "jpeg", flush_s: float = 1.0, chunk_size: int = 1 << 20,
                 max_queue: int = 30):
        from mcap.writer import CompressionType, Writer

        if image_format not in ("jpeg", "png"):
            raise ValueError(f"image_format: {image_format!r}: use jpeg or png")
        self.path = Path(path)
        self._made = MadeFiles()
        self.removed: bool | None = None
        """Set at close when no frame was written: whether the file is gone."""
        f = None
        try:
            self._made.make_folder(self.path.parent)
            f = _open_new(self.path)
            self.path = Path(f.name)
            self._made.add(self.path, os.fstat(f.fileno()))
            self._w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
            self._w.start(profile="ros2", library="drovisio")
            self._w.add_metadata("drovisio", {
                "created": datetime.now(UTC).isoformat(timespec="seconds"),
                "source": str(source), "schema": "drovisio/recording-mcap@1"})
        except BaseException:   # nothing is recorded: what was made is not left behind
            if f is not None:
                f.close()
            self._made.remove()
            raise
        self._f = f
        self.messages = messages
        self.quality = int(jpeg_quality)
        self.image_format = image_format
        self.flush_s = float(flush_s)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._last_flush = time.monotonic()
        self._started = False
        self.written = 0
        self.dropped = 0
        self.errors = 0
        self.last_error: str | None = None
        self._q: queue.Queue = queue.Queue(maxsize=max_queue)
        self._thread = threading.Thread(target=self._writer, daemon=True, name="mcap-recorder")
        self._thread.start()

    # ------------------------------------------------------------------ writing
    def _channel(self, topic: str, type_name: str) -> int:
        ch = self._channels.get(topic)
        if ch is None:
            sid = self._schemas.get(type_name)
            if sid is None:
                sid = self._w.register_schema(type_name, "ros2msg",
                                              schema_text(type_name).encode())
                self._schemas[type_name] = sid
            ch = self._w.register_channel(topic, "cdr", sid)
            self._channels[topic] = ch
        return ch

    def _write(self, topic: str, type_name: str, msg: dict, t: float) -> None:
        ns = int(round(t * 1e9))
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        self._w.add_message(self._channel(topic, type_name), log_time=ns, publish_time=ns,
                            data=encoder(type_name)(msg), sequence=seq)

    def add(self, frame, output) -> None:
        """Queue a frame and its output (never blocks)."""
        try:
            self._q.put_nowait((frame.image, output))
        except queue.Full:
            self.dropped += 1

    def _writer(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                break
            img, output = item
            try:
                if self.image_format == "png":
                    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
                else:
                    ok, buf = cv2.imencode(".jpg", img,
                                           [cv2.IMWRITE_JPEG_QUALITY, self.quality])
                if not ok:
                    raise OSError(f"{self.image_format} encoding failed")
                if not self._started:
                    for topic, type_name, msg in self.messages.run_messages(output.t):
                        self._write(topic, type_name, msg, output.t)
                    self._started = True
                for topic, type_name, msg in self.messages.frame_messages(
                        output, buf.tobytes(), self.image_format):
                    self._write(topic, type_name, msg, output.t)
                self.written += 1
                if time.monotonic() - self._last_flush >= self.flush_s:
                    self._w.flush()   # closes the chunk: what kill -9 keeps
                    self._last_flush = time.monotonic()
            except (OSError, ValueError) as e:
                self.errors += 1
                self.last_error = str(e)

    def close(self, timeout: float = STOP_WAIT_S) -> None:
        """Write what is queued, then the summary (the file is then complete); a file that
        holds no frame is removed (:attr:`removed`)."""
        stop_writer(self._q, self._thread, timeout)
        try:
            self._w.finish()
        except (OSError, ValueError) as e:
            self.errors += 1
            self.last_error = str(e)
        finally:
            self._f.close()
            if self.written == 0 and not self._thread.is_alive() and self.removed is None:
                self.removed = self._made.remove()

    def status(self) -> dict:
        """``removed``: None while kept, else whether the empty file is gone."""
        return {"file": str(self.path), "written": self.written, "dropped": self.dropped,
                "errors": self.errors, "last_error": self.last_error, "removed": self.removed}
