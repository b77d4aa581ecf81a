"""What the ground station knows of each drone: live or lost, rate, latency, bricks, target.

:class:`Fleet` is fed by the station's link (:mod:`drovisio.station.link`) with each drone's
frame outputs (the JSON output of DESIGN.md, as the drone's ``output`` topic carries it) and
with its presence (a Zenoh liveliness token the drone's sink holds while its session is
open). It holds a bounded amount per drone (windows of the last frames, the last output) and
at most ``max_drones`` drones, so a long run or a noisy network cannot grow it.

Times: ``t_recv`` is the station's UNIX time at reception and ``mono`` its monotonic clock;
a frame's latency is ``t_recv - output["t"]`` (the frame's capture time on the drone), which
needs the two clocks in step (NTP, or the same machine).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

__all__ = ["DroneStatus", "Fleet"]

LOST_AFTER_S = 1.0
"""A drone with no frame for this long is lost (30 fps drones send every 33 ms)."""

_WINDOW = 90
"""Frames in the rate and latency windows (3 s at 30 fps)."""


@dataclass
class _Drone:
    drone_id: str
    first_seen: float
    last_mono: float = -math.inf
    present: bool = False
    frames: int = 0
    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=_WINDOW))
    latencies_ms: deque[float] = field(default_factory=lambda: deque(maxlen=_WINDOW))
    last_output: dict[str, Any] | None = None
    image: bytes | None = None
    image_t: float | None = None
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class DroneStatus:
    """One drone as the Fleet page shows it.

    Attributes:
        drone_id: The drone's ``--drone-id``.
        state: ``live`` (frames arriving), ``lost`` (none for :data:`LOST_AFTER_S`, or its
            session closed).
        fps: Frames received per second over the last window.
        latency_ms_p50: Median capture → station latency (ms) over the window.
        latency_ms_p90: Its 90th percentile.
        frames: Frames received since the drone was first seen.
        bricks: Bricks in its last frame.
        target: The last frame's target brick (layout, instance, track, ``camera_from_brick``
            position in metres), or None.
        age_s: Seconds since its last frame.
        has_image: A recent camera image is held (see :meth:`Fleet.image`).
        info: What the drone says of itself (e.g. the address of its own web tool).
    """

    drone_id: str
    state: str
    fps: float
    latency_ms_p50: float | None
    latency_ms_p90: float | None
    frames: int
    bricks: int
    target: dict[str, Any] | None
    age_s: float | None
    has_image: bool
    info: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"drone_id": self.drone_id, "state": self.state, "fps": round(self.fps, 2),
                "latency_ms_p50": _round(self.latency_ms_p50),
                "latency_ms_p90": _round(self.latency_ms_p90), "frames": self.frames,
                "bricks": self.bricks, "target": self.target, "age_s": _round(self.age_s),
                "has_image": self.has_image, "info": self.info}


def _round(x: float | None, nd: int = 2) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, nd)


def _quantile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    s = sorted(values)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))]


def _target_of(output: dict[str, Any]) -> dict[str, Any] | None:
    tgt = output.get("target")
    if not isinstance(tgt, dict):
        return None
    bricks = output.get("bricks")
    for b in bricks if isinstance(bricks, list) else []:
        if isinstance(b, dict) and b.get("track") == tgt.get("track") \
                and b.get("layout") == tgt.get("layout"):
            return {"layout": b.get("layout"), "instance": b.get("instance"),
                    "track": b.get("track"), "tvec": b.get("tvec"), "rvec": b.get("rvec")}
    return dict(tgt)


class Fleet:
    """Thread-safe state of every drone seen (module doc).

    Args:
        lost_after_s: Seconds without a frame after which a drone is lost.
        max_drones: Drones kept at most (the longest lost are forgotten first).
    """

    def __init__(self, lost_after_s: float = LOST_AFTER_S, max_drones: int = 64):
        self.lost_after_s = float(lost_after_s)
        self.max_drones = int(max_drones)
        self._drones: dict[str, _Drone] = {}
        self._lock = threading.Lock()

    def _get(self, drone_id: str, t_recv: float) -> _Drone:
        d = self._drones.get(drone_id)
        if d is None:
            if len(self._drones) >= self.max_drones:
                oldest = min(self._drones.values(), key=lambda x: x.last_mono)
                del self._drones[oldest.drone_id]
            d = self._drones[drone_id] = _Drone(drone_id, first_seen=t_recv)
        return d

    def frame(self, drone_id: str, output: dict[str, Any], t_recv: float | None = None,
              mono: float | None = None) -> None:
        """A drone's frame output arrived (the JSON output of DESIGN.md)."""
        t_recv = time.time() if t_recv is None else t_recv
        mono = time.monotonic() if mono is None else mono
        with self._lock:
            d = self._get(drone_id, t_recv)
            d.frames += 1
            d.present = True
            d.last_mono = mono
            d.arrivals.append(mono)
            t = output.get("t")
            if isinstance(t, (int, float)) and math.isfinite(t):
                d.latencies_ms.append(1000.0 * (t_recv - float(t)))
            d.last_output = output

    def image(self, drone_id: str, jpeg: bytes | None = None, t: float | None = None
              ) -> tuple[bytes | None, float | None]:
        """Store a drone's latest camera image (with ``jpeg``) or return it and its capture
        time."""
        with self._lock:
            if jpeg is not None:
                d = self._get(drone_id, time.time())
                d.image, d.image_t = bytes(jpeg), t
            d2 = self._drones.get(drone_id)
            return (None, None) if d2 is None else (d2.image, d2.image_t)

    def last_bricks(self, drone_id: str) -> list[dict[str, Any]]:
        """The bricks of a drone's last frame that carry a pose (``rvec``, ``tvec`` of three
        finite numbers each), as its JSON output lists them."""
        with self._lock:
            d = self._drones.get(drone_id)
            bricks = (d.last_output or {}).get("bricks") if d is not None else None
        out = []
        for b in bricks if isinstance(bricks, list) else []:
            if isinstance(b, dict) and all(
                    isinstance(b.get(k), list) and len(b[k]) == 3
                    and all(isinstance(x, (int, float)) and math.isfinite(x) for x in b[k])
                    for k in ("rvec", "tvec")):
                out.append(b)
        return out

    def presence(self, drone_id: str, present: bool) -> None:
        """A drone's session opened (its liveliness token appeared) or closed."""
        with self._lock:
            self._get(drone_id, time.time()).present = present

    def describe(self, drone_id: str, info: dict[str, Any]) -> None:
        """What a drone says of itself (e.g. ``{"web": URL}``, its web tool)."""
        with self._lock:
            self._get(drone_id, time.time()).info.update(info)

    def status(self, mono: float | None = None) -> list[DroneStatus]:
        """Every drone seen, by id."""
        mono = time.monotonic() if mono is None else mono
        out = []
        with self._lock:
            for d in sorted(self._drones.values(), key=lambda x: x.drone_id):
                age = mono - d.last_mono if math.isfinite(d.last_mono) else None
                live = d.present and age is not None and age <= self.lost_after_s
                arr = [a for a in d.arrivals if mono - a <= 2.0]
                fps = (len(arr) - 1) / (arr[-1] - arr[0]) if len(arr) > 2 and arr[-1] > arr[0] \
                    else 0.0
                lat = list(d.latencies_ms)
                last = d.last_output or {}
                out.append(DroneStatus(
                    drone_id=d.drone_id, state="live" if live else "lost",
                    fps=fps if live else 0.0, latency_ms_p50=_quantile(lat, 0.5),
                    latency_ms_p90=_quantile(lat, 0.9), frames=d.frames,
                    bricks=len(bricks) if isinstance(bricks := last.get("bricks"), list) else 0,
                    target=_target_of(last),
                    age_s=age, has_image=d.image is not None, info=dict(d.info)))
        return out
