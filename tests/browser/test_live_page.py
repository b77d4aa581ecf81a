"""The live page in headless Chromium: the camera image and the 3D scene of the sample
bricks; a non-local browser without the token is refused, one with a viewer token watches."""

from __future__ import annotations

import time

import pytest

from webtool.app import create_app
from webtool.settings import Settings

pytestmark = pytest.mark.browser

SAMPLE_BRICKS = ("drick-aruco-centre:1", "drick-aruco-pyramids:0")


class RemoteClient:
    """Outermost ASGI middleware: every request looks like it comes from a phone on the
    Wi-Fi (192.0.2.10), so the token middleware treats the browser as non-local."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket"):
            scope = dict(scope, client=("192.0.2.10", 50000))
        await self.app(scope, receive, send)


def _scene_status(page, base):
    return page.request.get(base + "/api/live/status").json().get("scene") or {}


def test_live_page_shows_image_and_3d_scene(page, live_server_factory, tmp_path):
    app = create_app(Settings())
    base = live_server_factory(app)
    page.set_default_timeout(120_000)
    page.goto(base + "/live")
    assert page.locator("h1").inner_text().strip() == "Live view"
    # the camera image arrives over the WebSocket and is displayed (several frames)
    page.wait_for_function("Number(document.getElementById('live-image').dataset.frames||0) >= 3"
                           " && document.getElementById('live-image').naturalWidth > 0")
    # figures and the bricks of the sample
    page.wait_for_function("document.getElementById('fig-source').textContent === 'live'")
    # the table follows the newest frame (a pose older than max_age is never shown: a loaded
    # machine may empty it for a while), so it is read in the same look as it is waited for
    page.wait_for_function(
        "bs => { const rows = [...document.querySelectorAll('#bricks-body tr[data-brick]')];"
        " return rows.length >= 2 && rows.some(r => bs.includes(r.dataset.brick)); }",
        arg=list(SAMPLE_BRICKS))
    assert page.locator("#fig-fps").inner_text().endswith("fps")
    assert page.locator("#fig-latency").inner_text().endswith("ms")
    # the 3D view: viser's client in the iframe, connected through the app, showing bricks
    frame = page.frame_locator("#scene-frame")
    frame.locator("canvas").first.wait_for(state="attached")
    deadline = time.monotonic() + 120   # a bound for failures only
    sc = {}
    while time.monotonic() < deadline:
        sc = _scene_status(page, base)
        if sc.get("clients", 0) >= 1 and any(b.split()[0] in SAMPLE_BRICKS
                                             for b in sc.get("bricks", [])):
            break
        time.sleep(0.5)
    assert sc.get("clients", 0) >= 1, sc
    assert any(b.split()[0] in SAMPLE_BRICKS for b in sc["bricks"]), sc
    page.screenshot(path=str(tmp_path / "live.png"), full_page=True)
    # choosing a target from the table: its button pressed in the same look as it is found
    # (the table empties while no pose is fresh, which a loaded machine reaches between
    # frames)
    page.wait_for_function("() => { const b = document.querySelector("
                           "'#bricks-body tr[data-brick] button');"
                           " if (b) b.click(); return Boolean(b); }")
    page.wait_for_function("document.getElementById('target-msg').textContent.startsWith('Target')")


def test_non_local_browser_needs_the_token(page, live_server_factory):
    settings = Settings(host="0.0.0.0", token="full-tok-1", viewer_token="view-tok-2")
    app = create_app(settings)
    app.add_middleware(RemoteClient)  # added last: runs first
    base = live_server_factory(app)
    r = page.goto(base + "/live")
    assert r.status == 401
    assert "Access token required" in page.content()
    assert page.request.get(base + "/api/live/status").status == 401
    # a viewer link: the page works, changes are refused
    r = page.goto(base + "/live?token=view-tok-2")
    assert r.status == 200
    page.wait_for_function("document.getElementById('live-image').naturalWidth > 0",
                           timeout=120_000)
    page.wait_for_function("document.getElementById('access-note').textContent.includes("
                           "'View-only')")
    assert page.locator(".target-btn").first.is_disabled()
    status = page.evaluate("fetch('/api/live/target', {method: 'POST', headers: "
                           "{'content-type': 'application/json'}, body: '{\"spec\": \"none\"}'})"
                           ".then(r => r.status)")
    assert status == 403
