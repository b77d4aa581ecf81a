"""Fixtures of the calibration tests: OpenCV's sample views (skipped when absent) and rendered
views with known truth (rendered once per test session: ~10 s)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import pytest

from drovisio.calibration.board import BoardSpec, parse_board
from drovisio.camera import Camera

REPO_ROOT = Path(__file__).resolve().parents[2]
OPENCV_LEFT = Path(os.environ.get("DROVISIO_OPENCV_LEFT",
                                  REPO_ROOT.parent / "shared" / "datasets" / "opencv-left"))
REAL = Path(os.environ.get("DROVISIO_REAL_DATA",
                           REPO_ROOT.parent / "shared" / "datasets" / "real"))


def real_data(*parts: str) -> Path:
    """A file or folder of ../shared/datasets/real (its README: sources, references); skips
    the test when absent (fails instead where DROVISIO_REQUIRE_SHARED=1: CI has it)."""
    p = REAL.joinpath(*parts)
    if not p.exists():
        msg = (f"real data {p} is absent; set DROVISIO_REAL_DATA to the datasets/real folder "
               "to run this test")
        if os.environ.get("DROVISIO_REQUIRE_SHARED") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return p

#: Board of the rendered sessions (drovisio.calibration.synthetic.DEFAULT_BOARD).
RENDER_SEED = 0
N_RENDERED = 20


@pytest.fixture(scope="session")
def opencv_board() -> BoardSpec:
    return parse_board("chessboard:9x6", 0.025)


@pytest.fixture(scope="session")
def opencv_files() -> list[Path]:
    files = sorted(OPENCV_LEFT.glob("left*.jpg")) if OPENCV_LEFT.is_dir() else []
    if len(files) != 13:
        msg = (f"OpenCV's 13 sample views are not at {OPENCV_LEFT} (found {len(files)}); "
               "set DROVISIO_OPENCV_LEFT to their folder to run these tests")
        if os.environ.get("DROVISIO_REQUIRE_SHARED") == "1":  # CI has ../shared: never skip
            pytest.fail(msg)
        pytest.skip(msg)
    return files


@pytest.fixture(scope="session")
def opencv_images(opencv_files) -> dict[str, cv2.Mat]:
    return {f.name: cv2.imread(str(f)) for f in opencv_files}


@pytest.fixture(scope="session")
def true_camera() -> Camera:
    return Camera.drone_webcam()


@pytest.fixture(scope="session")
def rendered(true_camera):
    """20 rendered views (9×6 board, 3 cm squares, noise σ = 1 level) of the drone webcam."""
    from drovisio.calibration.synthetic import render_calibration_views

    return render_calibration_views(true_camera, N_RENDERED, seed=RENDER_SEED)


@pytest.fixture(scope="session")
def rendered_session(rendered):
    """A session with the 20 rendered views added and solved."""
    from drovisio.calibration.session import CalibrationSession
    from drovisio.calibration.synthetic import DEFAULT_BOARD

    s = CalibrationSession(DEFAULT_BOARD)
    for v in rendered:
        assert s.add_image(v.image, v.name).kept, v.name
    s.solve()
    return s


@pytest.fixture(scope="session")
def opencv_session(opencv_images, opencv_board):
    from drovisio.calibration.session import CalibrationSession

    s = CalibrationSession(opencv_board)
    for name, img in opencv_images.items():
        s.add_image(img, name)
    s.solve()
    return s
