"""The positioning pipeline: Source → Detector(s) → Fusion → Tracker → Sink(s).

:class:`Pipeline` takes the newest frame of a :class:`~drovisio.sources.FrameSource`, runs the
detectors the loaded layouts need (codes → ArUco, dots → colour dots; in parallel threads when
there are two: OpenCV releases the GIL), fuses a brick's code and dot poses
(:mod:`drovisio.fusion`), tracks every brick (:mod:`drovisio.tracking`), chooses the target
(:mod:`drovisio.sinks.target`), and hands one :class:`FrameOutput` per frame to every sink,
to the recorder and to listeners (the live page). It never raises for a frame: a detector
error is counted and reported (the frame gives no bricks); a lost source gives no frames, the
tracks age out within ``max_age`` and the loop keeps waiting for the source to come back.

Detectors follow one protocol, :class:`drovisio.detect.base.Detector`: ``detect(image,
gravity=None) -> list[BrickPose]`` and ``reset()``; :func:`detectors_for` picks them.

Gravity (the detectors' evidence for the flip ambiguity): a callable ``t_mono -> unit vector
in the camera frame | None``; ``drovisio run`` gives the autopilot's attitude (from the MAVLink
link) through the mount, or the mount's level "down" when there is no attitude.

Timing: each output records the capture time (``t`` UNIX s, ``t_mono``), the detection time
and, once the sinks returned, the latency capture → sent (:attr:`Pipeline.stats`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from drovisio._threads import STOP_WAIT_S
from drovisio.camera import Camera
from drovisio.detect.base import Detector
from drovisio.detect.result import BrickPose
from drovisio.fusion import dots_half_turn_symmetric, fuse_frame
from drovisio.layout import MarkerLayout
from drovisio.mount import Mount
from drovisio.pipeline_status import PipelineStats, PipelineStatus, TargetBrickStatus
from drovisio.sinks.base import Sink
from drovisio.sinks.target import TargetSelector
from drovisio.sources import Frame, FrameSource, SourceState
from drovisio.tracking import BrickTracker, TrackedBrick, TrackerConfig

__all__ = [
    "STOP_WAIT_S",
    "Detector",
    "FrameOutput",
    "FrameRecorder",
    "Pipeline",
    "PipelineStats",
    "PipelineStatus",
    "detectors_for",
]

log = logging.getLogger("drovisio.pipeline")


def detectors_for(camera: Camera, layouts: Sequence[MarkerLayout], stream: bool = True
                  ) -> list[Detector]:
    """The detectors the layouts need: ArUco if any has codes, dots if any has dots.

    Args:
        camera: The camera of the frames.
        layouts: The loaded layouts.
        stream: The frames come in order from one stream (the detectors keep what the
            previous frames tell); False for unrelated single images.
    """
    # deferred: the detectors load compiled kernels, which a status-only import never needs
    from drovisio.detect.aruco import ArucoBrickDetector
    from drovisio.detect.dots import DotDetector

    out: list[Detector] = []
    if any(getattr(lay, "has_codes", False) for lay in layouts):
        out.append(ArucoBrickDetector(camera, layouts, stream=stream))
    if any(getattr(lay, "has_dots", False) for lay in layouts):
        out.append(DotDetector(camera, layouts, stream=stream))
    return out


class FrameRecorder(Protocol):
    """Where the frames and their outputs are recorded (:class:`drovisio.recording.Recorder`,
    the ROS 2 ``.mcap`` recorder)."""

    def add(self, frame: Frame, output: FrameOutput) -> None: ...

    def status(self) -> dict: ...

    def close(self) -> None: ...


@dataclass
class FrameOutput:
    """Everything the pipeline knows about one processed frame."""

    source: str
    frame: int
    seq: int
    t: float
    """Capture time, UNIX seconds."""
    t_mono: float
    bricks: list[TrackedBrick]
    target: TrackedBrick | None = None
    detections: list[BrickPose] = field(default_factory=list)
    """This frame's raw detections (before fusion and tracking)."""
    detect_ms: float = 0.0
    source_state: str = "live"
    gravity: np.ndarray | None = None
    errors: list[str] = field(default_factory=list)

    def to_json(self, with_covariance: bool = True) -> dict:
        out: dict = {"file": self.source, "frame": self.frame, "t": round(self.t, 6),
                     "bricks": [b.to_json(with_covariance) for b in self.bricks],
                     "target": None if self.target is None else
                     {"layout": self.target.layout, "instance": self.target.instance,
                      "track": self.target.track},
                     "detect_ms": round(self.detect_ms, 2)}
        if self.errors:
            out["error"] = "; ".join(self.errors)
        return out


