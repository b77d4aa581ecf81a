"""Detection does not depend on the thread count: the same frame gives the same bricks and
bit-identical poses with one thread and with several (OpenCV's and numpy's BLAS), run after
run."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.detect.dots import DotDetector
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.scenes import SceneSpec, gravity_in_camera, render_random

CAM = Camera.drone_webcam()


@pytest.fixture(scope="module")
def code_frames(tag36h11_layouts):
    # near and far bricks, some blurred: the rescue, the ring quads and the second look run
    spec = SceneSpec(layouts=tag36h11_layouts, n_bricks=4, distance=(0.8, 2.2),
                     blur_sigma_px=(0.3, 1.0))
    return [render_random(8100 + s, spec, CAM, ss=2) for s in range(3)]


@pytest.fixture
def restore_threads():
    n = cv2.getNumThreads()
    yield
    cv2.setNumThreads(n)


def _run(det, frames) -> list[tuple]:
    out = []
    for r in frames:
        for p in det.detect(r.image, gravity=gravity_in_camera(r.camera_from_world)):
            out.append((p.layout, p.instance, tuple(p.markers), bool(p.ambiguous),
                        np.asarray(p.rvec, np.float64).tobytes(),
                        np.asarray(p.tvec, np.float64).tobytes(),
                        float(p.reprojection_rmse_px)))
    return out


def test_code_bricks_identical_with_one_and_many_threads(code_frames, tag36h11_layouts,
                                                         restore_threads):
    from threadpoolctl import threadpool_limits

    runs = []
    for threads in (1, 4, 1, 4):
        cv2.setNumThreads(threads)
        # a new detector each time, as a new process would have
        with threadpool_limits(limits=threads, user_api="blas"):
            runs.append(_run(ArucoBrickDetector(CAM, tag36h11_layouts), code_frames))
    truth = sum(len(r.bricks) for r in code_frames)
    assert len(runs[0]) >= 0.75 * truth, (len(runs[0]), truth)  # not vacuous
    for other in runs[1:]:
        assert other == runs[0]


def test_dot_bricks_identical_with_one_and_many_threads(restore_threads):
    lay = load_layout(shipped_layouts_dir() / "drick-dots-2x3.json")
    spec = SceneSpec(layouts=[lay], n_bricks=3, distance=(0.6, 1.5))
    frames = [render_random(8200 + s, spec, CAM, ss=2) for s in range(2)]
    from threadpoolctl import threadpool_limits

    runs = []
    for threads in (1, 4, 1):
        cv2.setNumThreads(threads)
        with threadpool_limits(limits=threads, user_api="blas"):  # numpy's products too
            runs.append(_run(DotDetector(CAM, [lay]), frames))
    assert len(runs[0]) >= 4, runs[0]
    assert runs[1] == runs[0] and runs[2] == runs[0]
