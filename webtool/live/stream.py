"""The live view's image stream, made for Wi-Fi: when to send the next image to one viewer,
and at which size and JPEG quality (see :mod:`webtool.live.service` for the whole picture)."""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

__all__ = ["DEFAULT_BANDWIDTH_BPS", "LEVELS", "AdaptiveStream"]

DEFAULT_BANDWIDTH_BPS = 2_000_000

#: (scale, JPEG quality), best first.
LEVELS: list[tuple[float, int]] = [
    (1.0, 80), (1.0, 70), (1.0, 60), (1.0, 50), (0.75, 60), (0.75, 50), (0.75, 40),
    (0.5, 55), (0.5, 45), (0.5, 35), (0.375, 40), (0.25, 40), (0.25, 30)]


class AdaptiveStream:
    """When to send the next image to one viewer, and at which level (see the module doc).

    Args:
        rate_bps: This viewer's share of the bandwidth cap, bits per second.
        fps: The frame rate aimed at (the source's, at most ``max_fps`` of the service).
        clock: Monotonic clock (tests).
    """

    def __init__(self, rate_bps: float, fps: float = 15.0, level: int = 4,
                 max_inflight: int = 2,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self.rate_Bps = rate_bps / 8.0
        self.fps = fps
        self.level = level
        self.max_inflight = max_inflight
        self.inflight: deque[float] = deque()
        self.tokens = 0.0
        self.t_last = clock()
        self.last_send = -1e9
        self.fits = 0
        self.ack_delay = 0.0
        self.sent: deque[tuple[float, int]] = deque(maxlen=64)
        self.total_bytes = 0
        self.frames = 0

    def set_rate(self, rate_bps: float) -> None:
        self.rate_Bps = rate_bps / 8.0

    @property
    def budget(self) -> float:
        """Bytes per frame that keep ``fps`` within the share."""
        return self.rate_Bps / max(self.fps, 0.1)

    def _refill(self, now: float) -> None:
        self.tokens = min(self.tokens + (now - self.t_last) * self.rate_Bps, 2 * self.budget)
        self.t_last = now

    def ready(self) -> bool:
        now = self.clock()
        self._refill(now)
        return (len(self.inflight) < self.max_inflight and self.tokens >= 0
                and now - self.last_send >= 0.9 / max(self.fps, 0.1))

    def on_sent(self, nbytes: int) -> None:
        now = self.clock()
        self._refill(now)
        self.tokens -= nbytes
        self.last_send = now
        self.inflight.append(now)
        self.sent.append((now, nbytes))
        self.total_bytes += nbytes
        self.frames += 1
        if nbytes > 1.05 * self.budget and self.level < len(LEVELS) - 1:
            # far over budget: several steps at once (each step is ~25-35 % smaller)
            steps = max(1, int(math.log(nbytes / self.budget) / math.log(1.35)))
            self.level = min(len(LEVELS) - 1, self.level + steps)
            self.fits = 0
        elif nbytes < 0.5 * self.budget:
            self.fits += 1
            if self.fits >= 5 and self.level > 0 and self.ack_delay < 0.3:
                self.level -= 1
                self.fits = 0
        else:
            self.fits = 0

    def on_ack(self) -> None:
        now = self.clock()
        if self.inflight:
            d = now - self.inflight.popleft()
            self.ack_delay = 0.7 * self.ack_delay + 0.3 * d
            if self.ack_delay > 0.5 and self.level < len(LEVELS) - 1:
                self.level += 1  # the link (or the phone) cannot keep up
                self.ack_delay = 0.3  # give the smaller level time to show its effect
                self.fits = 0

    def kbps(self) -> float:
        now = self.clock()
        recent = [(t, n) for t, n in self.sent if now - t <= 3.0]
        if not recent:
            return 0.0
        span = max(now - recent[0][0], 1.0 / max(self.fps, 0.1))
        return 8 * sum(n for _, n in recent) / span / 1000

    def info(self) -> dict[str, Any]:
        scale, q = LEVELS[self.level]
        return {"level": self.level, "scale": scale, "jpeg_quality": q,
                "share_kbps": round(self.rate_Bps * 8 / 1000, 1), "kbps": round(self.kbps(), 1),
                "ack_ms": round(self.ack_delay * 1000, 1)}
