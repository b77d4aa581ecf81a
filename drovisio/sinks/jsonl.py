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


def _missing_folders(folder: Path) -> list[Path]:
    """The folders of ``folder``'s path that do not exist yet, deepest first."""
    out = []
    for q in (folder, *folder.parents):
        if q.exists() or q.is_symlink():
            break
        out.append(q)
    return out


class JsonlSink:
    def __init__(self, path: str = "-", with_covariance: bool = True):
        self.name = f"jsonl:{path}"
        self.with_covariance = with_covariance
        self.delivery = Delivery()
        self._closed = False
        # The file this sink made, and the folders it made for it (deepest first): removed
        # at close when nothing was written. Not a file opened at the first frame, nor a
        # temporary file moved into place at close: the stream is read while it is written
        # (tail -f, a logger; a kill -9 keeps what was written), and opening it at start is
        # the start-up check (a folder that cannot be made, a FIFO nobody reads: said before
        # anything runs, not at the first frame).
        self._made: Path | None = None
        self._folders: list[Path] = []
        if path in ("-", ""):
            self._f = sys.stdout
            self._own = False
            return
        p = Path(path)
        try:
            self._folders = _missing_folders(p.parent)
            p.parent.mkdir(parents=True, exist_ok=True)
            fd, made = _open_append(p)
            os.set_blocking(fd, True)
            self._f = os.fdopen(fd, "a", encoding="utf-8", buffering=1)
        except OSError as e:
            self._remove_made()
            raise SinkError(f"jsonl:{path}: cannot open for writing ({e.strerror or e})") \
                from e
        self._own = True
        if made:
            self._made = p
        else:
            self._folders = []

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
            untouched = self._unwritten()
        except (OSError, ValueError):
            untouched = False
        try:
            self._f.close()
        except OSError:
            pass
        if untouched:
            self._remove_made()

    def _unwritten(self) -> bool:
        """The file this sink made is still empty, and still the one at its path."""
        if self._made is None:
            return False
        st, own = os.stat(self._made), os.fstat(self._f.fileno())
        return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino) and own.st_size == 0

    def _remove_made(self) -> None:
        """Remove what this sink made, the file then its folders; a folder something else
        was put in stays, and so does every folder above it."""
        try:
            if self._made is not None:
                self._made.unlink()
            for q in self._folders:
                q.rmdir()
        except OSError:
            pass

    def status(self) -> dict:
        return {"sink": self.name, **self.delivery.status()}
