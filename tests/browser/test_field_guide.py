"""The field guide's pages, driven in headless Chromium at phone (390×844) and laptop
(1280×800) sizes: the camera mount page (preview, measure from the live camera, save), the
square size asked before a camera's first solve, viser's own panel folded in the 3D views, and
the Help page, and a station's Fleet page with two drones. The screenshots of the guide (docs/images/*.jpg) are taken here; they are
written into docs/images only by `make docs` (DROVISIO_DOCS_IMAGES=1), so that `make test`
leaves the checkout as it found it."""

from __future__ import annotations

import json
import os
import re
import socket
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.mount import body_from_camera_angles, load_mount
from drovisio.pipeline import FrameOutput
from drovisio.raw_frame import RawFrame
from drovisio.resources import docs_dir
from drovisio.ros.messages import RosMessages, namespace_for
from drovisio.sinks.zenoh import ZenohSink
from drovisio.tracking import TrackedBrick
from webtool.app import create_app
from webtool.calibration.service import CalibrationService
from webtool.settings import Settings

pytestmark = pytest.mark.browser

SIZES = {"phone": {"width": 390, "height": 844}, "laptop": {"width": 1280, "height": 800}}
IMAGES = docs_dir() / "images"
#: `make docs` sets it: the screenshots replace the guide's pictures
WRITE_DOCS = os.environ.get("DROVISIO_DOCS_IMAGES", "") == "1"
SAMPLE_VIEWS = Path(__file__).resolve().parents[2] / "sample_sessions" / "calibration"
SAMPLE_VIDEO = SAMPLE_VIEWS.parent / "approach" / "approach.mp4"
#: viser's developer controls, which must not cover the tool's 3D views
VISER_DEV = ("Save Canvas", "Reset View", "Dev Settings", "Scene tree")


def _context(browser, size: str):
    mobile = size == "phone"
    return browser.new_context(viewport=SIZES[size], is_mobile=mobile, has_touch=mobile,
                               device_scale_factor=1)


def _shot(page, name: str, folder: Path) -> Path:
    folder = IMAGES if WRITE_DOCS else folder
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.jpg"
    page.evaluate("window.scrollTo(0, 0)")      # what one sees on opening the page
    page.screenshot(path=str(path), type="jpeg", quality=70)
    return path


def _no_sideways_scroll(page, size: str) -> None:
    assert page.evaluate("document.documentElement.scrollWidth") <= SIZES[size]["width"], size


def _viser_panel_folded(frame) -> None:
    """viser's page in the iframe is up, its canvas drawn, its developer panel folded."""
    frame.locator("canvas").first.wait_for(state="visible")
    for text in VISER_DEV:       # it folds once the server's placement arrives
        frame.get_by_text(text, exact=True).first.wait_for(state="hidden", timeout=120_000)


def _wait_3d(frame) -> None:
    _viser_panel_folded(frame)
    time.sleep(1.5)          # let the software renderer draw the scene before a screenshot


