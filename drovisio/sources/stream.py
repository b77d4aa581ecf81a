"""Network streams (RTSP, HTTP MJPEG, UDP …) read through FFmpeg, with deadlines."""

from __future__ import annotations

import time
from typing import Any

from drovisio.errors import LIMITS
from drovisio.raw_frame import RawFrame

__all__ = ["StreamReader"]


class _CaptureReader:
    finite = False
    lossless = False

    def __init__(self, label: str):
        self.label = label
        self.cap: Any = None
        self.count = 0

    def _make(self) -> Any:  # pragma: no cover - overridden
        raise NotImplementedError

    def open(self) -> None:
        self.close()
        cap = self._make()
        if cap is None or not cap.isOpened():
            if cap is not None:
                cap.release()
            raise OSError(f"cannot open {self.label}")
        self.cap = cap

    def read(self) -> RawFrame | None:
        if self.cap is None:
            return None
        ok, img = self.cap.read()
        if not ok or img is None:
            return None
        self.count += 1
        return RawFrame(img, self.count - 1)

    def close(self) -> None:
        if self.cap is not None:
            try:
                self.cap.release()
            finally:
                self.cap = None



class StreamReader(_CaptureReader):
    """A network stream (RTSP, HTTP MJPEG, UDP…) through FFmpeg, with open and read
    timeouts so that a stalled stream is reported lost instead of blocking."""

    def __init__(self, url: str, open_timeout_s: float | None = None,
                 read_timeout_s: float = 2.0):
        super().__init__(url)
        self.url = url
        self.open_timeout_s = (LIMITS.connect_timeout_s if open_timeout_s is None
                               else open_timeout_s)
        self.read_timeout_s = read_timeout_s

    def open(self) -> None:
        start = time.monotonic()
        try:
            super().open()
        except OSError:
            # the time it took, measured: a refused connection ends long before the deadline
            took, deadline = time.monotonic() - start, self.open_timeout_s
            why = (f"within {deadline:g} s" if took >= 0.9 * deadline else
                   f"(refused, or not a video: the attempt ended after {took:.1f} s, before "
                   f"the {deadline:g} s deadline)")
            raise OSError(f"cannot open {self.url}: no video stream there {why}; check the "
                          "address, and that the camera is on and streaming") from None

    def read(self) -> RawFrame | None:
        """The next frame; a stream that stalls past the read deadline, or ends, is lost.

        Raises:
            OSError: in one line, naming the URL and the deadline (the source reconnects).
        """
        if self.cap is None:
            return None
        f = super().read()
        if f is None:
            raise OSError(f"{self.url}: no frame within {self.read_timeout_s:g} s (the stream "
                          "stalled or ended); reconnecting")
        return f

    def _make(self) -> Any:
        import cv2  # deferred: heavy (`drovisio --help` must not load it)

        return cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(self.open_timeout_s * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.read_timeout_s * 1000)])

