"""No web page but the tool's own can change the tool or the drone: every write and every
socket checks Origin and Host (DNS rebinding), even from loopback; the viser ports and the
``ws://`` sink of ``drovisio run`` refuse browsers; tokens never reach the log."""

from __future__ import annotations

import asyncio
import logging

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"
FOREIGN = "http://evil.example"


@pytest.fixture
def app(tmp_path):
    a = create_app(Settings(calibration_dir=tmp_path / "cal", designer_layouts_dir=tmp_path,
                            replay_dir=tmp_path))
    yield a
    from webtool.services import close_services

    close_services(a)


def _concrete(path: str) -> str:
    return path.replace("{index}", "0").replace("{view_id}", "0").replace("{path:path}", "")


def _routes(app):
    """Every route of the app, the included routers' too."""
    for r in app.routes:
        router = getattr(r, "original_router", None)
        yield from (router.routes if router is not None else [r])


def write_routes(app) -> list[tuple[str, str]]:
    return [(m, _concrete(r.path)) for r in _routes(app)
            for m in sorted(getattr(r, "methods", None) or ())
            if m in ("POST", "PUT", "PATCH", "DELETE")]


def socket_routes(app) -> list[str]:
    return [_concrete(r.path) for r in _routes(app)
            if not getattr(r, "methods", None) and "websocket" in type(r).__name__.lower()]


def test_the_app_has_the_writes_and_sockets_this_test_covers(app):
    writes = write_routes(app)
    assert len(writes) >= 25 and ("POST", "/api/live/target") in writes
    assert set(socket_routes(app)) == {"/api/live/ws", "/live/3d", "/designer/3d", "/replay/3d",
                                      "/mount/3d", "/fleet/3d"}


def test_every_write_from_another_site_is_refused_even_on_loopback(app):
    c = TestClient(app, base_url=LOCAL, client=("127.0.0.1", 5000))
    refused = []
    for method, path in write_routes(app):
        r = c.request(method, path, json={}, headers={"Origin": FOREIGN})
        refused.append((method, path, r.status_code))
        assert r.status_code == 403, (method, path, r.status_code, r.text)
        assert "another site" in r.json()["detail"]
    # same request from the tool's own page: not refused by the middleware
    r = c.post("/api/live/target", json={"spec": "nearest"}, headers={"Origin": LOCAL})
    assert r.status_code == 200 and r.json()["target"]["spec"] == "nearest"


def test_cross_site_fetch_metadata_is_refused(app):
    c = TestClient(app, base_url=LOCAL)
    r = c.post("/api/designer/undo", headers={"Sec-Fetch-Site": "cross-site"})
    assert r.status_code == 403


def test_dns_rebinding_is_refused_for_reads_writes_and_sockets(app):
    c = TestClient(app, base_url="http://rebind.example:8080", client=("127.0.0.1", 5000))
    assert c.get("/api/health").status_code == 403
    assert c.get("/api/live/status").status_code == 403
    for method, path in write_routes(app):
        r = c.request(method, path, json={}, headers={"Origin": "http://rebind.example:8080"})
        assert r.status_code == 403, (method, path)
    for path in socket_routes(app):
        with pytest.raises(WebSocketDisconnect) as e, \
                c.websocket_connect("ws://rebind.example:8080" + path):
            pass
        assert e.value.code == 1008


def test_sockets_from_another_site_are_refused(app):
    c = TestClient(app, base_url=LOCAL, client=("127.0.0.1", 5000))
    for path in socket_routes(app):
        with pytest.raises(WebSocketDisconnect) as e, \
                c.websocket_connect("ws://127.0.0.1:8080" + path, headers={"Origin": FOREIGN}):
            pass
        assert e.value.code == 1008, path