@pytest.mark.parametrize("size", ["phone", "laptop"])
def test_the_pages_of_the_field_guide(browser, live_server_factory, tmp_path, size):
    settings = Settings(calibration_dir=tmp_path / "cal", mount_dir=tmp_path / "mount",
                        designer_layouts_dir=tmp_path / "layouts", study_dir=tmp_path / "study",
                        sample_seconds_per_view=0.4)
    base = live_server_factory(create_app(settings))
    context = _context(browser, size)
    try:
        page = context.new_page()
        page.set_default_timeout(120_000)

        page.goto(base + "/")
        assert page.locator("section#mount a").is_visible()
        assert page.locator("section#help a").is_visible()
        _no_sideways_scroll(page, size)
        _shot(page, f"start-{size}", tmp_path / "shots")

        page.goto(base + "/calibration")
        page.wait_for_function("document.getElementById('live').naturalWidth > 0")
        # the board to print: the page's link gives the true-scale PDF
        pdf = page.request.get(base + page.get_attribute("#print-a4", "href"))
        assert pdf.ok and pdf.body()[:5] == b"%PDF-"
        assert page.locator("#print-a4").is_visible()
        _no_sideways_scroll(page, size)
        _shot(page, f"calibration-{size}", tmp_path / "shots")

        # the camera mount: the form moves the preview, the live camera measures it, it saves
        page.goto(base + "/mount")
        page.wait_for_function("document.getElementById('ground-text').textContent"
                               ".startsWith('At 1.5 m')")
        assert page.input_value("#tilt") == "20.0"
        _wait_3d(page.frame_locator("#preview-frame"))
        _no_sideways_scroll(page, size)
        _shot(page, f"mount-{size}", tmp_path / "shots")
        before = page.text_content("#ground-text")
        page.fill("#tilt", "35")
        page.wait_for_function(f"document.getElementById('ground-text').textContent !== "
                               f"{json.dumps(before)}")
        shown = page.request.get(base + "/api/mount/scene").json()["shown"]
        assert abs(shown["body_from_camera"][0][2]
                   - body_from_camera_angles(35.0, 0.0, 0.0, (0.08, 0, 0.05))[0, 2]) < 1e-6
        page.click("#measure-live")
        page.wait_for_function("document.getElementById('measure-msg').textContent"
                               ".startsWith('Measured from')")
        page.click("#use-measured")
        tilt = float(page.input_value("#tilt"))
        assert abs(tilt - 20.0) < 1.5, tilt
        page.click("#save-button")
        page.wait_for_function("document.getElementById('save-msg').textContent"
                               ".startsWith('Saved to')")
        saved = load_mount(tmp_path / "mount" / "mount.json").angles()
        assert abs(saved["tilt_deg"] - tilt) < 0.051 and saved["offset_m"] == [0.08, 0.0, 0.05]

        # the designer: one set of controls (the page's), viser's panel folded and empty
        page.goto(base + "/designer")
        page.wait_for_function("document.querySelectorAll('#example option').length > 0")
        page.click("#open-example")
        page.wait_for_function("document.querySelector('#mesh-info').textContent.includes('mm')")
        viewer = page.frame_locator("#viewer")
        _wait_3d(viewer)
        for label in ("Undo", "Redo", "Add codes", "Delete"):
            assert viewer.get_by_text(label, exact=True).count() == 0, label
        _no_sideways_scroll(page, size)
        _shot(page, f"designer-{size}", tmp_path / "shots")

        page.goto(base + "/live")
        page.wait_for_function("Number(document.getElementById('live-image').dataset.frames||0)"
                               " >= 3 && document.querySelectorAll('#bricks-body tr[data-brick]')"
                               ".length >= 1")
        _wait_3d(page.frame_locator("#scene-frame"))
        _no_sideways_scroll(page, size)
        _shot(page, f"live-{size}", tmp_path / "shots")

        page.goto(base + "/study")
        page.wait_for_function("document.getElementById('study-reports').textContent"
                               ".includes('No report yet')")
        assert page.locator("#study-start").is_enabled()
        _no_sideways_scroll(page, size)
        _shot(page, f"study-{size}", tmp_path / "shots")

        # the guide itself, with the pictures just taken
        page.goto(base + "/help")
        assert page.locator("h1").first.inner_text() == "Field guide"
        page.wait_for_function("[...document.images].every(i => i.complete)")
        widths = dict(page.eval_on_selector_all(
            "article img", "is => is.map(i => [i.getAttribute('src'), i.naturalWidth])"))
        assert len(widths) == 14
        for src, w in widths.items():
            name = src.rsplit("/", 1)[-1]
            # every picture of the guide is shipped, at the width of the screen it shows
            assert (IMAGES / name).is_file(), src
            assert w == SIZES[name[:-4].rsplit("-", 1)[1]]["width"], src
        _no_sideways_scroll(page, size)
    finally:
        context.close()


def _simulated_drones(port: int, rendered) -> list:
    """Two drones publishing to a station on loopback (what ``drovisio run --sink zenoh:``
    sends), each with a brick, its target and a camera picture."""
    sinks = []
    for k, drone_id in enumerate(("drone1", "drone2")):
        ns, prefix = namespace_for(drone_id)
        web = f"&web=http://192.168.1.{21 + k}:8080/"
        sinks.append(ZenohSink(f"zenoh:connect=tcp/127.0.0.1:{port}{web}",
                               RosMessages(None, None, (), namespace=ns, frame_prefix=prefix)))
    return sinks


