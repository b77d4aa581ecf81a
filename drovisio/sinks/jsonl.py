"""``jsonl:-`` / ``jsonl:PATH``: one JSON object per processed frame (JSON Lines)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from drovisio.sinks.base import Delivery, SinkError

__all__ = ["JsonlSink"]


class JsonlSink:
    def __init__(self, path: str = "-", with_covariance: bool = True):
        self.name = f"jsonl:{path}"
        self.with_covariance = with_covariance
        self.delivery = Delivery()
        if path in ("-", ""):
            self._f = sys.stdout
            self._own = False
        else:
            p = Path(path)
            try:
                p.parent.mkdir(parents=True, exist_ok=True)
                # non-blocking open: a FIFO nobody reads fails at once (ENXIO), never hangs
                fd = os.open(p, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NONBLOCK, 0o666)
                os.set_blocking(fd, True)
                self._f = os.fdopen(fd, "a", encoding="utf-8", buffering=1)
            except OSError as e:
                raise SinkError(f"jsonl:{path}: cannot open for writing ({e.strerror or e})") \
                    from e
            self._own = True

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
        if self._own:
            try:
                self._f.close()
            except OSError:
                pass

    def status(self) -> dict:
        return {"sink": self.name, **self.delivery.status()}
