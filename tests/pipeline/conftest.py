"""Fakes for the pipeline tests: a synthetic frame reader that can fail, a fake detector."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drovisio.detect.result import BrickPose
from drovisio.sources import EndOfStream, RawFrame

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_sessions"
APPROACH = SAMPLE / "approach"
LAYOUTS = [REPO / "marker_layouts" / f"{n}.json"
           for n in ("drick-aruco-pyramids", "drick-aruco-centre", "drick-dots-2x3")]


class FlakyReader:
    """Synthetic frames at up to ``fps``; after :meth:`unplug` reads fail and opens raise
    until :meth:`plug` (a camera unplugged and plugged back in: the test says when, so that
    nothing depends on how fast a loaded machine runs). With ``n``: a finite source of ``n``
    frames, each with its media time, like a file."""

    finite = False

    def __init__(self, fps: float = 30.0, n: int | None = None, size=(64, 48)):
        self.label = "fake camera"
        self.fps = fps
        self.n = n
        self.finite = n is not None
        self.size = size
        self.i = 0
        self.opens = 0
        self.is_open = False
        self.unplugged = threading.Event()

    def unplug(self) -> None:
        self.unplugged.set()

    def plug(self) -> None:
        self.unplugged.clear()

    def open(self) -> None:
        if self.unplugged.is_set():
            raise OSError("device not found")
        self.opens += 1
        self.is_open = True

    def read(self):
        if self.n is not None and self.i >= self.n:
            raise EndOfStream()
        time.sleep(1.0 / self.fps)
        if self.unplugged.is_set() or not self.is_open:
            return None
        img = np.full((self.size[1], self.size[0], 3), self.i % 250 + 1, np.uint8)
        self.i += 1
        return RawFrame(img, self.i - 1,
                        media_time=(self.i - 1) / self.fps if self.finite else None)

    def close(self) -> None:
        self.is_open = False


class FakeDetector:
    """One brick per frame at a fixed pose plus noise; optionally raising."""

    name = "fake"

    def __init__(self, noise: float = 0.0, raise_every: int = 0, seed: int = 0):
        self.noise = noise
        self.raise_every = raise_every
        self.calls = 0
        self.rng = np.random.default_rng(seed)
        self.lock = threading.Lock()

    def detect(self, image, gravity=None):
        with self.lock:
            self.calls += 1
            k = self.calls
        if self.raise_every and k % self.raise_every == 0:
            raise RuntimeError("boom")
        n = self.rng.normal(0, self.noise, 6) if self.noise else np.zeros(6)
        cov = np.diag([1e-4] * 3 + [1e-5] * 3)
        return [BrickPose("drick-aruco-centre", 1, "aruco", np.array([3.1, 0.0, 0.0]) + n[:3],
                          np.array([0.1, 0.0, 1.5]) + n[3:], 0.2, markers=[1],
                          covariance=cov)]


@pytest.fixture
def flaky_reader():
    return FlakyReader


@pytest.fixture
def fake_detector():
    return FakeDetector
