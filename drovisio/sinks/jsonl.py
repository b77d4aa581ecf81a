"""``jsonl:-`` / ``jsonl:PATH``: one JSON object per processed frame (JSON Lines).

A ``jsonl:PATH`` file is opened at start and appended to: an existing file is never truncated
or replaced, and a file this sink made is removed again at close when nothing was ever
written to it (a run that ended before its first frame leaves no empty file behind).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from drovisio.fileio import MadeFiles
from drovisio.sinks.base import Delivery, SinkError

__all__ = ["JsonlSink"]

_APPEND = os.O_WRONLY | os.O_APPEND | os.O_NONBLOCK


def _open_append(p: Path) -> tuple[int, bool]:
    """``p`` opened for appending (made if missing): (descriptor, whether this call made it).

    Non-blocking: a FIFO nobody reads fails at once (ENXIO), never hangs.
    """
    try:
        return os.open(p, _APPEND | os.O_CREAT | os.O_EXCL, 0o666), True
    except FileExistsError:
        pass
    try:
        return os.open(p, _APPEND), False
    except FileNotFoundError:   # a link to nothing, or removed meanwhile: made, not ours
        return os.open(p, _APPEND | os.O_CREAT, 0o666), False


class JsonlSink:
    def __init__(self, path: str = "-", with_covariance: bool = True):
        self.name = f"jsonl:{path}"
        self.with_covariance = with_covariance
        self.delivery = Delivery()
        self._closed = False
        # The file this sink made, and the folders it made for it: removed at close when
        # nothing was written. Not a file opened at the first frame, nor a
        # temporary file moved into place at close: the stream is read while it is written
        # (tail -f, a logger; a kill -9 keeps what was written), and opening it at start is
        # the start-up check (a folder that cannot be made, a FIFO nobody reads: said before
        # anything runs, not at the first frame).
        self._made = MadeFiles()
        self._made_file = False
        if path in ("-", ""):
            self._f = sys.stdout
            self._own = False
            return
        p = Path(path)
        try:
            self._made.make_folder(p.parent)
            fd, made = _open_append(p)
            if made:
                self._made.add(p, os.fstat(fd))
            os.set_blocking(fd, True)
            self._f = os.fdopen(fd, "a", encoding="utf-8", buffering=1)
        except OSError as e:
            self._made.remove()
            raise SinkError(f"jsonl:{path}: cannot open for writing ({e.strerror or e})") \
                from e
        self._own = True
        self._made_file = made

    def send(self, output) -> None:
        try:
            self._f.write(json.dumps(output.to_json(self.with_covariance),
                                     separators=(",", ":")) + "\n")
            self._f.flush()
        except (OSError, ValueError) as e:  # disk full, closed stdout: count, go on
            self.delivery.failed(str(e))
            return
        self.delivery.delivered()

    def close(self) -> None:
        if not self._own or self._closed:
            return
        self._closed = True
        try:
            untouched = self._made_file and os.fstat(self._f.fileno()).st_size == 0
        except (OSError, ValueError):
            untouched = False
        try:
            self._f.close()
        except OSError:
            pass
        if untouched:
            self._made.remove()   # only if the path still names the file made here

    def status(self) -> dict:
        return {"sink": self.name, **self.delivery.status()}
