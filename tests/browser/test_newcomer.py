"""A new user's first hour, in headless Chromium: the designer's save, the mount measured and
saved on the demo, a calibration used, then the live view using both; and every page at
390x844 no wider than the screen with touch targets of at least 44 px.

Everything the user makes goes to the test's own data folder: the checkout is left as it
was (`git status` unchanged)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from drovisio.layout import load_layout
from drovisio.mount import load_mount
from webtool.app import create_app
from webtool.settings import Settings

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[2]
PHONE = {"width": 390, "height": 844}
PAGES = ["/", "/calibration", "/mount", "/designer", "/live", "/study", "/help"]
#: a control smaller than this is missed by a thumb (the pages aim at 48 px)
MIN_TAP_PX = 44


def _git_status() -> str | None:
    try:
        return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"],
                              cwd=ROOT, capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None


def _phone(browser):
    return browser.new_context(viewport=PHONE, is_mobile=True, has_touch=True,
                               device_scale_factor=1)


def _fits_the_phone(page, where: str) -> None:
    got = page.evaluate("""() => {
      const de = document.documentElement;
      const small = [];
      for (const el of document.querySelectorAll('button, select, .button, input[type=submit]')) {
        const r = el.getBoundingClientRect();
        const cs = getComputedStyle(el);
        if (r.width === 0 || r.height === 0 || cs.visibility === 'hidden') continue;
        if (el.closest('details:not([open])')) continue;
        if (r.height < MIN_TAP) small.push((el.id || el.textContent.trim().slice(0, 30)) + ' ' + r.height);
      }
      const wide = [...document.querySelectorAll('body *')].filter(e => {
        const r = e.getBoundingClientRect(); return r.right > de.clientWidth + 0.5 && r.width > 0;
      }).slice(0, 5).map(e => e.tagName + '#' + e.id + '.' + e.className);
      return {scroll: de.scrollWidth, width: de.clientWidth, small, wide};
    }""".replace("MIN_TAP", str(MIN_TAP_PX)))
    assert got["scroll"] == got["width"] == PHONE["width"], (where, got)
    assert not got["small"], (where, got["small"])


def _small_report(folder: Path) -> None:
    """A study report (a few rendered frames) in the data folder's study/."""
    from drovisio.study.protocol import PROTOCOL_SCHEMA, default_protocol, load_protocol
    from drovisio.study.report import write_report
    from drovisio.study.run import run_study

    full = default_protocol(quick=True, frames=1)
    keep, seen = [], set()
    for s in full.steps:
        if s.layout == "code" and (s.figure, s.vary) not in seen:
            seen.add((s.figure, s.vary))
            keep.append(s.model_dump(exclude_none=True))
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "p.json"
    p.write_text(json.dumps({"schema": PROTOCOL_SCHEMA, "name": "small",
                             "layouts": [x.model_dump(exclude_none=True) for x in full.layouts
                                         if x.name == "code"], "steps": keep}))
    res = run_study(load_protocol(p), folder, methods=["drovisio-codes", "opencv"],
                    memory_seconds=0, speed_bricks=(1,), speed_frames=1)
    write_report(res, folder / "small", "drovisio study run --protocol p.json", "text")


def test_every_page_fits_a_phone(browser, live_server_factory, tmp_path):
    data = tmp_path / "data"
    _small_report(data / "study")
    from drovisio.resources import sample_sessions_dir

    base = live_server_factory(create_app(Settings(
        data_dir=data, sample_seconds_per_view=0.4,
        replay_dir=sample_sessions_dir() / "missions")))     # as `drovisio serve` has it
    context = _phone(browser)
    try:
        page = context.new_page()
        page.set_default_timeout(120_000)
        missing = []
        page.on("response", lambda r: missing.append(r.url) if r.status == 404 else None)
        for path in PAGES:
            page.goto(base + path)
            page.wait_for_load_state("load")
            page.wait_for_timeout(800)      # the page's first data arrives and is laid out
            _fits_the_phone(page, path)
        # the live page's replay panel, once a run is loaded
        page.goto(base + "/live")
        page.wait_for_function("document.getElementById('replay-run').value !== ''")
        page.click("#replay-load")
        page.wait_for_function("!document.getElementById('replay-play').disabled")
        _fits_the_phone(page, "/live with a replay")
        h = page.evaluate("document.getElementById('replay-frame').getBoundingClientRect()"
                          ".height")
        assert h >= 0.45 * PHONE["height"], h        # a 3D view, not a thumbnail
        # the study report
        page.goto(base + "/study/reports/small/report.html")
        page.wait_for_load_state("load")
        _fits_the_phone(page, "study report")
        # its figures are drawn at their own size (text legible), scrolled inside their box
        widths = page.eval_on_selector_all("figure img", "is => is.map(i => i.width)")
        assert widths and min(widths) >= 600, widths
        shots = ROOT / "test-results"
        shots.mkdir(exist_ok=True)
        page.evaluate("document.querySelector('figure').scrollIntoView()")
        page.screenshot(path=str(shots / "study-report-390.png"), full_page=False)
        assert not [u for u in missing if u.endswith("favicon.ico")], missing
    finally:
        context.close()


