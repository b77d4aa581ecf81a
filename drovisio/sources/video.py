"""Video files, frame by frame, damaged frames and cut-short files included."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drovisio.errors import LIMITS
from drovisio.images import (
    IMAGE_SUFFIXES,
    ImageError,
    check_frame_size,
    read_image,
    to_bgr8,
    video_header_size,
)
from drovisio.raw_frame import EndOfStream, RawFrame

__all__ = ["MAX_BAD_FRAMES_IN_A_ROW", "VideoFileReader"]


def _check_video_frame(path: str, size: tuple[int, int] | None, said: str) -> None:
    """Refuse a video whose frames are over the image caps, before one is decoded."""
    if size is None or size[0] <= 0 or size[1] <= 0:
        return  # unknown here: the next check (or the decoder) decides
    try:
        check_frame_size(*size)
    except ImageError:
        w, h = size
        raise OSError(f"{path}: {said} frames of {w}x{h} ({w * h / 1e6:.0f} Mpx), more than "
                      f"the {LIMITS.max_image_pixels / 1e6:.0f} Mpx (and "
                      f"{LIMITS.max_image_side} pixels a side) Drovisio decodes; re-encode it "
                      "smaller (or set DROVISIO_MAX_IMAGE_MPX)") from None


#: when a frame cannot be decoded, this many following frames are tried; if none decodes,
#: the video ends there (cut short) and one item says where
MAX_BAD_FRAMES_IN_A_ROW = 8


class VideoFileReader:
    """A video file, frame by frame; ``loop=True`` starts over at the end (demo playback).

    A frame the decoder cannot read (a damaged file) becomes a frame carrying ``error`` and
    decoding resumes after it; when none of the next :data:`MAX_BAD_FRAMES_IN_A_ROW` frames
    decodes either, the file is taken as cut short there: one frame carrying ``error`` says
    where the video ended and how many of the frames its header announces are missing, and
    the video ends.
    """

    finite = True
    lossless = False

    def __init__(self, path: str | Path, loop: bool = False):
        self.path = str(path)
        self.label = self.path
        self.loop = loop
        self.finite = not loop
        self.cap: Any = None
        self.fps = 0.0
        self.index = 0
        self.lap = 0
        self.total = 0
        self.count = 0
        """Frames the file's header announces (0: unknown)."""
        self._pending: list[RawFrame] = []
        self.ended_early: int | None = None
        """The frame index at which a cut-short file ended (None: it did not)."""

    def open(self) -> None:
        import cv2  # deferred: heavy (`drovisio --help` must not load it)

        self.close()
        p = Path(self.path)
        if not p.exists():
            raise OSError(f"{self.path}: no such video file")
        if not p.is_file():
            raise OSError(f"{self.path}: not a regular file (a folder, a pipe or a device)")
        if p.suffix.lower() in IMAGE_SUFFIXES:
            # one picture as a source: the image reader's bounded checks (header size, file
            # size), and an undecodable one cannot be opened (exit 2), not one error frame
            try:
                read_image(p)
            except ImageError as e:
                raise OSError(f"{self.path}: {e}") from None
        # the frame size the container announces, before anything is decoded
        _check_video_frame(self.path, video_header_size(p), "its header announces")
        cap = cv2.VideoCapture(self.path)
        if not cap.isOpened():
            cap.release()
            raise OSError(f"{self.path}: cannot open the video (unknown format, or a "
                          "damaged or cut-short file)")
        try:  # the decoder's own size (other containers, or a stream unlike its container)
            _check_video_frame(self.path, (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0),
                                           int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0)),
                               "its decoder reports")
        except OSError:
            cap.release()
            raise
        self.cap = cap
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if 0.1 <= fps <= 1000 else 30.0
        n = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.count = int(n) if 0 < n < 1e9 else 0
        self.index = 0
        self._pending = []
        self.ended_early = None
        # a file none of whose frames decodes cannot be opened: said now, in one line
        try:
            first = self.read()
        except EndOfStream:
            first = None
        if first is None or (first.error is not None and self.ended_early == 0):
            self.close()
            why = (first.error if first is not None and first.error
                   else "no frame can be decoded (not a video, or a damaged file)")
            raise OSError(f"{self.path}: {why}")
        self._pending.insert(0, first)

    def _frame(self, img, i: int, error: str | None = None) -> RawFrame:
        self.total += 1
        t = (self.total - 1) / self.fps
        if error is not None:
            return RawFrame(None, i, media_time=t, error=error)
        try:
            bgr, notes = to_bgr8(img)
        except ImageError as e:
            return RawFrame(None, i, media_time=t, error=str(e))
        return RawFrame(bgr, i, media_time=t, notes=notes)

    def _restart(self) -> bool:
        import cv2  # deferred: heavy (`drovisio --help` must not load it)

        if not (self.loop and self.index > 0):
            return False
        self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self.lap += 1
        self.index = 0
        return True

    def read(self) -> RawFrame | None:
        import cv2  # deferred: heavy (`drovisio --help` must not load it)

        if self.cap is None:
            return None
        if self._pending:
            return self._pending.pop(0)
        ok, img = self.cap.read()
        if ok and img is not None:
            i = self.index
            self.index += 1
            return self._frame(img, i)
        if self.count and self.index < self.count:  # announced but not decodable
            first = self.index
            # a damaged frame, or the end of a cut-short file: look a few frames further
            for j in range(first + 1, min(first + 1 + MAX_BAD_FRAMES_IN_A_ROW, self.count)):
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, j)
                ok, img = self.cap.read()
                if ok and img is not None:
                    out = self._frame(None, first, "frame could not be decoded (the video is "
                                                   "damaged)")
                    self._pending = [self._frame(None, k, "frame could not be decoded (the "
                                                          "video is damaged)")
                                     for k in range(first + 1, j)] + [self._frame(img, j)]
                    self.index = j + 1
                    return out
            self.index = self.count
            self.ended_early = first
            return self._frame(None, first, (
                f"the video ends at frame {first}, {self.count - first} frames before the "
                f"{self.count} its header announces (the file is cut short or damaged from "
                "there: copy it again)" if first else
                f"no frame of the {self.count} its header announces can be decoded (the file "
                "is damaged or cut short: copy it again)"))
        if self._restart():
            ok, img = self.cap.read()
            if ok and img is not None:
                self.index = 1
                return self._frame(img, 0)
        raise EndOfStream()

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
            self.cap = None