def _feed(sinks, rendered, n: int) -> None:
    for k, sink in enumerate(sinks):
        t = time.time()
        b = TrackedBrick(layout="drick-aruco-centre", instance=k + 1, track=k + 1,
                         method="aruco", rvec=np.array([0.0, 0.0, 0.3 * k]),
                         tvec=np.array([0.05 * k, 0.02, 0.9 + 0.3 * k]),
                         covariance=np.eye(6) * 1e-6, t=t, t_measured=t, age=0.0,
                         measured=True)
        out = FrameOutput(source="cam", frame=n, seq=n, t=t, t_mono=time.monotonic(),
                          bricks=[b], target=b)
        sink.on_frame(RawFrame(image=rendered[k], index=n), out)
        sink.send(out)


@pytest.mark.parametrize("size", ["phone", "laptop"])
def test_the_fleet_page_of_a_station(browser, live_server_factory, tmp_path, size):
    port = _free_port()
    base = live_server_factory(create_app(Settings(station_listen=[f"tcp/127.0.0.1:{port}"],
                                                   data_dir=tmp_path)))
    cap = cv2.VideoCapture(str(SAMPLE_VIDEO))
    rendered = [cap.read()[1] for _ in range(121)][60::60]   # the bricks well in view
    cap.release()
    sinks = _simulated_drones(port, rendered)
    stop = threading.Event()

    def loop() -> None:
        n = 0
        while not stop.wait(1 / 15):
            _feed(sinks, rendered, n)
            n += 1

    feeder = threading.Thread(target=loop, daemon=True)
    feeder.start()
    context = _context(browser, size)
    try:
        page = context.new_page()
        page.set_default_timeout(120_000)
        page.goto(base + "/fleet")
        page.wait_for_function("document.querySelectorAll('#fleet-rows tr.live').length === 2"
                               " && [...document.querySelectorAll('#fleet-rows img')]"
                               ".filter(i => i.complete && i.naturalWidth > 0).length === 2")
        assert page.locator('#fleet-rows tr[data-drone="drone2"] td.target').inner_text() \
            .startswith("drick-aruco-centre #2 at ")
        _wait_3d(page.frame_locator("#scene-frame"))
        _no_sideways_scroll(page, size)
        _shot(page, f"fleet-{size}", tmp_path / "shots")
    finally:
        stop.set()
        feeder.join(60)
        for sink in sinks:
            sink.close()
        context.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _NoCamera:
    def __call__(self):
        raise OSError("/dev/video-test: no such device")


@pytest.mark.parametrize("size", ["phone", "laptop"])
def test_the_square_size_is_asked_before_a_cameras_first_solve(browser, live_server_factory,
                                                                 tmp_path, size):
    context = _context(browser, size)
    try:
        _square_size_asked(context.new_page(), live_server_factory, tmp_path)
    finally:
        context.close()


def _square_size_asked(page, live_server_factory, tmp_path) -> None:
    settings = Settings(calibration_dir=tmp_path / "cal", source="/dev/video-test")
    app = create_app(settings)
    app.state.calibration = CalibrationService(settings, source_factory=_NoCamera())
    base = live_server_factory(app)
    page.set_default_timeout(120_000)
    page.goto(base + "/calibration")
    page.set_input_files("#upload-files", [str(SAMPLE_VIEWS / f"view_{i:02d}.jpg")
                                           for i in range(10)])
    page.wait_for_function("document.getElementById('views-count').textContent === '10'")
    page.click("#solve")
    page.locator("#square-form").wait_for(state="visible")
    assert page.input_value("#square-mm") == "25"
    assert page.locator("#result:not([hidden])").count() == 0     # nothing solved yet
    page.fill("#square-mm", "24.6")
    page.click("#square-solve")
    page.wait_for_selector("#result:not([hidden]) #param-fx", state="attached")
    assert page.locator("#square-form").is_hidden()
    st = page.request.get(base + "/api/calibration/state").json()
    assert st["session"]["square_mm"] == 24.6 and st["session"]["square_measured"] is True
    # the next solve does not ask again
    page.click("#solve")
    assert page.locator("#square-form").is_hidden()
    assert re.search(r"\d", page.text_content("#param-fx"))