def test_the_newcomers_path(browser, live_server_factory, tmp_path):
    before = _git_status()
    data = tmp_path / "data"
    app = create_app(Settings(data_dir=data, sample_seconds_per_view=0.4))
    base = live_server_factory(app)
    context = _phone(browser)
    try:
        page = context.new_page()
        page.set_default_timeout(60_000)

        # 1. the designer: start from a shipped layout, save it under a new name
        page.goto(base + "/designer")
        page.wait_for_function("document.querySelectorAll('#example option').length > 2")
        page.select_option("#example", "layout:drick-aruco-pyramids.json")
        page.click("#open-example")
        page.wait_for_function("document.querySelector('#mesh-info').textContent.includes('mm')")
        page.fill("#layout-name", "my-first-brick")
        page.dispatch_event("#layout-name", "change")
        # a new brick type cannot reuse the shipped one's ids: the check offers free ones
        page.get_by_role("button", name="(free)").first.click()
        page.wait_for_function("!document.getElementById('save-button').disabled")
        page.click("#save-button")
        saved = data / "layouts" / "my-first-brick.json"
        page.wait_for_function("document.body.textContent.includes('Saved my-first-brick.json')")
        assert load_layout(saved).name == "my-first-brick"

        # 2. the mount, measured on the demo with "x arrow to the nose": tilt yes, pan no
        page.goto(base + "/mount")
        page.wait_for_function("document.getElementById('ground-text').textContent"
                               ".startsWith('At 1.5 m')")
        page.check("#aligned")
        page.click("#measure-live")
        page.wait_for_function("document.getElementById('measure-msg').textContent"
                               ".startsWith('Measured from')")
        msg = page.text_content("#measure-msg")
        assert "pan not measured" in msg and "Why no pan" in msg, msg
        page.click("#use-measured")
        assert abs(float(page.input_value("#tilt")) - 20.0) < 1.5
        assert float(page.input_value("#pan")) == 0.0
        page.fill("#tilt", "24")
        page.dispatch_event("#tilt", "input")
        page.wait_for_timeout(600)
        page.click("#save-button")
        page.wait_for_function("document.getElementById('save-msg').textContent"
                               ".startsWith('Saved to')")
        mount_file = data / "mount" / "mount.json"
        assert abs(load_mount(mount_file).angles()["tilt_deg"] - 24.0) < 0.051

        # 3. the calibration: the sample views, solved, used
        page.goto(base + "/calibration")
        page.wait_for_function("Number(document.getElementById('views-count').textContent) >= 10",
                               timeout=120_000)
        page.click("#solve")
        page.wait_for_selector("#result:not([hidden]) #result-verdict h3", timeout=120_000)
        page.click("#use")
        page.wait_for_function("document.getElementById('use-status').textContent"
                               ".includes('In use')")
        camera_file = Path(app.state.settings.camera)
        assert camera_file.is_relative_to(data / "calibration")

        # 4. the live view: both in use at once, no restart
        page.goto(base + "/live")
        page.wait_for_function("Number(document.getElementById('live-image').dataset.frames||0)"
                               " >= 3")
        live = app.state.live
        assert live.config().camera_file == camera_file
        assert live.config().mount_file == mount_file
        assert abs(live.mount.angles()["tilt_deg"] - 24.0) < 0.051
        page.wait_for_function("document.querySelectorAll('#bricks-body tr[data-brick]')"
                               ".length >= 1")
        label = page.text_content("#bricks-body tr[data-brick] td")
        assert label.startswith(("brick ", "a drick")), label
        _fits_the_phone(page, "/live")
    finally:
        context.close()
    # nothing written into the checkout
    if before is not None:
        assert _git_status() == before
