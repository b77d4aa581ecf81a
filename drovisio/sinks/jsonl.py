"""``jsonl:-`` / ``jsonl:PATH``: one JSON object per processed frame (JSON Lines).

A ``jsonl:PATH`` file is appended to, never truncated or replaced. An existing one (a log, a
FIFO, a device) is opened at start, so that a FIFO nobody reads is said before anything runs;
a missing one is made at the first line, its folder checked at start: a run that ends before
its first frame leaves no file behind, and nothing is ever removed (another writer may hold
the same file open).
"""

from __future__ import annotations

import errno
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import TextIO

from drovisio.sinks.base import Delivery, SinkError

__all__ = ["JsonlSink"]

# non-blocking open: a FIFO nobody reads fails at once (ENXIO), never hangs
_APPEND = os.O_WRONLY | os.O_APPEND | os.O_NONBLOCK


def _check_can_make(p: Path) -> None:
    """Raise the OSError that making ``p`` (and its missing folders) would meet, leaving
    nothing behind: its nearest existing folder must be a folder that takes a new entry (a
    folder of our own, made and removed again at once: permissions alone do not say it, not
    for root, not on /proc or a read-only mount)."""
    for q in p.parents:
        if os.path.lexists(q):
            if not q.is_dir():
                raise OSError(errno.ENOTDIR, "not a folder", str(q))
            try:
                os.rmdir(tempfile.mkdtemp(prefix=".drovisio-check-", dir=q))
            except OSError as e:   # named by the folder, not by the probe's own name
                raise OSError(e.errno, e.strerror, str(q)) from None
            return


def _cannot_write(p: Path, e: OSError) -> str:
    """Why ``p`` cannot be written and what to do (the spec is said by ``open_sink``)."""
    why = e.strerror or str(e)
    if e.errno == errno.ENXIO:            # a FIFO (or device) nobody reads
        return (f"cannot open for writing ({why}); start the program that reads it first, "
                "or give a file")
    # the folder in the way, when it is not the file itself
    where = (f"cannot write in {e.filename}" if e.filename is not None
             and Path(e.filename) != p else "cannot open for writing")
    return (f"{where} ({why}); give a file in a folder that exists (or can be made) and "
            "that this user can write to")


class JsonlSink:
    def __init__(self, path: str = "-", with_covariance: bool = True):
        self.name = f"jsonl:{path}"
        self.with_covariance = with_covariance
        self.delivery = Delivery()
        self._closed = False
        self._f: TextIO | None = None
        if path in ("-", ""):
            self._f = sys.stdout
            self._own = False
            return
        self._path = Path(path)
        try:
            if os.path.lexists(self._path):
                self._open()
            else:
                _check_can_make(self._path)
        except OSError as e:
            raise SinkError(_cannot_write(self._path, e)) from e
        self._own = True

    def _open(self) -> TextIO:
        """The file, opened for appending (made, with its folders, if missing)."""
        self._path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self._path, _APPEND | os.O_CREAT, 0o666)
        os.set_blocking(fd, True)
        self._f = os.fdopen(fd, "a", encoding="utf-8", buffering=1)
        return self._f

    def send(self, output) -> None:
        try:
            if self._closed:
                raise ValueError("the sink is closed")
            f = self._f if self._f is not None else self._open()
            f.write(json.dumps(output.to_json(self.with_covariance),
                               separators=(",", ":")) + "\n")
            f.flush()
        except (OSError, ValueError) as e:  # disk full, closed stdout: count, go on
            self.delivery.failed(str(e))
            return
        self.delivery.delivered()

    def close(self) -> None:
        if not self._own or self._closed:
            return
        self._closed = True
        if self._f is not None:
            try:
                self._f.close()
            except OSError:
                pass

    def status(self) -> dict:
        return {"sink": self.name, **self.delivery.status()}
