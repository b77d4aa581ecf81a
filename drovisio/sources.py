"""Frame sources: camera, video file, folder of images, stream URL, recording, sample
playback — the one way Drovisio reads frames (the pipeline, the web tool's pages, the command
line and the benchmarks all use these readers).

A source is a :class:`Reader` (opens, reads one frame, closes; knows nothing about threads)
wrapped in a :class:`FrameSource`, which reads in its own thread and keeps **only the newest
frame**: a slow detector never makes a queue grow behind it; frames it had no time for are
counted as dropped. On loss (camera unplugged, stream down, read error) the thread closes
the reader and reopens it with a growing pause (0.1 s doubling to 2 s), reports the state
(:class:`SourceState`) and the last error, and never raises.

Timestamps: each :class:`Frame` carries its capture time twice, ``t_mono``
(``time.monotonic()``, for ages and latencies) and ``t_wall`` (UNIX time, for outputs), taken
when the reader returned the frame. Files and recordings are *played* like a camera
(``pace="realtime"``: at their own frame rate, dropping frames when the consumer is slow) or
as fast as the consumer takes them without dropping any (``pace="max"``).

A V4L2 camera is opened once per process (:class:`SharedCamera`) and shared by all its
readers, so that the web tool's calibration page and live view can watch the same camera.

A frame that cannot be decoded (a damaged frame of a video, an unreadable image in a folder)
is not a loss of the source: the reader returns a :class:`RawFrame` carrying ``error``, the
batch iteration of the command line (:func:`iter_inputs`) turns it into an ``"error"`` line, and
:class:`FrameSource` hands it over too (the pipeline reports it). A *finite* source (file,
folder, recording) that cannot be opened is not retried: it ends in :attr:`SourceState.FAILED`
with the reason; cameras and stream URLs keep reconnecting and say so in their state.

SOURCE strings (:func:`reader_for`, the ``--source`` of ``drovisio run``): a camera index
(``0``: V4L2), a video file, a folder of images (name order), a recording folder (made by
``--record``; has ``recording.json``), or a stream URL (``rtsp://``, ``http://``, ``udp://``,
``tcp://`` …, through FFmpeg).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from drovisio.errors import LIMITS, InputError
from drovisio.images import (
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    ImageError,
    check_frame_size,
    is_video_file,
    read_image,
    to_bgr8,
    video_header_size,
)
from drovisio.raw_frame import EndOfStream, RawFrame

__all__ = [
    "CameraReader",
    "EndOfStream",
    "Frame",
    "FrameItem",
    "FrameSource",
    "ImageFolderReader",
    "Pace",
    "PlaybackReader",
    "RawFrame",
    "Reader",
    "RecordingReader",
    "SharedCamera",
    "SourceState",
    "StreamReader",
    "VideoFileReader",
    "iter_inputs",
    "list_folder",
    "open_source",
    "reader_for",
]

Pace = Literal["realtime", "max"]


class SourceState(str, Enum):
    STARTING = "starting"
    LIVE = "live"
    LOST = "lost"        # retrying
    ENDED = "ended"      # finite source exhausted
    FAILED = "failed"    # finite source that could not be opened (not retried)
    STOPPED = "stopped"  # closed by us


@dataclass
class Frame:
    """A timestamped frame handed to the pipeline."""

    image: np.ndarray | None
    """None when ``error`` says why this frame could not be decoded."""
    index: int
    t_mono: float
    t_wall: float
    seq: int = 0
    """Running number of frames produced by this FrameSource (over reconnections)."""
    t_read: float = 0.0
    """Monotonic time the frame was handed over (latency reference). Equal to ``t_mono``
    except for files played with ``pace="max"``, whose ``t_mono``/``t_wall`` follow the
    media clock (so that tracking sees the video's own timing)."""
    media_time: float | None = None
    name: str = ""
    error: str | None = None


class Reader(Protocol):
    """One kind of source. ``open`` raises on failure; ``read`` returns a frame (possibly one
    carrying ``error``), None on a failure (the source is lost), or raises
    :class:`EndOfStream` when a finite source ends.

    Attributes:
        label: What to call the source in messages.
        finite: True for files, folders and recordings (they end; they are not retried).
        lossless: True when every frame must reach the consumer (a playback paced by its
            consumer); :class:`FrameSource` then waits instead of dropping.
    """

    label: str
    finite: bool

    def open(self) -> None: ...

    def read(self) -> RawFrame | None: ...

    def close(self) -> None: ...


# ------------------------------------------------------------------------------------------
# Readers
# ------------------------------------------------------------------------------------------


class _CaptureReader:
    finite = False
    lossless = False

    def __init__(self, label: str):
        self.label = label
        self.cap = None
        self.count = 0

    def _make(self):  # pragma: no cover - overridden
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


def open_v4l2(index: int, width: int | None = None, height: int | None = None,
              fps: float | None = None):
    """``cv2.VideoCapture`` of V4L2 camera ``index``, set to deliver its newest frame."""
    import cv2

    cap = cv2.VideoCapture(index, cv2.CAP_V4L2)
    if cap.isOpened():
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not a driver queue
        if width and height:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        if fps:
            cap.set(cv2.CAP_PROP_FPS, fps)
    return cap


class SharedCamera:
    """One V4L2 camera, opened once per process and shared by all its users.

    A camera device can be opened by one reader only; the web tool's calibration page and
    live view (and anything else in the process) each want frames from it. The first
    :meth:`acquire` of an index starts a thread that opens the device and keeps its newest
    frame; every user waits for frames newer than the last it got (:meth:`next`); the last
    :meth:`release` stops the thread and closes the device. On loss the thread reopens the
    device with a growing pause, like :class:`FrameSource`. Size and rate settings are those of
    the first user.
    """

    _registry: dict[int, SharedCamera] = {}
    _registry_lock = threading.Lock()
    opener: Callable[..., object] = staticmethod(open_v4l2)
    """Makes the capture (tests put a fake here)."""

    def __init__(self, index: int, width=None, height=None, fps=None):
        self.index = index
        self._args = (width, height, fps)
        self._users = 0
        self._cond = threading.Condition()
        self._frame: np.ndarray | None = None
        self._seq = 0
        self._t_wall = 0.0
        self.lost = False
        """True while the device is closed after a failure (users get None)."""
        self.error: str | None = None
        self.opens = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @classmethod
    def acquire(cls, index: int, width=None, height=None, fps=None) -> SharedCamera:
        with cls._registry_lock:
            cam = cls._registry.get(index)
            if cam is None:
                cam = cls._registry[index] = SharedCamera(index, width, height, fps)
            cam._users += 1
            if cam._thread is None:
                cam._stop.clear()
                cam._thread = threading.Thread(target=cam._run, daemon=True,
                                               name=f"shared-camera-{index}")
                cam._thread.start()
            return cam

    def release(self) -> None:
        with SharedCamera._registry_lock:
            self._users -= 1
            if self._users > 0:
                return
            SharedCamera._registry.pop(self.index, None)
            self._stop.set()
            thread, self._thread = self._thread, None
        with self._cond:
            self._cond.notify_all()
        if thread is not None:
            thread.join(3.0)

    @property
    def users(self) -> int:
        return self._users

    def _run(self) -> None:
        cap: Any = None
        pause = 0.1
        try:
            while not self._stop.is_set():
                if cap is None:
                    try:
                        cap = SharedCamera.opener(self.index, *self._args)
                        ok = cap is not None and cap.isOpened()
                    except Exception as e:  # noqa: BLE001 - any failure: retry later
                        ok, self.error = False, str(e)
                    if not ok:
                        if cap is not None:
                            cap.release()
                        cap = None
                        self._set_lost(self.error or f"cannot open camera {self.index}")
                        self._stop.wait(pause)
                        pause = min(pause * 2, 2.0)
                        continue
                    self.opens += 1
                ok, img = cap.read()
                if not ok or img is None or img.size == 0:
                    cap.release()
                    cap = None
                    self._set_lost(f"camera {self.index} stopped delivering frames")
                    continue
                pause = 0.1
                with self._cond:
                    self._frame, self._t_wall = img, time.time()
                    self._seq += 1
                    self.lost, self.error = False, None
                    self._cond.notify_all()
        finally:
            if cap is not None:
                cap.release()

    def _set_lost(self, error: str) -> None:
        with self._cond:
            self.lost, self.error = True, error
            self._cond.notify_all()

    def next(self, after: int, timeout: float = 2.0) -> tuple[np.ndarray, int, float] | None:
        """The newest frame with a sequence number above ``after``, as (a copy of the image,
        its number, its capture time); None when the camera is lost or nothing came within
        ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                if self.lost or self._stop.is_set():
                    return None            # never an old frame of a camera that is gone
                if self._seq > after and self._frame is not None:
                    return self._frame.copy(), self._seq, self._t_wall
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)


class CameraReader:
    """A V4L2 camera by index (``/dev/videoN``), through the process's
    :class:`SharedCamera` (so that several readers can watch one camera)."""

    finite = False
    lossless = False

    def __init__(self, index: int, width: int | None = None, height: int | None = None,
                 fps: float | None = None):
        self.label = f"camera {index}"
        self.index, self.width, self.height, self.fps = index, width, height, fps
        self.count = 0
        self._cam: SharedCamera | None = None
        self._seq = 0

    def open(self) -> None:
        self.close()
        cam = SharedCamera.acquire(self.index, self.width, self.height, self.fps)
        got = cam.next(cam._seq - 1 if cam._seq else 0, timeout=3.0)
        if got is None:
            err = cam.error
            cam.release()
            raise OSError(err or f"cannot open {self.label}")
        self._cam, self._seq = cam, got[1] - 1   # the frame just seen is read next

    def read(self) -> RawFrame | None:
        if self._cam is None:
            return None
        got = self._cam.next(self._seq)
        if got is None:
            return None
        img, self._seq, t_wall = got
        self.count += 1
        return RawFrame(img, self.count - 1, t_wall=t_wall)

    def close(self) -> None:
        if self._cam is not None:
            cam, self._cam = self._cam, None
            cam.release()


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
        try:
            super().open()
        except OSError:
            raise OSError(f"cannot open {self.url}: no video stream there within "
                          f"{self.open_timeout_s:g} s (check the address, and that the camera "
                          "is on and streaming)") from None

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

    def _make(self):
        import cv2

        return cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(self.open_timeout_s * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.read_timeout_s * 1000)])


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
        import cv2

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
        import cv2

        if not (self.loop and self.index > 0):
            return False
        self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self.lap += 1
        self.index = 0
        return True

    def read(self) -> RawFrame | None:
        import cv2

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


def list_folder(folder: Path) -> list[Path]:
    """Images and videos of a folder (not recursive), in name order; hidden files skipped."""
    items = [p for p in folder.iterdir()
             if p.is_file() and not p.name.startswith(".")
             and p.suffix.lower() in IMAGE_SUFFIXES | VIDEO_SUFFIXES]
    return sorted(items, key=lambda p: p.name)


class ImageFolderReader:
    """The images of a folder in name order, played at ``fps``; an unreadable image is a
    frame carrying ``error`` (the source goes on)."""

    finite = True
    lossless = False

    def __init__(self, folder: str | Path, fps: float = 10.0, loop: bool = False):
        self.folder = Path(folder)
        self.label = str(folder)
        self.fps = float(fps)
        self.loop = loop
        self.finite = not loop
        self.files: list[Path] = []
        self.i = 0

    def open(self) -> None:
        if not self.folder.is_dir():
            raise OSError(f"{self.folder}: no such folder")
        self.files = [f for f in list_folder(self.folder) if not is_video_file(f)]
        if not self.files:
            raise OSError(f"{self.folder}: no images in the folder (looked for "
                          f"{', '.join(sorted(IMAGE_SUFFIXES))})")
        self.i = 0

    def read(self) -> RawFrame | None:
        if self.i >= len(self.files):
            if not self.loop:
                raise EndOfStream()
            self.i = 0
        f = self.files[self.i]
        i = self.i
        self.i += 1
        try:
            img, notes = read_image(f)
        except ImageError as e:
            return RawFrame(None, i, media_time=i / self.fps, name=f.name, error=str(e))
        return RawFrame(img, i, media_time=i / self.fps, name=f.name, notes=notes)

    def close(self) -> None:
        pass


class RecordingReader:
    """A folder written by ``drovisio run --record DIR``, played with its recorded timing."""

    finite = True
    lossless = False

    def __init__(self, folder: str | Path, loop: bool = False):
        self.folder = Path(folder)
        self.label = f"recording {folder}"
        self.loop = loop
        self.finite = not loop
        self.entries: list[dict] = []
        self.i = 0
        self.lap = 0

    def open(self) -> None:
        from drovisio.recording import read_index

        self.entries = read_index(self.folder)
        if not self.entries:
            raise OSError(f"{self.folder}: the recording holds no frames")
        self.i = 0

    def read(self) -> RawFrame | None:
        if self.i >= len(self.entries):
            if not self.loop:
                raise EndOfStream()
            self.i = 0
            self.lap += 1
        e = self.entries[self.i]
        self.i += 1
        t0 = self.entries[0]["t"]
        span = self.entries[-1]["t"] - t0 + 0.1
        t = e["t"] - t0 + self.lap * span
        try:
            img, notes = read_image(self.folder / e["image"])
        except ImageError as err:
            return RawFrame(None, int(e["frame"]), media_time=t, name=e["image"],
                            error=str(err))
        return RawFrame(img, int(e["frame"]), media_time=t, name=e["image"], notes=notes)

    def close(self) -> None:
        pass


class PlaybackReader:
    """Still images played as if a camera filmed them, looping, at up to ``fps`` frames per
    second (the calibration page's sample session, or a folder of calibration photos).

    Each image is one board placement, held for ``seconds_per_view``: first the board "moves"
    there (a quarter of the time: a blurred blend sliding from the previous image), then it is
    held still (the image itself, shifted by a random sub-pixel jitter, with a little sensor
    noise), so that the sharpness and stillness gates see what a real camera would give. On a
    busy machine a placement is held for at least ``min_still_frames`` frames, so that no
    placement is skipped however slowly frames are processed (``lossless``: the consumer's
    pace drives it).
    """

    MOVE_FRACTION = 0.25
    finite = False
    lossless = True

    def __init__(self, files: list[Path], seconds_per_view: float = 1.5, fps: float = 12.0,
                 seed: int = 0, label: str = "sample session", min_still_frames: int = 3
                 ) -> None:
        if not files:
            raise OSError("no images to play")
        self.files = list(files)
        spv = max(0.05, float(seconds_per_view))
        self.move_s = self.MOVE_FRACTION * spv
        self.still_s = spv - self.move_s
        self.min_still = max(2, int(min_still_frames))
        self.period = 1.0 / max(1.0, float(fps))
        self.label = label
        self._rng = np.random.default_rng(seed)
        # a few precomputed noise fields (drawing fresh Gaussian noise costs more than the rest)
        self._noise: list[np.ndarray] = []
        self._next = time.monotonic()
        self._k = 0                # index of the placement shown
        self._moving = False       # first placement: already there
        self._since = time.monotonic()
        self._n = 0                # frames given in the current phase
        self._count = 0
        self._cache: dict[int, np.ndarray] = {}

    @classmethod
    def from_folder(cls, folder: Path, **kw) -> PlaybackReader:
        files = [f for f in list_folder(Path(folder)) if not is_video_file(f)]
        return cls(files, label=kw.pop("label", f"images in {folder}"), **kw)

    def open(self) -> None:
        pass

    def _image(self, k: int) -> np.ndarray:
        k %= len(self.files)
        if k not in self._cache:
            if len(self._cache) >= 2:  # only the current and the previous placement are kept
                self._cache.pop(next(iter(self._cache)))
            try:
                self._cache[k] = read_image(self.files[k])[0]
            except ImageError as e:
                raise OSError(f"cannot read {self.files[k]}: {e}") from None
        return self._cache[k]

    def _advance(self, now: float) -> None:
        if self._moving:
            if now - self._since >= self.move_s and self._n >= 1:
                self._moving, self._since, self._n = False, now, 0
        elif now - self._since >= self.still_s and self._n >= self.min_still:
            self._k += 1
            self._moving, self._since, self._n = True, now, 0

    def _noisy(self, img: np.ndarray) -> np.ndarray:
        if not self._noise or self._noise[0].shape != img.shape:
            self._noise = [np.round(self._rng.normal(0.0, 1.5, img.shape)).astype(np.int16)
                           for _ in range(3)]
        noise = self._noise[int(self._rng.integers(len(self._noise)))]
        return np.clip(img.astype(np.int16) + noise, 0, 255).astype(np.uint8)

    def _picture(self, now: float) -> np.ndarray:
        import cv2

        cur = self._image(self._k)
        h, w = cur.shape[:2]
        if self._moving:
            prev = self._image(self._k - 1)
            if prev.shape != cur.shape:
                prev = cv2.resize(prev, (w, h))
            a = min(1.0, (now - self._since) / self.move_s, 0.5 * self._n)
            mixed = cv2.addWeighted(prev, 1.0 - a, cur, a, 0.0)
            dx = 4.0 + (1.0 - a) * 12.0
            m = np.array([[1, 0, dx], [0, 1, 0.3 * dx]], np.float32)
            mixed = cv2.warpAffine(mixed, m, (w, h), borderMode=cv2.BORDER_REPLICATE)
            return cv2.blur(mixed, (17, 1))  # horizontal motion blur
        dx, dy = self._rng.uniform(-0.2, 0.2, 2)
        m = np.array([[1, 0, dx], [0, 1, dy]], np.float32)
        img = cv2.warpAffine(cur, m, (w, h), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
        return self._noisy(img)

    def read(self) -> RawFrame | None:
        now = time.monotonic()
        if self._next > now:
            time.sleep(self._next - now)
        now = time.monotonic()
        self._next = max(self._next + self.period, now)
        self._advance(now)
        self._n += 1
        try:
            img = self._picture(now)
        except OSError:
            return None
        self._count += 1
        return RawFrame(img, self._count - 1, name=self.files[self._k % len(self.files)].name)

    def close(self) -> None:
        self._cache.clear()


def _is_url(s: str) -> bool:
    return "://" in s and not s.startswith("file://")


def _check_url(url: str) -> None:
    """A stream URL that can never connect (no host, a port that is no port, broken
    brackets) is refused now; a sound one is retried for as long as it is down.

    Raises:
        InputError: naming ``--source`` and what is wrong.
    """
    from urllib.parse import urlsplit

    from drovisio.errors import one_line

    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 - parsing the port is what may fail
    except ValueError as e:
        raise InputError(f"{one_line(url, 200)}: --source: not a usable URL ({e}); give "
                         "e.g. rtsp://HOST:554/stream or http://HOST:8080/video") from None
    if parts.scheme.lower() in ("http", "https", "rtsp", "rtsps", "rtmp", "tcp") \
            and not parts.hostname:
        raise InputError(f"{one_line(url, 200)}: --source: the URL names no host; give "
                         f"e.g. {parts.scheme}://HOST:PORT/...")


def _camera_index(s: str) -> int | None:
    if s.isdigit():
        return int(s)
    if s.startswith("/dev/video") and s[len("/dev/video"):].isdigit():
        return int(s[len("/dev/video"):])
    return None


def reader_for(source: str, loop: bool = False, folder_fps: float = 10.0) -> Reader:
    """The reader of a SOURCE string (see the module doc).

    Raises:
        InputError: a file or folder that does not exist, or that is not a video, an image
            folder or a recording (cameras and URLs are not checked: they may come later).
    """
    s = str(source).strip()
    cam = _camera_index(s)
    if cam is not None:
        return CameraReader(cam)
    if _is_url(s):
        _check_url(s)
        return StreamReader(s)
    s = s.removeprefix("file://")
    p = Path(s)
    if p.is_dir():
        if (p / "recording.json").is_file():
            return RecordingReader(p, loop=loop)
        return ImageFolderReader(p, fps=folder_fps, loop=loop)
    if not p.exists():
        raise InputError(f"{s}: --source: no such file or folder (give a camera index such "
                         "as 0, a video file, a folder of images or a stream URL)")
    if not p.is_file():
        raise InputError(f"{s}: --source: not a regular file (a pipe or a device); give a "
                         "camera index (0) for a camera")
    if p.suffix.lower() == ".mcap":   # an MCAP recording (drovisio run --record FILE.mcap)
        from drovisio.ros.mcap_source import McapReader

        return McapReader(p, loop=loop)
    return VideoFileReader(p, loop=loop)


# ------------------------------------------------------------------------------------------
# Batch iteration (the command line's inputs)
# ------------------------------------------------------------------------------------------


@dataclass
class FrameItem:
    """One frame of the command line's inputs, or the reason it could not be read."""

    file: str
    """The path as given (a folder's image: the folder as given joined with its name; a
    video's frame: the video path)."""
    frame: int
    """The frame's index in its video; for images, their running index over the run."""
    image: np.ndarray | None = None
    """BGR uint8 (H, W, 3), or None when ``error`` is set."""
    error: str | None = None
    notes: list[str] = field(default_factory=list)
    source: str = ""
    """The input (file, folder or video) this frame came from, as given."""
    is_video: bool = False


def _video_items(path: str, source: str) -> Iterator[FrameItem]:
    reader = VideoFileReader(path)
    try:
        reader.open()
    except OSError as e:
        yield FrameItem(path, 0, error=str(e).removeprefix(f"{path}: "), source=source,
                        is_video=True)
        return
    n = 0
    try:
        while True:
            try:
                raw = reader.read()
            except EndOfStream:
                break
            if raw is None:
                break
            n += 1
            yield FrameItem(path, raw.index, raw.image, raw.error, raw.notes, source=source,
                            is_video=True)
    finally:
        reader.close()
    if n == 0:
        yield FrameItem(path, 0, error="video has no readable frame", source=source,
                        is_video=True)


def iter_inputs(inputs: Iterable[str], messages: list[str] | None = None
                ) -> Iterator[FrameItem]:
    """The frames of the command line's inputs, in order (a folder's images and videos in
    name order, a video frame by frame), never raising for a bad input.

    Args:
        inputs: Image files, folders or videos.
        messages: Problems that produce no frame at all (an empty folder) are appended here.

    Yields:
        :class:`FrameItem`; unreadable frames carry ``error`` instead of an image.
    """
    image_index = 0
    for inp in inputs:
        p = Path(inp)
        if p.is_dir():
            files = list_folder(p)
            if not files:
                if messages is not None:
                    messages.append(f"{inp}: folder has no images or videos (looked for "
                                    f"{', '.join(sorted(IMAGE_SUFFIXES | VIDEO_SUFFIXES))})")
                continue
            for f in files:
                shown = os.path.join(inp, f.name)
                if is_video_file(f):
                    yield from _video_items(shown, inp)
                    continue
                yield _image_item(f, shown, image_index, inp)
                image_index += 1
            continue
        if p.exists() and p.is_file() and (is_video_file(p) or not _looks_like_image(p)):
            yield from _video_items(inp, inp)
            continue
        yield _image_item(p, inp, image_index, inp)
        image_index += 1


def _looks_like_image(p: Path) -> bool:
    """An image by its suffix, or (unknown suffix) by a header Pillow or OpenCV knows."""
    if p.suffix.lower() in IMAGE_SUFFIXES:
        return True
    import cv2

    return bool(cv2.haveImageReader(str(p)))


def _image_item(path: Path, shown: str, index: int, source: str) -> FrameItem:
    try:
        img, notes = read_image(path)
    except ImageError as e:
        return FrameItem(shown, index, error=str(e), source=source)
    return FrameItem(shown, index, img, None, notes, source=source)


# ------------------------------------------------------------------------------------------
# The threaded source
# ------------------------------------------------------------------------------------------


@dataclass
class SourceStatus:
    label: str
    state: str
    since: float
    """Monotonic time of the last state change."""
    frames: int
    dropped: int
    reconnects: int
    error: str | None
    finite: bool
    frame_errors: int = 0
    """Frames that could not be decoded (handed over with their ``error``)."""

    def to_json(self) -> dict:
        return {"label": self.label, "state": self.state,
                "for_s": round(time.monotonic() - self.since, 3), "frames": self.frames,
                "dropped": self.dropped, "reconnects": self.reconnects, "error": self.error,
                "frame_errors": self.frame_errors, "finite": self.finite}


class FrameSource:
    """Reads a :class:`Reader` in a background thread; :meth:`get` gives the newest frame.

    Args:
        reader: The reader.
        pace: For finite readers, ``"realtime"`` plays at the media timing (dropping frames
            the consumer has no time for, like a camera), ``"max"`` hands every frame over as
            soon as the previous one was taken (nothing dropped). Live readers ignore it.
        backoff: (first, max) pause in seconds between reopen attempts after a loss.
        clock: (monotonic, wall) clock functions (tests).
    """

    def __init__(self, reader: Reader, pace: Pace = "realtime",
                 backoff: tuple[float, float] = (0.1, 2.0),
                 clock: tuple[Callable[[], float], Callable[[], float]] | None = None):
        self.reader = reader
        self.label = reader.label
        self.pace = pace
        self.backoff = backoff
        self._mono, self._wall = clock or (time.monotonic, time.time)
        self._cond = threading.Condition()
        self._slot: Frame | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._state = SourceState.STARTING
        self._since = self._mono()
        self._error: str | None = None
        self.frames = 0
        self.dropped = 0
        self.reconnects = 0
        self.frame_errors = 0
        self._clock_offset = 0.0

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> SourceState:
        return self._state

    def _set_state(self, s: SourceState, error: str | None = None) -> None:
        if error is not None:
            self._error = error
        if s != self._state:
            self._state = s
            self._since = self._mono()
            if s == SourceState.LIVE:
                self._error = None
            with self._cond:
                self._cond.notify_all()

    def status(self) -> SourceStatus:
        return SourceStatus(self.label, self._state.value, self._since, self.frames,
                            self.dropped, self.reconnects, self._error,
                            bool(getattr(self.reader, "finite", False)), self.frame_errors)

    def now(self) -> float:
        """The source's clock now (monotonic; the media clock for ``pace="max"`` files)."""
        return self._mono() + self._clock_offset

    @property
    def ended(self) -> bool:
        """True once a finite source is exhausted (or could not be opened) and its last frame
        was taken."""
        return self._state in _FINAL and self._slot is None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> FrameSource:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, daemon=True,
                                            name=f"source:{self.label}")
            self._thread.start()
        return self

    def stop(self, timeout: float = 3.0) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._state not in (SourceState.ENDED, SourceState.FAILED):
            self._set_state(SourceState.STOPPED)

    def __enter__(self) -> FrameSource:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ consumer
    def get(self, timeout: float | None = None) -> Frame | None:
        """The newest frame not yet taken (waits up to ``timeout``), or None."""
        deadline = None if timeout is None else self._mono() + timeout
        with self._cond:
            while self._slot is None:
                if self._state in _FINAL or self._stop.is_set():
                    return None
                remaining = None if deadline is None else deadline - self._mono()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining if remaining is not None else 0.5)
            f, self._slot = self._slot, None
            self._cond.notify_all()
            return f

    # ------------------------------------------------------------------ producer
    def _publish(self, f: Frame, wait_for_consumer: bool) -> None:
        with self._cond:
            if wait_for_consumer:
                while self._slot is not None and not self._stop.is_set():
                    self._cond.wait(0.2)
            if self._slot is not None:
                self.dropped += 1
            self._slot = f
            self._cond.notify_all()

    def _sleep(self, s: float) -> None:
        self._stop.wait(max(0.0, s))

    def _run(self) -> None:
        r = self.reader
        pace_max = self.pace == "max"  # applies to frames with a media time (files)
        lossless = bool(getattr(r, "lossless", False))
        finite = bool(getattr(r, "finite", False))
        opened = False
        delay = self.backoff[0]
        t_start = m_start = None
        w_start = 0.0
        ever_opened = False
        while not self._stop.is_set():
            if not opened:
                try:
                    r.open()
                    opened = True
                    if ever_opened:
                        self.reconnects += 1
                    ever_opened = True
                    t_start = m_start = None
                except Exception as e:  # noqa: BLE001 - any failure: retry later
                    why = str(e) if isinstance(e, OSError) else f"{type(e).__name__}: {e}"
                    if finite and not ever_opened:   # a file that is not there stays so
                        self._set_state(SourceState.FAILED, why)
                        break
                    self._set_state(SourceState.LOST, why)
                    self._sleep(delay)
                    delay = min(delay * 2, self.backoff[1])
                    continue
            try:
                raw = r.read()
            except EndOfStream:
                self._set_state(SourceState.ENDED)
                break
            except Exception as e:  # noqa: BLE001
                raw = None
                self._error = str(e) if isinstance(e, OSError) else f"{type(e).__name__}: {e}"
            if raw is None:
                self._set_state(SourceState.LOST, self._error or f"{self.label}: no frame")
                try:
                    r.close()
                except Exception:  # noqa: BLE001
                    pass
                opened = False
                self._sleep(delay)
                delay = min(delay * 2, self.backoff[1])
                continue
            delay = self.backoff[0]
            if not pace_max and raw.media_time is not None:
                now = self._mono()
                if t_start is None or m_start is None:
                    t_start, m_start = now, raw.media_time
                due = t_start + (raw.media_time - m_start)
                if due > now:
                    self._sleep(due - now)
                elif now - due > 0.5:  # far behind (slow decoding): re-anchor
                    t_start, m_start = now, raw.media_time
            if self._stop.is_set():
                break
            now_m = self._mono()
            t_mono, t_wall = now_m, raw.t_wall if raw.t_wall is not None else self._wall()
            if pace_max and raw.media_time is not None:
                if t_start is None or m_start is None:
                    t_start, m_start, w_start = now_m, raw.media_time, t_wall
                t_mono = t_start + (raw.media_time - m_start)
                t_wall = w_start + (raw.media_time - m_start)
            f = Frame(image=raw.image, index=raw.index, t_mono=t_mono, t_wall=t_wall,
                      seq=self.frames, t_read=now_m, media_time=raw.media_time,
                      name=raw.name, error=raw.error)
            self._clock_offset = t_mono - now_m
            self.frames += 1
            if raw.error is not None:
                self.frame_errors += 1
            self._set_state(SourceState.LIVE)
            self._publish(f, wait_for_consumer=lossless or (pace_max
                                                            and raw.media_time is not None))
        try:
            r.close()
        except Exception:  # noqa: BLE001
            pass
        if self._state not in (SourceState.ENDED, SourceState.FAILED):
            self._set_state(SourceState.STOPPED)


_FINAL = (SourceState.ENDED, SourceState.FAILED, SourceState.STOPPED)


def open_source(source: str, pace: Pace = "realtime", loop: bool = False) -> FrameSource:
    """A started :class:`FrameSource` for a SOURCE string."""
    return FrameSource(reader_for(source, loop=loop), pace=pace).start()