class Pipeline:
    """Runs the stages on a source until it ends or :meth:`stop` is called.

    Args:
        source: A started (or startable) :class:`FrameSource`.
        detectors: Detectors (see :func:`detectors_for`).
        sinks: Where each :class:`FrameOutput` goes.
        tracker: The brick tracker (default: one with ``max_age``).
        mount: Camera mount (for body-frame poses).
        target: Target selector shared with the sinks and the UI.
        gravity: ``t_mono -> gravity in the camera frame | None``.
        recorder: A :class:`drovisio.recording.Recorder` (frames + outputs), or None.
        max_age: Drop time of unseen bricks (s), when no tracker is given.
        parallel: Run several detectors in parallel threads.
        fuse: Fuse code and dot poses of the same brick.
        layouts: The loaded layouts (tells which bricks' dots alone are half-turn symmetric).
        camera: The camera the detectors were made for. With it, a frame of another size is
            reported instead of measured with the wrong intrinsics, and a camera file without
            an image size takes the first frame's (detectors rebuilt by
            ``detector_factory(camera)``).
        detector_factory: Makes the detectors for a camera (with ``camera``).
    """

    def __init__(self, source: FrameSource, detectors: Sequence[Detector],
                 sinks: Sequence[Sink] = (), tracker: BrickTracker | None = None,
                 mount: Mount | None = None, target: TargetSelector | None = None,
                 gravity: Callable[[float], np.ndarray | None] | None = None,
                 recorder: FrameRecorder | None = None, max_age: float = 0.5,
                 parallel: bool = True, fuse: bool = True,
                 layouts: Sequence[MarkerLayout] = (), camera: Camera | None = None,
                 detector_factory: Callable[[Camera], list[Detector]] | None = None):
        self.source = source
        self.detectors = list(detectors)
        self.camera = camera
        self.detector_factory = detector_factory
        self.notes: list[str] = []
        """Things said once about the run (e.g. the image size taken from the source)."""
        self.sinks = list(sinks)
        self.mount = mount
        self.tracker = tracker or BrickTracker(TrackerConfig(max_age=max_age), mount=mount)
        if self.tracker.mount is None:
            self.tracker.mount = mount
        # a target set later is checked against the layouts given (none given: not checked)
        self.target = target or TargetSelector(layouts=list(layouts) or None)
        self.gravity = gravity
        self.recorder = recorder
        self.fuse = fuse
        self.layouts = list(layouts)
        self._symmetric_dots = {lay.name for lay in self.layouts
                                if getattr(lay, "has_codes", False)
                                and dots_half_turn_symmetric(lay)}
        self.stats = PipelineStats()
        self._parallel = parallel
        self._listeners: list[Callable[[Frame | None, FrameOutput | None], None]] = []
        for sink in self.sinks:   # a sink that also wants the images (a station's thumbnail)
            on_frame = getattr(sink, "on_frame", None)
            if callable(on_frame):
                self._listeners.append(on_frame)
        self._stop = threading.Event()
        # set while no thread is inside run(): close() waits for it (see close)
        self._idle = threading.Event()
        self._idle.set()
        self._runner: int | None = None
        self._close_lock = threading.Lock()
        self._closing = False
        self._closed = threading.Event()
        self._pool = (ThreadPoolExecutor(max_workers=len(self.detectors),
                                         thread_name_prefix="detect")
                      if parallel and len(self.detectors) > 1 else None)
        self.last_output: FrameOutput | None = None

    # ------------------------------------------------------------------ listeners
    def add_listener(self, fn: Callable[[Frame | None, FrameOutput | None], None]) -> None:
        """``fn(frame, output)`` after each frame (``(None, None)`` on idle ticks); keep it
        fast: it runs in the pipeline thread."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[Frame | None, FrameOutput | None], None]) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    def _notify(self, frame: Frame | None, out: FrameOutput | None) -> None:
        for fn in list(self._listeners):
            try:
                fn(frame, out)
            except Exception as e:  # noqa: BLE001 - a listener never stops the pipeline
                log.warning("listener failed: %s", e)

    # ------------------------------------------------------------------ stages
    def _detect(self, frame: Frame, g: np.ndarray | None) -> tuple[list[BrickPose], list[str]]:
        errors: list[str] = []
        image = frame.image
        assert image is not None

        def one(d: Detector) -> list[BrickPose]:
            try:
                return list(d.detect(image, gravity=g))
            except Exception as e:  # noqa: BLE001
                self.stats.detector_errors += 1
                msg = f"{getattr(d, 'name', type(d).__name__)}: {type(e).__name__}: {e}"
                self.stats.last_error = msg
                errors.append(msg)
                return []

        if self._pool is not None:
            results = list(self._pool.map(one, self.detectors))
        else:
            results = [one(d) for d in self.detectors]
        return [p for r in results for p in r], errors

    def _gravity_at(self, t_mono: float) -> np.ndarray | None:
        """Gravity in the camera frame at ``t_mono`` (None when unknown or it failed)."""
        if self.gravity is None:
            return None
        try:
            return self.gravity(t_mono)
        except Exception:  # noqa: BLE001
            return None

    def _measure(self, frame: Frame, g: np.ndarray | None
                 ) -> tuple[list[BrickPose], list[str]]:
        """The frame's detections and errors (an undecodable frame or one of another size
        is said, not detected)."""
        mismatch = self._fit_camera(frame.image) if frame.image is not None else None
        if frame.image is None:   # a frame the source could not decode: said, not detected
            return [], [frame.error or "frame could not be decoded"]
        if mismatch is not None:
            self.stats.unfit_frames += 1
            self.stats.unfit = mismatch
            return [], [mismatch]
        return self._detect(frame, g)

    def _send(self, out: FrameOutput) -> None:
        for s in self.sinks:
            try:
                s.send(out)
            except Exception as e:  # noqa: BLE001
                self.stats.sink_errors += 1
                self.stats.last_error = f"{getattr(s, 'name', s)}: {e}"

    def _count(self, frame: Frame, bricks: list[TrackedBrick], detect_ms: float) -> None:
        now = time.monotonic()
        st = self.stats
        st.latency_ms.append((now - (frame.t_read or frame.t_mono)) * 1e3)
        st.detect_ms.append(detect_ms)
        st.frame_times.append(now)
        st.frames += 1
        st.bricks = len(bricks)
        st.held = sum(not b.measured for b in bricks)

    def process(self, frame: Frame) -> FrameOutput:
        """All stages for one frame; sends the output to the sinks and returns it."""
        g = self._gravity_at(frame.t_mono)
        t0 = time.perf_counter()
        poses, errors = self._measure(frame, g)
        detect_ms = (time.perf_counter() - t0) * 1e3
        if self.fuse:
            poses = fuse_frame(poses, symmetric_dots=self._symmetric_dots)
        # codes whose id was read several times in the frame: posed and flagged by the
        # detector, but never tracked (one track would jump between the copies)
        tracked = [p for p in poses if not p.duplicate]
        if len(tracked) != len(poses):
            self.stats.count_duplicates({f"{p.layout}:{p.instance}" for p in poses
                                         if p.duplicate})
        bricks = self.tracker.update(tracked, frame.t_mono, frame.t_wall)
        target = self.target.choose(bricks)
        out = FrameOutput(source=self.source.label, frame=frame.index, seq=frame.seq,
                          t=frame.t_wall, t_mono=frame.t_mono, bricks=bricks, target=target,
                          detections=poses, detect_ms=detect_ms,
                          source_state=self.source.state.value, gravity=g, errors=errors)
        self._send(out)
        self._count(frame, bricks, detect_ms)
        if self.recorder is not None and frame.image is not None:
            self.recorder.add(frame, out)
        self.last_output = out
        self._notify(frame, out)
        return out

    def _fit_camera(self, image: np.ndarray) -> str | None:
        """None when the frame fits the camera (a camera without a size takes the frame's);
        else why it does not."""
        cam = self.camera
        if cam is None:
            return None
        size = (int(image.shape[1]), int(image.shape[0]))
        if cam.size_known and cam.size == size:
            return None
        try:
            new, note = cam.for_image(*size)
        except ValueError as e:
            return str(e)
        self.camera = new
        if note:
            self.notes.append(note)
            log.warning("%s", note)
        if self.detector_factory is not None:
            self.detectors = list(self.detector_factory(new))
            if self._parallel and self._pool is None and len(self.detectors) > 1:
                self._pool = ThreadPoolExecutor(max_workers=len(self.detectors),
                                                thread_name_prefix="detect")
        return None

    def step(self, timeout: float = 0.1) -> FrameOutput | None:
        """Process the newest frame if one arrives within ``timeout``; else age the tracks."""
        frame = self.source.get(timeout)
        if frame is None:
            self.tracker.prune(self.source.now() if hasattr(self.source, "now")
                               else time.monotonic())
            self.stats.bricks = len(self.tracker.tracks)
            self.stats.held = len(self.tracker.tracks)
            self._notify(None, None)
            return None
        return self.process(frame)

    def warm_up(self, width: int, height: int) -> None:
        """Run each detector once on a blank frame (first calls build tables and caches;
        without this the first real frame is several times slower)."""
        blank = np.full((height, width, 3), 127, np.uint8)
        for d in self.detectors:
            try:
                d.detect(blank, gravity=None)
            except Exception:  # noqa: BLE001 - a real frame will report it
                pass

    # ------------------------------------------------------------------ loop
    def run(self, max_frames: int | None = None,
            on_status: Callable[[PipelineStatus], None] | None = None,
            status_period: float = 1.0) -> int:
        """Loop until the source ends, :meth:`stop` is called or ``max_frames`` were done.

        ``on_status(snapshot)`` is called every ``status_period`` seconds.
        Returns the number of frames processed (0 once :meth:`close` was called).
        """
        with self._close_lock:
            if self._closing:   # a run started after close would restart the closed source
                return 0
            self._runner = threading.get_ident()
            self._idle.clear()
        try:
            return self._loop(max_frames, on_status, status_period)
        finally:
            self._runner = None
            self._idle.set()

    def _loop(self, max_frames: int | None,
              on_status: Callable[[PipelineStatus], None] | None,
              status_period: float) -> int:
        self.source.start()
        n = 0
        next_status = time.monotonic() + status_period
        while not self._stop.is_set():
            out = self.step(0.1)
            if out is not None:
                n += 1
                if max_frames is not None and n >= max_frames:
                    break
            elif self.source.ended:
                break
            if on_status is not None and time.monotonic() >= next_status:
                next_status += status_period
                if time.monotonic() > next_status:
                    next_status = time.monotonic() + status_period
                on_status(self.snapshot())
        return n

    def stop(self) -> None:
        """Ask :meth:`run` to end after the frame in progress; returns at once (a signal
        handler calls it). :meth:`close` waits for the end."""
        self._stop.set()

    def snapshot(self) -> PipelineStatus:
        """Figures for status lines and the live page."""
        out = self.last_output
        t = out.target if out is not None else None
        fresh = (t is not None and out is not None
                 and self.source.now() - out.t_mono <= self.tracker.config.max_age)
        brick = (TargetBrickStatus(t.layout, t.instance, t.track, round(t.distance, 3))
                 if fresh and t is not None else None)
        return PipelineStatus.of(
            self.stats, source=self.source.status(), target=self.target.spec,
            target_brick=brick,
            sinks=[x.status() for x in self.sinks if hasattr(x, "status")],
            recording=self.recorder.status() if self.recorder is not None else None)

    def status(self) -> dict:
        """:meth:`snapshot`'s JSON form."""
        return self.snapshot().to_json()

    def close(self) -> None:
        """Stop the run and wait for its end, then stop the source, close the sinks and the
        recorder; when it returns, no thread of the pipeline's runs any more.

        Called from another thread than :meth:`run`'s (the web tool's live page), it waits
        for the frame in progress: the detectors' threads may be compiling their kernels (a
        first run) or inside OpenCV, and a thread left in native code while the interpreter
        exits aborts the process ("terminate called without an active exception"). Later
        calls wait for the first one to finish.
        """
        with self._close_lock:
            first, self._closing = not self._closing, True
        if not first:
            if threading.get_ident() != self._runner:
                self._closed.wait(STOP_WAIT_S)
            return
        self._stop.set()
        ended = self._wait_for_run()
        try:
            self.source.stop(STOP_WAIT_S)
        finally:
            for s in self.sinks:
                try:
                    s.close()
                except Exception:  # noqa: BLE001
                    pass
            if self.recorder is not None:
                self.recorder.close()
            if self._pool is not None:
                self._pool.shutdown(wait=ended)
            self._closed.set()

    def _wait_for_run(self) -> bool:
        """Wait until no thread is inside :meth:`run` (the caller's own run excepted); False
        (and said) when it did not end within :data:`STOP_WAIT_S`."""
        if threading.get_ident() == self._runner or self._idle.wait(STOP_WAIT_S):
            return True
        log.warning("the pipeline's frame in progress did not end within %.0f s; closing "
                    "without it", STOP_WAIT_S)
        return False

    @property
    def source_state(self) -> SourceState:
        return self.source.state
