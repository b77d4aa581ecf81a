"""Closing the pipeline waits for the frame in progress, so that the process can exit.

A first run's frame compiles the detectors' kernels (minutes, cold cache) in the detectors'
threads. The web tool's live pipeline runs in a thread of its own and is closed from another
one (the app's shutdown): a close that returned before the frame ended let the interpreter
exit with a thread still in native code, and the process aborted ("terminate called without
an active exception", exit 134) after a passing test run. Here a detector stays in OpenCV
(the GIL released, as in a compile) for about a second on its first frame, the pipeline is
closed as soon as that frame began, and the process exits: nothing may still be detecting
when close returns, and the exit is clean.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

CHILD = r"""
import json, sys, threading, time

import cv2
import numpy as np

from drovisio.pipeline import Pipeline
from drovisio.raw_frame import RawFrame
from drovisio.sources import FrameSource


class Camera:
    label, finite = "camera", False

    def open(self):
        pass

    def read(self):
        time.sleep(0.01)
        return RawFrame(np.zeros((48, 64, 3), np.uint8), 0)

    def close(self):
        pass


class InNativeCode:
    '''Its first frame stays in OpenCV, the GIL released, as a first run's compile does.'''
    name = "native"

    def __init__(self):
        self.entered = threading.Event()
        self.busy = False

    def detect(self, image, gravity=None):
        if not self.entered.is_set():
            self.busy = True
            self.entered.set()
            big = np.random.default_rng(0).integers(0, 255, (1080, 1920, 3), np.uint8)
            for _ in range(40):
                cv2.GaussianBlur(big, (0, 0), 5)
            self.busy = False
        return []

    def reset(self):
        pass


detectors = [InNativeCode() for _ in range(int(sys.argv[1]))]
p = Pipeline(FrameSource(Camera()), detectors)
# the live page's way: run in a daemon thread, closed from another thread
threading.Thread(target=p.run, daemon=True, name="live-pipeline").start()
assert all(d.entered.wait(120) for d in detectors), "the first frame never came"
p.close()
print(json.dumps({
    "detecting": [d.busy for d in detectors],
    "threads": sorted(t.name for t in threading.enumerate()
                      if t.name.startswith(("detect", "source:"))),
}))
"""


@pytest.mark.parametrize("n_detectors", [1, 2], ids=["in-the-pipeline-thread", "in-a-pool"])
def test_close_waits_for_the_frame_in_progress_and_the_process_exits_cleanly(n_detectors):
    # the bound only turns a hang into a failure
    r = subprocess.run([sys.executable, "-c", CHILD, str(n_detectors)], capture_output=True,
                       text=True, timeout=300)
    assert "terminate called" not in r.stderr, r.stderr[-2000:]
    assert r.returncode == 0, r.stderr[-2000:]
    said = json.loads(r.stdout.strip().splitlines()[-1])
    assert said == {"detecting": [False] * n_detectors, "threads": []}, said
