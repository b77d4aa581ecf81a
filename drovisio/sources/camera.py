"""V4L2 cameras: one device opened once per process (:class:`SharedCamera`) and read by any
number of readers (:class:`CameraReader`), so that the web tool's calibration page and live
view can watch the same camera."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drovisio._threads import join_thread
from drovisio.raw_frame import RawFrame

__all__ = ["CameraReader", "SharedCamera", "open_v4l2"]


def open_v4l2(index: int, width: int | None = None, height: int | None = None,
              fps: float | None = None) -> Any:
    """``cv2.VideoCapture`` of V4L2 camera ``index``, set to deliver its newest frame."""
    import cv2  # deferred: heavy (`drovisio --help` must not load it)

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

    def __init__(self, index: int, width: int | None = None, height: int | None = None,
                 fps: float | None = None):
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
    def acquire(cls, index: int, width: int | None = None, height: int | None = None,
                fps: float | None = None) -> SharedCamera:
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
        # a read in progress is in OpenCV, and the device is free only once it is closed
        join_thread(thread, f"reading camera {self.index}")

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


