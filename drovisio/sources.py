"""Frame sources: camera, video file, folder of images, stream URL, recording — timestamped,
newest frame first, and never crashing on loss.

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

SOURCE strings (:func:`open_source`, the ``--source`` of ``drovisio run``): a camera index
(``0``: V4L2), a video file, a folder of images (name order), a recording folder (made by
``--record``; has ``recording.json``), or a stream URL (``rtsp://``, ``http://``, ``udp://``,
``tcp://`` …, through FFmpeg).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Literal, Protocol

import numpy as np

__all__ = [
    "CameraReader",
    "EndOfStream",
    "Frame",
    "FrameSource",
    "ImageFolderReader",
    "Pace",
    "RawFrame",
    "Reader",
    "RecordingReader",
    "SharedCamera",
    "SourceState",
    "StreamReader",
    "VideoFileReader",
    "open_source",
    "reader_for",
]

Pace = Literal["realtime", "max"]


class SourceState(str, Enum):
    STARTING = "starting"
    LIVE = "live"
    LOST = "lost"        # retrying
    ENDED = "ended"      # finite source exhausted
    STOPPED = "stopped"  # closed by us


class EndOfStream(Exception):
    """Raised by a finite reader when it has no more frames."""


@dataclass
class RawFrame:
    """What a reader returns for one frame."""

    image: np.ndarray
    index: int
    media_time: float | None = None
    """Position in the file/recording (s), used to pace playback; None for live sources."""
    name: str = ""
    t_wall: float | None = None
    """Capture time if the reader knows it better than 'now' (UNIX s)."""


@dataclass
class Frame:
    """A timestamped frame handed to the pipeline."""

    image: np.ndarray
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


class Reader(Protocol):
    """One kind of source. ``open`` raises on failure; ``read`` returns a frame, None on a
    failure (the source is lost), or raises :class:`EndOfStream` when a finite source ends."""

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
        cap = None
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

    def __init__(self, url: str, open_timeout_s: float = 5.0, read_timeout_s: float = 2.0):
        super().__init__(url)
        self.url = url
        self.open_timeout_s, self.read_timeout_s = open_timeout_s, read_timeout_s

    def _make(self):
        import cv2

        return cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(self.open_timeout_s * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.read_timeout_s * 1000)])


class VideoFileReader:
    """A video file, frame by frame; ``loop=True`` starts over at the end (demo playback)."""

    finite = True

    def __init__(self, path: str | Path, loop: bool = False):
        self.path = str(path)
        self.label = self.path
        self.loop = loop
        self.finite = not loop
        self.cap = None
        self.fps = 0.0
        self.index = 0
        self.lap = 0
        self.total = 0

    def open(self) -> None:
        import cv2

        self.close()
        if not Path(self.path).is_file():
            raise OSError(f"{self.path}: no such video file")
        cap = cv2.VideoCapture(self.path)
        if not cap.isOpened():
            cap.release()
            raise OSError(f"{self.path}: cannot open the video")
        self.cap = cap
        self.fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) or 30.0
        self.index = 0

    def read(self) -> RawFrame | None:
        if self.cap is None:
            return None
        ok, img = self.cap.read()
        if not ok or img is None:
            if self.loop and self.index > 0:
                import cv2

                self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                self.lap += 1
                self.index = 0
                ok, img = self.cap.read()
                if not ok:
                    raise EndOfStream()
            else:
                raise EndOfStream()
        i = self.index
        self.index += 1
        self.total += 1
        return RawFrame(img, i, media_time=(self.total - 1) / self.fps)

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
            self.cap = None


class ImageFolderReader:
    """The images of a folder in name order, played at ``fps``."""

    finite = True

    def __init__(self, folder: str | Path, fps: float = 10.0, loop: bool = False):
        self.folder = Path(folder)
        self.label = str(folder)
        self.fps = float(fps)
        self.loop = loop
        self.finite = not loop
        self.files: list[Path] = []
        self.i = 0

    def open(self) -> None:
        from drovisio.io_frames import list_folder

        if not self.folder.is_dir():
            raise OSError(f"{self.folder}: no such folder")
        self.files = list_folder(self.folder)
        if not self.files:
            raise OSError(f"{self.folder}: no images in the folder")
        self.i = 0

    def read(self) -> RawFrame | None:
        from drovisio.io_frames import read_image

        while True:
            if self.i >= len(self.files):
                if not self.loop:
                    raise EndOfStream()
                self.i = 0
            f = self.files[self.i]
            i = self.i
            self.i += 1
            img, err, _notes = read_image(f)
            if img is not None:
                return RawFrame(img, i, media_time=i / self.fps, name=f.name)
            # an unreadable file is skipped, not a loss of the source

    def close(self) -> None:
        pass


class RecordingReader:
    """A folder written by ``drovisio run --record DIR``, played with its recorded timing."""

    finite = True

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
        import cv2

        if self.i >= len(self.entries):
            if not self.loop:
                raise EndOfStream()
            self.i = 0
            self.lap += 1
        e = self.entries[self.i]
        self.i += 1
        img = cv2.imread(str(self.folder / e["image"]), cv2.IMREAD_COLOR)
        if img is None:
            return self.read() if self.i < len(self.entries) else None
        t0 = self.entries[0]["t"]
        span = self.entries[-1]["t"] - t0 + 0.1
        return RawFrame(img, int(e["frame"]), media_time=e["t"] - t0 + self.lap * span,
                        name=e["image"])

    def close(self) -> None:
        pass


def _is_url(s: str) -> bool:
    return "://" in s and not s.startswith("file://")


def reader_for(source: str, loop: bool = False, folder_fps: float = 10.0) -> Reader:
    """The reader of a SOURCE string (see the module doc)."""
    from drovisio.io_frames import VIDEO_EXTS

    s = str(source).strip()
    if s.isdigit():
        return CameraReader(int(s))
    if s.startswith("/dev/video"):
        return CameraReader(int(s[len("/dev/video"):]))
    if _is_url(s):
        return StreamReader(s)
    s = s.removeprefix("file://")
    p = Path(s)
    if p.is_dir():
        if (p / "recording.json").is_file():
            return RecordingReader(p, loop=loop)
        return ImageFolderReader(p, fps=folder_fps, loop=loop)
    if p.suffix.lower() in VIDEO_EXTS or p.is_file():
        return VideoFileReader(p, loop=loop)
    # not there (yet): treat as a video file; FrameSource reports it lost and retries
    return VideoFileReader(p, loop=loop)


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

    def to_json(self) -> dict:
        return {"label": self.label, "state": self.state,
                "for_s": round(time.monotonic() - self.since, 3), "frames": self.frames,
                "dropped": self.dropped, "reconnects": self.reconnects, "error": self.error}


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
                            bool(getattr(self.reader, "finite", False)))

    def now(self) -> float:
        """The source's clock now (monotonic; the media clock for ``pace="max"`` files)."""
        return self._mono() + self._clock_offset

    @property
    def ended(self) -> bool:
        """True once a finite source is exhausted and its last frame was taken."""
        return self._state in (SourceState.ENDED, SourceState.STOPPED) and self._slot is None

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
        if self._state != SourceState.ENDED:
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
                if self._state in (SourceState.ENDED, SourceState.STOPPED) or self._stop.is_set():
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
                    self._set_state(SourceState.LOST, f"{type(e).__name__}: {e}")
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
                self._error = f"{type(e).__name__}: {e}"
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
                if t_start is None:
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
                      name=raw.name)
            self._clock_offset = t_mono - now_m
            self.frames += 1
            self._set_state(SourceState.LIVE)
            self._publish(f, wait_for_consumer=pace_max and raw.media_time is not None)
        try:
            r.close()
        except Exception:  # noqa: BLE001
            pass
        if self._state != SourceState.ENDED:
            self._set_state(SourceState.STOPPED)


def open_source(source: str, pace: Pace = "realtime", loop: bool = False) -> FrameSource:
    """A started :class:`FrameSource` for a SOURCE string."""
    return FrameSource(reader_for(source, loop=loop), pace=pace).start()
