"""The calibration page in headless Chromium: a whole session on the sample session (auto-capture,
the heatmap and the hint change, solve, download a camera file that loads, nothing lost on
reload), and a camera that disappears mid-session."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from drovisio.camera_file import load_camera
from webtool.app import create_app
from webtool.calibration.service import CalibrationService
from webtool.settings import Settings

pytestmark = pytest.mark.browser

REPO = Path(__file__).resolve().parents[2]
TRUE_CAMERA = REPO / "sample_sessions" / "camera.yaml"
N_VIEWS = 6

VIEWS = "Number(document.getElementById('views-count').textContent)"


def test_whole_session_on_the_sample(page, live_server_factory, tmp_path):
    url = live_server_factory(Settings(calibration_dir=tmp_path / "cal",
                                       sample_seconds_per_view=0.4))
    page.goto(url + "/calibration")
    page.wait_for_function("document.getElementById('next-action').textContent !== 'Loading…'"
                           " && document.querySelectorAll('#heatmap rect').length > 0")
    heat0 = page.inner_html("#heatmap")
    hint0 = page.text_content("#next-action")
    outline0 = page.get_attribute("#hint-outline", "points")

    # auto-capture keeps views by itself; the heatmap and the hint follow
    page.wait_for_function(f"{VIEWS} >= {N_VIEWS}", timeout=120_000)
    page.wait_for_function("document.getElementById('live').naturalWidth > 0")
    assert page.inner_html("#heatmap") != heat0
    assert page.text_content("#next-action") != hint0
    assert page.get_attribute("#hint-outline", "points") != outline0
    assert page.locator("#views li").count() >= N_VIEWS
    assert "px" in page.text_content("#p-uncert .val")

    page.click("#solve")
    page.wait_for_selector("#result:not([hidden]) #result-verdict h3")
    # plain words first; the figures one click away
    assert page.locator("#param-fx").is_hidden()
    page.click("#result-details > summary")
    page.wait_for_selector("#result:not([hidden]) #param-fx")
    assert page.locator("#params tbody tr").count() == 9
    assert page.text_content("#result-verdict h3") in ("Good calibration", "Not good enough yet")
    assert "RMS reprojection error" in page.text_content("#rms")
    assert "root mean square" in page.text_content("#rms-def")
    page.wait_for_function("document.getElementById('uncertainty-map').naturalWidth > 0")
    assert page.text_content("#lens-result").startswith("Lens model: normal lens")
    # the shipped views are of a flat (rendered) board: said, not flagged
    assert page.text_content("#board-flatness").startswith(
        "Board: the board is flat within the measurement")
    assert "error" not in (page.get_attribute("#board-flatness", "class") or "")

    # the lens choice: "choose for me" solves again and says why it kept the normal model
    page.select_option("#lens", "auto")
    page.wait_for_function(
        "document.getElementById('lens-result').textContent.includes('held-out RMS')",
        timeout=120_000)
    assert "kept plumb_bob" in page.text_content("#lens-result")
    assert page.locator("#params tbody tr").count() == 9

    with page.expect_download() as dl:
        page.click("#download-opencv")
    saved = tmp_path / "downloaded.yaml"
    dl.value.save_as(saved)
    assert dl.value.suggested_filename.endswith(".yaml")
    cam, truth = load_camera(saved), load_camera(TRUE_CAMERA)
    assert abs(cam.fx - truth.fx) / truth.fx < 0.01, (cam.fx, truth.fx)

    page.click("#use")
    page.wait_for_function("document.getElementById('use-status').textContent.includes('In use')")

    # a reload loses nothing: the views and the result come back
    n = int(page.text_content("#views-count"))
    page.reload()
    page.wait_for_function(f"{VIEWS} >= {n}")
    page.wait_for_selector("#result:not([hidden]) #param-fx", state="attached")
    assert "camera.yaml" in page.text_content("#s-camera")


class _Unplugged:
    """Two still frames of a sample view, then nothing: the camera was pulled out."""

    label = "test camera"
    finite = False

    def __init__(self) -> None:
        import cv2

        img = cv2.imread(str(REPO / "sample_sessions" / "calibration" / "view_00.jpg"))
        self.frames = [img, img, img]

    def open(self) -> None:
        pass

    def read(self):
        from drovisio.sources import RawFrame

        time.sleep(0.02)
        return RawFrame(self.frames.pop(), 0) if self.frames else None

    def close(self) -> None:
        pass


def test_camera_disconnected_mid_session(page, live_server_factory, tmp_path):
    settings = Settings(calibration_dir=tmp_path / "cal", source="/dev/video-test")
    app = create_app(settings)
    calls = {"n": 0}

    def factory():
        calls["n"] += 1
        if calls["n"] == 1:
            return _Unplugged()
        raise OSError("/dev/video-test: no such device")

    app.state.calibration = CalibrationService(settings, source_factory=factory)
    url = live_server_factory(app)
    page.goto(url + "/calibration")
    page.wait_for_function("document.getElementById('camera-status').textContent"
                           ".includes('Camera disconnected — retrying')")
    assert page.locator("#camera-status.warn").count() == 1
    assert page.text_content("#views-count") == "1"
    assert "The 1 view captured so far is saved." in page.text_content("#camera-status")
    assert page.is_visible("#stage-msg")
    assert page.locator("#capture").is_disabled()