def test_the_live_target_cannot_be_changed_from_a_foreign_origin(app):
    c = TestClient(app, base_url=LOCAL, client=("127.0.0.1", 5000))
    assert c.post("/api/live/target", json={"spec": "none"}, headers={"Origin": FOREIGN}
                  ).status_code == 403
    assert c.get("/api/live/status").json()["target"]["spec"] == "nearest"


def test_the_machine_names_and_ip_literals_are_accepted(app):
    from webtool.access import machine_names

    for host in ["127.0.0.1:8080", "localhost:8080", "[::1]:8080", "192.168.4.2:8080",
                 *[f"{n}:8080" for n in machine_names()]]:
        c = TestClient(app, base_url=f"http://{host}")
        assert c.get("/api/health").status_code == 200, host


def test_a_token_lets_a_reverse_proxy_name_through(tmp_path):
    app = create_app(Settings(host="0.0.0.0", token="tok-123456789", viewer_token="view-987"))
    c = TestClient(app, base_url="http://drone.site.example:8080")
    assert c.get("/api/health").status_code == 403
    assert c.get("/api/health", headers={"Authorization": "Bearer tok-123456789"}
                 ).status_code == 200


def test_viser_ports_refuse_browsers(app):
    """The 3D views' own ports (127.0.0.1) answer only the tool's proxy: a page that finds the
    port gets 403 for both its HTTP request and its WebSocket."""
    from websockets.asyncio.client import connect
    from websockets.exceptions import InvalidStatus

    c = TestClient(app, base_url=LOCAL)
    port = c.get("/api/live/scene").json()["port"]
    import viser

    proto = [f"viser-v{viser.__version__}"]

    async def attempt(origin: str | None) -> str:
        try:
            async with connect(f"ws://127.0.0.1:{port}", origin=origin, subprotocols=proto,
                               open_timeout=60) as ws:
                await ws.recv()
                return "open"
        except InvalidStatus as e:
            return str(e.response.status_code)

    assert asyncio.run(attempt("http://evil.example")) == "403"
    assert asyncio.run(attempt(None)) == "open"          # what the tool's proxy does


def test_ws_sink_refuses_web_pages_and_keeps_the_target():
    """``drovisio run --sink ws://...``: a web page's {"set_target": "none"} must not reach the
    flight controller's target; a program (no Origin) may change it."""
    import json

    from websockets.asyncio.client import connect
    from websockets.exceptions import InvalidStatus

    from drovisio.sinks.target import TargetSelector
    from drovisio.sinks.websocket import WebSocketSink

    target = TargetSelector("nearest")
    sink = WebSocketSink("127.0.0.1", 0, target=target)
    try:
        async def from_page() -> str:
            try:
                async with connect(f"ws://127.0.0.1:{sink.port}",
                                   origin="http://evil.example") as ws:
                    await ws.send(json.dumps({"set_target": "none"}))
                    return await ws.recv()
            except InvalidStatus as e:
                return str(e.response.status_code)

        async def from_program() -> str:
            async with connect(f"ws://127.0.0.1:{sink.port}") as ws:
                await ws.send(json.dumps({"set_target": "none"}))
                return await ws.recv()

        assert asyncio.run(from_page()) == "403"
        assert str(target.spec) == "nearest"
        assert json.loads(asyncio.run(from_program()))["target"]["spec"] == "none"
    finally:
        sink.close()


def test_tokens_never_reach_the_access_log(caplog):
    from webtool.access import install_log_redaction, redact_tokens

    assert redact_tokens('GET /live?token=abcDEF123&x=1 HTTP/1.1') == \
        "GET /live?token=***&x=1 HTTP/1.1"
    install_log_redaction()
    log = logging.getLogger("uvicorn.access")
    with caplog.at_level(logging.INFO, logger="uvicorn.access"):
        log.info('%s - "%s %s HTTP/%s" %d', "10.0.0.5:5555", "GET", "/?token=s3cret-XYZ",
                 "1.1", 200)
    assert "s3cret-XYZ" not in caplog.text and "token=***" in caplog.text
