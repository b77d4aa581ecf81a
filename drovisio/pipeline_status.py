"""The running pipeline's figures: rolling windows (:class:`PipelineStats`) and the typed
snapshot of everything a status line or the live page shows (:class:`PipelineStatus`).

:meth:`PipelineStatus.to_json` is the status's JSON form (``Pipeline.status()``, the live
page's ``/api/live/status``): its keys and roundings are a contract.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drovisio.sinks.target import TargetSpec
from drovisio.sources import SourceStatus

__all__ = ["PipelineStats", "PipelineStatus", "TargetBrickStatus"]

MAX_DUPLICATE_NAMES = 16
"""At most this many ``layout:instance`` names are counted in :attr:`PipelineStats.duplicates`
(bounded memory)."""


class PipelineStats:
    """Rolling figures (bounded memory: fixed-size windows).

    Args:
        window: Frames each window holds.
    """

    def __init__(self, window: int = 90):
        self.detect_ms: deque[float] = deque(maxlen=window)
        self.latency_ms: deque[float] = deque(maxlen=window)
        self.frame_times: deque[float] = deque(maxlen=window)
        """Monotonic time (s) each frame was done."""
        self.frames = 0
        self.detector_errors = 0
        self.sink_errors = 0
        self.bricks = 0
        self.held = 0
        """Bricks of the last frame held over by the tracker (not measured in it)."""
        self.last_error: str | None = None
        self.unfit_frames = 0
        """Frames not measured because they do not fit the camera (another image size)."""
        self.unfit: str | None = None
        """Why the last of those did not fit."""
        self.duplicates: dict[str, int] = {}
        """``layout:instance`` -> frames in which its code id was read on several codes (those
        copies are not tracked: which one is the brick is unknown); at most 16 names."""

    def count_duplicates(self, names: set[str]) -> None:
        """One more frame for each ``layout:instance`` read on several codes."""
        for name in sorted(names):
            if name in self.duplicates or len(self.duplicates) < MAX_DUPLICATE_NAMES:
                self.duplicates[name] = self.duplicates.get(name, 0) + 1

    def fps(self, now: float | None = None) -> float:
        """Frames per second over the last 2 s (0 with fewer than two frames)."""
        ft = list(self.frame_times)
        if len(ft) < 2:
            return 0.0
        now = time.monotonic() if now is None else now
        recent = [t for t in ft if now - t <= 2.0]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6)

    @staticmethod
    def _median(d: deque) -> float:
        return float(np.median(list(d))) if d else 0.0

    def median_detect_ms(self) -> float:
        return self._median(self.detect_ms)

    def median_latency_ms(self) -> float:
        return self._median(self.latency_ms)


@dataclass(frozen=True)
class TargetBrickStatus:
    """The brick sent to the flight controller, while it is fresh."""

    layout: str
    instance: int | None
    track: int
    distance_m: float
    """From the camera, metres (rounded to the millimetre)."""

    def to_json(self) -> dict[str, Any]:
        return {"layout": self.layout, "instance": self.instance, "track": self.track,
                "distance": self.distance_m}


@dataclass(frozen=True)
class PipelineStatus:
    """A snapshot of the running pipeline (figures rounded as shown)."""

    frames: int
    """Frames processed since the start."""
    fps: float
    """Frames processed per second over the last 2 s."""
    detect_ms: float
    """Median detection time of the recent frames, milliseconds."""
    latency_ms: float
    """Median latency capture → sent of the recent frames, milliseconds."""
    bricks: int
    """Bricks of the last frame (tracked, held over included)."""
    held: int
    """Of those, held over by the tracker (not measured in the last frame)."""
    detector_errors: int
    sink_errors: int
    """Exceptions a sink raised (a sink's own failures are in its status)."""
    last_error: str | None
    duplicates: dict[str, int]
    """``layout:instance`` -> frames with its code id read on several codes."""
    source: SourceStatus
    target: TargetSpec
    """What the target selector is asked for."""
    target_brick: TargetBrickStatus | None
    """The chosen brick, None when none was chosen or it is older than the tracker's
    ``max_age``."""
    sinks: list[dict[str, Any]] = field(default_factory=list)
    """Each sink's own status (its own keys)."""
    recording: dict[str, Any] | None = None
    """The recorder's status, None without one."""
    unfit_frames: int = 0
    """Frames not measured because they do not fit the camera (another image size)."""
    unfit: str | None = None
    """Why the last of those did not fit."""

    @classmethod
    def of(cls, stats: PipelineStats, *, source: SourceStatus, target: TargetSpec,
           target_brick: TargetBrickStatus | None, sinks: list[dict[str, Any]],
           recording: dict[str, Any] | None) -> PipelineStatus:
        """The snapshot of ``stats`` and the stages' own status."""
        return cls(frames=stats.frames, fps=round(stats.fps(), 2),
                   detect_ms=round(stats.median_detect_ms(), 2),
                   latency_ms=round(stats.median_latency_ms(), 2),
                   bricks=stats.bricks, held=stats.held,
                   detector_errors=stats.detector_errors, sink_errors=stats.sink_errors,
                   last_error=stats.last_error, duplicates=dict(stats.duplicates),
                   source=source, target=target, target_brick=target_brick, sinks=sinks,
                   recording=recording, unfit_frames=stats.unfit_frames, unfit=stats.unfit)

    def to_json(self) -> dict[str, Any]:
        """The JSON form (see the module doc)."""
        out: dict[str, Any] = {
            "frames": self.frames, "fps": self.fps, "detect_ms": self.detect_ms,
            "latency_ms": self.latency_ms, "bricks": self.bricks, "held": self.held,
            "detector_errors": self.detector_errors, "sink_errors": self.sink_errors,
            "last_error": self.last_error, "duplicates": dict(self.duplicates),
            "source": self.source.to_json(), "target": self.target.to_json(),
            "target_brick": None if self.target_brick is None else self.target_brick.to_json(),
            "sinks": self.sinks}
        if self.recording is not None:
            out["recording"] = self.recording
        if self.unfit_frames:   # frames of another size than the camera file's, and why
            out["unfit_frames"] = self.unfit_frames
            out["unfit"] = self.unfit
        return out
