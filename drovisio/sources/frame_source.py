"""The threaded source: a reader read in its own thread, keeping only the newest frame, with
the reconnect and back-off loop."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np

from drovisio._threads import STOP_WAIT_S, join_thread
from drovisio.errors import InputError, one_line
from drovisio.raw_frame import EndOfStream, RawFrame
from drovisio.sources.reader import Pace, Reader

__all__ = ["Frame", "FrameSource", "SourceState", "SourceStatus"]


class SourceState(str, Enum):
    """Where a :class:`FrameSource` stands (its status's ``state``)."""

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


_FINAL = (SourceState.ENDED, SourceState.FAILED, SourceState.STOPPED)


@dataclass
class SourceStatus:
    """A :class:`FrameSource`'s counters and state, for status pages and JSON."""

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

    def stop(self, timeout: float = STOP_WAIT_S) -> None:
        """Stop the reader thread and wait for it (a read in progress may be in OpenCV);
        ``timeout`` only turns a hang into a warning."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        join_thread(self._thread, f"reading {self.label}", timeout)
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
        """The reader thread: open, read, pace, hand over; on loss close, pause, reopen."""
        r = self.reader
        run = _RunState(delay=self.backoff[0],
                        pace_max=self.pace == "max",  # applies to frames with a media time
                        lossless=bool(getattr(r, "lossless", False)),
                        finite=bool(getattr(r, "finite", False)))
        while not self._stop.is_set():
            if not run.opened:
                step = self._open(run)
                if step is _Step.STOP:
                    break
                if step is _Step.RETRY:
                    continue
            try:
                raw = r.read()
            except EndOfStream:
                self._set_state(SourceState.ENDED)
                break
            except Exception as e:  # noqa: BLE001 - any failure: the source is lost
                if run.finite:   # reopened, a file would play again from its start: it ends
                    self._set_state(SourceState.FAILED, _why(e))
                    break
                raw = None
                self._error = _why(e)
            if raw is None:
                self._lose(run)
                continue
            run.delay = self.backoff[0]
            if not run.pace_max and raw.media_time is not None:
                self._pace_realtime(run, raw.media_time)
            if self._stop.is_set():
                break
            self._hand_over(run, raw)
        try:
            r.close()
        except Exception:  # noqa: BLE001
            pass
        if self._state not in (SourceState.ENDED, SourceState.FAILED):
            self._set_state(SourceState.STOPPED)

    def _open(self, run: _RunState) -> _Step:
        """Open the reader; a finite source that never opened fails for good, anything else
        is retried after a growing pause."""
        try:
            self.reader.open()
        except Exception as e:  # noqa: BLE001 - any failure: retry later
            why = _why(e)
            if run.finite and not run.ever_opened:   # a file that is not there stays so
                self._set_state(SourceState.FAILED, why)
                return _Step.STOP
            self._set_state(SourceState.LOST, why)
            self._back_off(run)
            return _Step.RETRY
        run.opened = True
        if run.ever_opened:
            self.reconnects += 1
        run.ever_opened = True
        run.t_start = run.m_start = None
        return _Step.READ

    def _lose(self, run: _RunState) -> None:
        """The reader gave no frame: report the loss, close it and pause before reopening."""
        self._set_state(SourceState.LOST, self._error or f"{self.label}: no frame")
        try:
            self.reader.close()
        except Exception:  # noqa: BLE001
            pass
        run.opened = False
        self._back_off(run)

    def _back_off(self, run: _RunState) -> None:
        self._sleep(run.delay)
        run.delay = min(run.delay * 2, self.backoff[1])

    def _pace_realtime(self, run: _RunState, media_time: float) -> None:
        """Wait until a file's frame is due at its media timing (``pace="realtime"``)."""
        now = self._mono()
        if run.t_start is None or run.m_start is None:
            run.t_start, run.m_start = now, media_time
        due = run.t_start + (media_time - run.m_start)
        if due > now:
            self._sleep(due - now)
        elif now - due > 0.5:  # far behind (slow decoding): re-anchor
            run.t_start, run.m_start = now, media_time

    def _hand_over(self, run: _RunState, raw: RawFrame) -> None:
        """Stamp the frame (the media clock for ``pace="max"`` files) and publish it."""
        now_m = self._mono()
        t_mono, t_wall = now_m, raw.t_wall if raw.t_wall is not None else self._wall()
        if run.pace_max and raw.media_time is not None:
            if run.t_start is None or run.m_start is None:
                run.t_start, run.m_start, run.w_start = now_m, raw.media_time, t_wall
            t_mono = run.t_start + (raw.media_time - run.m_start)
            t_wall = run.w_start + (raw.media_time - run.m_start)
        f = Frame(image=raw.image, index=raw.index, t_mono=t_mono, t_wall=t_wall,
                  seq=self.frames, t_read=now_m, media_time=raw.media_time,
                  name=raw.name, error=raw.error)
        self._clock_offset = t_mono - now_m
        self.frames += 1
        if raw.error is not None:
            self.frame_errors += 1
        self._set_state(SourceState.LIVE)
        self._publish(f, wait_for_consumer=run.lossless or (run.pace_max
                                                            and raw.media_time is not None))


class _Step(Enum):
    """What the reader thread does after an open attempt."""

    READ = "read"
    RETRY = "retry"
    STOP = "stop"


@dataclass
class _RunState:
    """The reader thread's working state."""

    delay: float
    """Pause (s) before the next reopen attempt."""
    pace_max: bool
    lossless: bool
    finite: bool
    opened: bool = False
    ever_opened: bool = False
    t_start: float | None = None
    """Monotonic time (s) the media clock was anchored at."""
    m_start: float | None = None
    """Media time (s) at that anchor."""
    w_start: float = 0.0
    """Wall time (s) at that anchor (``pace="max"``)."""


def _why(e: Exception) -> str:
    """An exception in one line: an OSError's or a bad input's own words, anything else with
    its type."""
    return one_line(e if isinstance(e, (OSError, InputError)) else f"{type(e).__name__}: {e}")
