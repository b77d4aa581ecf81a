"""The calibration page's live camera: a worker thread that takes the camera's frames (through
:class:`drovisio.sources.FrameSource`), hands each to the session, and keeps the latest
annotated frame for the page; the camera's status in plain words.

The worker starts on a request (:meth:`CameraFeed.touch`) and stops, releasing the camera,
after ``idle_timeout`` seconds without one (so the camera is free for other parts of the
tool). When the camera gives no frame, the page is told "camera disconnected — retrying" and
the source is reopened with a growing pause (0.5 s → 4 s).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable

import numpy as np

from drovisio._threads import join_thread
from drovisio.sources import FrameSource, Reader, SourceState
from webtool.calibration.camera import BACKOFF_S, CameraStatus, FreshReader
from webtool.calibration.feedback import saved_views

__all__ = ["CameraFeed"]


class CameraFeed:
    """The camera worker of one calibration service (see the module docstring).

    Args:
        factory: Makes a frame source (a fresh reader per opening).
        on_frame: Called with each camera frame (BGR (H, W, 3) uint8) in the worker thread;
            it publishes the annotated frame with :meth:`publish`.
        views: The number of views kept (said when the camera is lost: they are saved).
        on_read_error: Told what a failing read raised (shown as the feedback's detail).
        idle_timeout: Seconds without a request after which the camera is released.
    """

    def __init__(self, factory: Callable[[], Reader], on_frame: Callable[[np.ndarray], None],
                 views: Callable[[], int], on_read_error: Callable[[str], None],
                 idle_timeout: float = 45.0) -> None:
        self._factory = factory
        self._on_frame = on_frame
        self._views = views
        self._on_read_error = on_read_error
        self.idle_timeout = float(idle_timeout)
        self._lock = threading.RLock()
        self.cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.closed = False
        self._last_request = time.monotonic()
        self.status = CameraStatus()
        self.source_label = ""
        self.latest_raw: np.ndarray | None = None
        self.waiting_since: float | None = None
        """When the worker began waiting for the camera's next frame (monotonic seconds;
        None while it works on one)."""
        self.latest_jpeg: bytes | None = None
        self.seq = 0
        self.frame_size: tuple[int, int] | None = None

    @property
    def message(self) -> str:
        """What the camera is doing, for people ("Camera disconnected — retrying…")."""
        return self.status.message

    # ----------------------------------------------------------------------- lifecycle
    def touch(self) -> None:
        """A request came in: keep the camera running (start it if it was stopped)."""
        self._last_request = time.monotonic()
        if self.closed:
            return
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._stop.clear()
                self.status = CameraStatus("starting", "Starting the camera…", time.time())
                self._thread = threading.Thread(target=self._run, daemon=True,
                                                name="calibration-camera")
                self._thread.start()

    def close(self) -> None:
        """Stop the worker and wait for it (app shutdown): it may be inside OpenCV with a
        frame."""
        self.closed = True
        self._stop.set()
        join_thread(self._thread, "reading the calibration camera")
        with self.cond:
            self.cond.notify_all()

    # ----------------------------------------------------------------------- frames
    def publish(self, frame: np.ndarray, jpeg: bytes, then: Callable[[], None]) -> None:
        """Make ``frame`` (and its annotated ``jpeg``) the latest; ``then()`` runs under the
        same lock, before anyone waiting is woken."""
        with self.cond:
            self.latest_raw = frame
            self.latest_jpeg = jpeg
            self.seq += 1
            self.frame_size = (frame.shape[1], frame.shape[0])
            then()
            self.cond.notify_all()

    async def latest_frame(self, after: int = -1, wait: float = 1.0) -> tuple[bytes | None, int]:
        """The latest annotated frame (JPEG), waiting up to ``wait`` s for one newer than
        ``after`` (or for the first one while the camera starts); (None, seq) when there is
        no live picture (camera lost, or still starting when the wait ends).

        Waits on the event loop, like the designer's long poll: a page waiting for its next
        frame must not hold one of the server's worker threads (forty waiting requests would
        stall every other route)."""
        deadline = time.monotonic() + max(0.0, wait)
        while (self.seq <= max(after, 0) and self.status.state in ("ok", "starting")
               and not self.closed and time.monotonic() < deadline):
            await asyncio.sleep(0.05)
        with self.cond:  # held by the worker only while it swaps the latest frame
            if self.status.state != "ok":
                return None, self.seq
            return self.latest_jpeg, self.seq

    def latest(self) -> tuple[np.ndarray | None, float]:
        """The latest camera frame, and how long (seconds) the camera has kept the worker
        waiting for the next one: 0 while the worker works on a frame, however slowly a busy
        machine does it (the camera is delivering)."""
        since = self.waiting_since
        with self.cond:
            return self.latest_raw, 0.0 if since is None else time.monotonic() - since

    # ----------------------------------------------------------------------- worker
    def _set_state(self, state: str, message: str) -> None:
        with self._lock:
            c = self.status
            if c.state != state:
                self.status = CameraStatus(state, message, time.time(),
                                           c.failures if state == "disconnected" else 0)
            else:
                c.message = message

    def _idle(self) -> bool:
        return time.monotonic() - self._last_request > self.idle_timeout

    def _run(self) -> None:
        """The worker: frames from the camera to the session until nobody watches."""
        reader = FreshReader(self._factory)
        source = FrameSource(reader, pace="max", backoff=BACKOFF_S).start()
        reported = 0  # losses already said on the page
        try:
            while not self._stop.is_set():
                if self._idle():
                    self._set_state("stopped", "Camera paused: nobody is watching this page.")
                    break
                if self.waiting_since is None:
                    self.waiting_since = time.monotonic()
                frame = source.get(timeout=0.25)
                if frame is None:
                    if source.state is SourceState.LOST and reader.losses != reported:
                        reported = reader.losses
                        self._lost(reader)
                    continue
                self.waiting_since = None
                reported = reader.losses
                if frame.image is None:   # one bad frame: not a lost camera
                    continue
                self.source_label = reader.label
                if self.status.state != "ok":
                    self._set_state("ok", "Camera connected.")
                self._on_frame(frame.image)
        finally:
            source.stop()
            with self.cond:
                self.cond.notify_all()

    def _lost(self, reader: FreshReader) -> None:
        """Say that the camera is lost (the frame source is reopening it)."""
        if reader.read_error is not None:
            self._on_read_error(reader.read_error)
            reader.read_error = None
        self.source_label = reader.label
        with self._lock:
            fails = self.status.failures + 1
        detail = f" ({reader.problem})" if reader.problem else ""
        if self.seq:
            msg = f"Camera disconnected — retrying…{detail}."
        else:
            msg = (f"No picture from {self.source_label or 'the camera'} — retrying…{detail}. "
                   "Check that the camera is plugged in.")
        self._set_state("disconnected", (msg + " " + saved_views(self._views())).strip())
        with self._lock:
            self.status.failures = fails
        with self.cond:
            self.cond.notify_all()
