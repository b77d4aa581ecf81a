"""Live view API: figures, frames, target, adaptive image stream, access, 3D proxy."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from drovisio.detect.result import BrickPose
from drovisio.layout import load_layouts, shipped_layouts_dir
from drovisio.pipeline import Pipeline
from drovisio.sources import FrameSource, RawFrame
from webtool.access import COOKIE_NAME
from webtool.app import create_app
from webtool.live.service import LEVELS, AdaptiveStream, LiveService
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"  # the Host a browser on this machine sends
LOCAL_WS = "ws://127.0.0.1:8080"

TOKEN, VIEWER = "full-token-123", "viewer-token-456"


class NoiseCamera:
    """640×480 noisy frames at 15 fps (JPEGs of realistic size)."""

    label = "noise camera"
    finite = False

    def __init__(self):
        self.rng = np.random.default_rng(0)
        self.base = self.rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
        self.i = 0

    def open(self):
        pass

    def read(self):
        time.sleep(1 / 15)
        self.i += 1
        return RawFrame(np.roll(self.base, self.i, axis=1), self.i)

    def close(self):
        pass


class OneBrick:
    name = "fake"

    def detect(self, image, gravity=None):
        return [BrickPose("drick-aruco-centre", 1, "aruco", np.array([3.1, 0.0, 0.0]),
                          np.array([0.1, 0.0, 1.5]), 0.2, markers=[1],
                          covariance=np.eye(6) * 1e-5,
                          image_points=np.array([[300, 200], [340, 200], [340, 240],
                                                 [300, 240.0]]))]


def _fake_pipeline(svc):
    from drovisio.camera import Camera

    svc.camera = Camera.from_fov()
    svc.layouts = load_layouts([shipped_layouts_dir() / "drick-aruco-centre.json"])
    return Pipeline(FrameSource(NoiseCamera()), [OneBrick()], layouts=svc.layouts)


def _app(settings=None, **kw):
    settings = settings or Settings()
    app = create_app(settings)
    app.state.live = LiveService(settings, pipeline_factory=_fake_pipeline, scene=False, **kw)
    return app


def test_adaptive_stream_keeps_under_the_share():
    t = [0.0]
    st = AdaptiveStream(1_000_000, fps=15, clock=lambda: t[0])
    sent = 0
    levels = []
    while t[0] < 20:
        if st.ready():
            size = int(90_000 * LEVELS[st.level][0] ** 2 * LEVELS[st.level][1] / 80)
            st.on_sent(size)
            sent += size
            levels.append(st.level)
            t[0] += 0.005
            st.on_ack()
        t[0] += 0.005
    rate = sent * 8 / 20
    assert rate <= 1_000_000 * 1.05, rate
    assert rate >= 0.5 * 1_000_000  # uses its share, not far below
    assert st.frames >= 15 * 20 * 0.6  # and keeps a useful frame rate
    assert LEVELS[levels[-1]][0] < 1.0  # shrank the image to fit
    # a quarter of the share: smaller images still
    t[0] = 0.0
    st4 = AdaptiveStream(250_000, fps=15, clock=lambda: t[0])
    for _ in range(400):
        if st4.ready():
            st4.on_sent(int(90_000 * LEVELS[st4.level][0] ** 2 * LEVELS[st4.level][1] / 80))
            st4.on_ack()
        t[0] += 0.01
    assert st4.level > levels[-1]
    # a slow link (late acknowledgements) steps down too
    st5 = AdaptiveStream(10_000_000, fps=15, clock=lambda: t[0])
    lvl = st5.level
    for _ in range(3):
        st5.on_sent(1000)
        t[0] += 1.0
        st5.on_ack()
    assert st5.level > lvl


def test_status_frame_bricks_and_target(until):
    app = _app()
    with TestClient(app, base_url=LOCAL) as c:
        st = c.get("/api/live/status").json()
        assert st["running"] and st["access"] == "full" and st["bandwidth_kbps"] == 2000
        # the first frame (503 before it: documented)
        until(lambda: app.state.live.seq > 0, pause=0.05)
        r = c.get("/api/live/frame.jpg?level=3")
        assert r.status_code == 200 and r.content[:2] == b"\xff\xd8"
        small = c.get("/api/live/frame.jpg?level=12").content
        assert len(small) < len(r.content) / 3
        assert c.get("/api/live/frame.jpg?level=99").status_code == 422
        # a pose older than max_age is never shown: a loaded machine may show none for a while
        b = until(lambda: c.get("/api/live/bricks").json()["bricks"], pause=0.05)
        assert b[0]["layout"] == "drick-aruco-centre" and b[0]["target"] is True
        assert "body_from_brick" in b[0] and b[0]["age"] <= 0.5
        # the uncertainty in words: measured σ √1e-5 m = 3.2 mm, 0.18°, plus the tracker's
        # floors (2 mm, 0.3°)
        m = re.fullmatch(r"± ([\d.]+) mm, ± ([\d.]+)°", b[0]["uncertainty"])
        assert m and 3.0 <= float(m[1]) <= 6.0 and 0.2 <= float(m[2]) <= 0.6, b[0]["uncertainty"]
        assert len(b[0]["covariance"]) == 6 and all(len(r) == 6 for r in b[0]["covariance"])
        r = c.post("/api/live/target", json={"spec": "drick-aruco-centre:2"})
        assert r.status_code == 200 and r.json()["target"]["instance"] == 2
        # the next frames have brick 1 but no target
        b = until(lambda: [x for x in c.get("/api/live/bricks").json()["bricks"]
                           if x["target"] is False], pause=0.05)
        assert b[0]["instance"] == 1
        assert c.post("/api/live/target", json={"spec": "a:b"}).status_code == 422
        st = c.get("/api/live/status").json()
        for k in ("fps", "detect_ms", "latency_ms", "bricks", "source"):
            assert k in st
        # the rate is this machine's (a loaded one is slow): that frames were counted
        assert st["source"]["state"] == "live" and st["fps"] > 0


def test_a_target_the_loaded_layouts_cannot_have_is_refused_in_one_line():
    app = _app()
    with TestClient(app, base_url=LOCAL) as c:
        for spec, detail in [
            ("track:-1", "bad target: track number: -1 is out of range: give a whole number "
                         "1 or more"),
            ("drick-aruco-centre:20", "bad target: drick-aruco-centre has instances 0 to 19; "
                                      "20 is not one of them"),
            ("drick-aruco-pyramids:1", "bad target: no layout named 'drick-aruco-pyramids' "
                                       "is in use (in use: drick-aruco-centre)")]:
            r = c.post("/api/live/target", json={"spec": spec})
            assert r.status_code == 422 and r.json()["detail"] == detail, r.text
        assert c.get("/api/live/status").json()["target"]["spec"] == "nearest"
        r = c.post("/api/live/target", json={"spec": "drick-aruco-centre:19"})
        assert r.status_code == 200 and r.json()["target"]["instance"] == 19


def test_another_sites_page_cannot_start_the_pipeline_with_a_get(until):
    app = _app()
    with TestClient(app, base_url=LOCAL) as c:
        # an <img> on another site's page: no Origin, but the browser says where it is from
        for headers in ({"Sec-Fetch-Site": "cross-site"}, {"Sec-Fetch-Site": "same-site"},
                        {"Origin": "http://evil.example"}):
            for path in ("/api/live/frame.jpg", "/api/live/status", "/live/3d/"):
                r = c.get(path, headers=headers)
                assert r.status_code == 403, (path, headers, r.status_code)
                assert "another site" in r.json()["detail"]
        assert app.state.live.pipeline is None and not app.state.live.status()["running"]
        # the tool's own page (and a program that says nothing) still start it: the picture,
        # or the documented 503 while a loaded machine's first frame is on its way
        r = c.get("/api/live/frame.jpg", headers={"Sec-Fetch-Site": "same-origin"})
        assert (r.status_code == 200 and r.content[:2] == b"\xff\xd8") or (
            r.status_code == 503 and "no frame yet" in r.json()["detail"]), r.status_code
        assert app.state.live.status()["running"]
        until(lambda: app.state.live.seq > 0, pause=0.05)
        r = c.get("/api/live/frame.jpg", headers={"Sec-Fetch-Site": "same-origin"})
        assert r.status_code == 200 and r.content[:2] == b"\xff\xd8"


def test_sockets_beyond_the_cap_are_refused_with_the_reason():
    from starlette.testclient import WebSocketDenialResponse

    app = _app(Settings(max_sockets=2))
    why = ("too many live views open (at most 2 streams and 3D views at once); close one "
           "and reload")
    with TestClient(app, base_url=LOCAL) as c:
        with c.websocket_connect(LOCAL_WS + "/api/live/ws") as a, \
                c.websocket_connect(LOCAL_WS + "/api/live/ws") as b:
            assert a.receive() and b.receive()
            for path in ("/api/live/ws", "/live/3d", "/designer/3d"):  # 3D views count too
                with pytest.raises(WebSocketDenialResponse) as e, \
                        c.websocket_connect(LOCAL_WS + path):
                    pass
                assert e.value.status_code == 503 and e.value.json()["detail"] == why
            assert app.state.live.viewers == 2
        # closed ones free their places
        with c.websocket_connect(LOCAL_WS + "/api/live/ws") as a, \
                c.websocket_connect(LOCAL_WS + "/api/live/ws") as b:
            assert a.receive() and b.receive()


def test_the_3d_relay_queues_two_messages_at_most(monkeypatch):
    """A browser that reads slowly must stop the relay reading from viser (whose buffer then
    keeps only the newest state of each thing) instead of the relay queueing for it."""
    import asyncio

    from webtool.viewer import proxy

    asked = {}

    async def refuse(url, **kw):
        asked.update(kw)
        raise OSError("no viser here")

    monkeypatch.setattr(proxy, "connect", refuse)

    class Ws:
        scope: dict = {}

        async def close(self, code=1000):
            asked["closed"] = code

    asyncio.run(proxy.proxy_socket(Ws(), 1))
    assert asked["closed"] == 1011 and asked["max_queue"] is not None
    assert asked["max_queue"] <= 2


def test_several_viewers_share_the_bandwidth_cap():
    app = _app(bandwidth_bps=800_000)
    with TestClient(app, base_url=LOCAL) as c:
        c.get("/api/live/status")
        with c.websocket_connect(LOCAL_WS + "/api/live/ws") as a, c.websocket_connect(LOCAL_WS + "/api/live/ws") as b:
            got = {id(a): [0, 0], id(b): [0, 0]}
            states = []
            t0 = time.monotonic()
            # until both have had five images (counted, not timed: a loaded machine is slow)
            while min(v[0] for v in got.values()) < 5:
                assert time.monotonic() - t0 < 60, got
                for ws in (a, b):
                    m = ws.receive()
                    if m.get("bytes"):
                        got[id(ws)][0] += 1
                        got[id(ws)][1] += len(m["bytes"])
                        ws.send_text("ack")
                    elif m.get("text"):
                        states.append(json.loads(m["text"]))
            dt = time.monotonic() - t0
        total_bps = sum(v[1] for v in got.values()) * 8 / dt
        assert all(v[0] >= 5 for v in got.values()), got  # both viewers get images
        # under the cap (+ the token bucket's initial burst of two frames per viewer)
        fps = app.state.live.max_fps
        burst = 2 * 2 * 400_000 / 8 / fps * 8 / dt  # bits of two frame budgets per viewer
        assert total_bps <= 800_000 + burst, total_bps
        s = [x for x in states if x["status"]["viewers"] == 2][-1]
        assert s["stream"]["share_kbps"] == 400.0 and s["type"] == "state"
        assert s["bricks"] and s["status"]["source"]["state"] == "live"


def test_token_viewer_token_and_refusals():
    settings = Settings(host="0.0.0.0", token=TOKEN, viewer_token=VIEWER)
    app = _app(settings)
    with TestClient(app, base_url=LOCAL) as remote:  # client host "testclient": not loopback
        assert remote.get("/live", headers={"accept": "text/html"}).status_code == 401
        assert remote.get("/api/live/status").status_code == 401
        assert remote.get("/api/live/frame.jpg").status_code == 401
        assert remote.post("/api/live/target", json={"spec": "nearest"}).status_code == 401
        assert remote.get("/live/3d/").status_code == 401
        from starlette.websockets import WebSocketDisconnect

        with pytest.raises(WebSocketDisconnect), remote.websocket_connect(LOCAL_WS + "/api/live/ws") as ws:
            ws.receive()
        # a viewer link: watches, cannot change
        r = remote.get(f"/live?token={VIEWER}")
        assert r.status_code == 200 and VIEWER in r.headers["set-cookie"]
        st = remote.get("/api/live/status").json()  # the cookie now
        assert st["access"] == "viewer"
        r = remote.post("/api/live/target", json={"spec": "none"})
        assert r.status_code == 403 and r.json()["detail"] == "read-only access"
        with remote.websocket_connect(LOCAL_WS + "/api/live/ws") as ws:
            m = ws.receive()
            assert m.get("bytes") or json.loads(m["text"])["access"] == "viewer"
        # the full token can change
        remote.cookies.set(COOKIE_NAME, TOKEN)
        assert remote.post("/api/live/target", json={"spec": "none"}).status_code == 200
    assert Settings(host="0.0.0.0").viewer_token and Settings().viewer_token is None


def test_3d_client_and_socket_through_the_proxy(until):
    import viser

    settings = Settings()
    app = create_app(settings)
    app.state.live = LiveService(settings, pipeline_factory=_fake_pipeline, scene=True)
    with TestClient(app, base_url=LOCAL) as c:
        r = c.get("/live/3d/")
        assert r.status_code == 200 and b"<html" in r.content[:2000].lower()
        info = c.get("/api/live/scene").json()
        assert info["url"] == "/live/3d/" and info["port"]
        with c.websocket_connect(LOCAL_WS + "/live/3d", subprotocols=[f"viser-v{viser.__version__}"]) as ws:
            m = ws.receive()
            assert m.get("bytes")  # viser's first (msgpack) message, relayed
        until(lambda: c.get("/api/live/status").json().get("scene", {}).get("bricks"),
              pause=0.05)
        assert any("drick-aruco-centre:1" in n
                   for n in c.get("/api/live/status").json()["scene"]["bricks"])


def test_access_lines_with_qr_codes():
    from webtool.access import access_lines, terminal_qr

    lines = access_lines("http://192.168.1.20:8080/", TOKEN, VIEWER)
    assert lines[0].endswith(f"http://192.168.1.20:8080/?token={TOKEN}")
    viewer = [x for x in lines if "view only" in x][0]
    assert viewer.endswith(f"http://192.168.1.20:8080/live?token={VIEWER}")
    qr = terminal_qr("http://x/")
    assert len(qr.splitlines()) > 10 and "█" in qr
    assert access_lines("http://h/", None, None) == []


def test_idle_service_releases_the_source_and_restarts(until):
    settings = Settings()
    svc = LiveService(settings, pipeline_factory=_fake_pipeline, scene=False, idle_timeout=0.3)
    try:
        svc.ensure_started()
        assert svc.status()["running"]
        # nobody watching: stopped (the camera is free for calibration)
        until(lambda: not svc.status()["running"], pause=0.05)
        svc.ensure_started()
        assert svc.status()["running"]
    finally:
        svc.close()
    assert not svc.status()["running"]


@pytest.mark.parametrize("name", ["rec", "x.mcap"])
def test_the_live_pipeline_removes_a_recording_that_got_no_frame_and_says_so(
        tmp_path, caplog, name):
    """The live page's pipeline records through the same recorders as ``drovisio run``: one
    that got no frame leaves no recording behind, said in one line in the server's log."""
    import cv2

    from drovisio.resources import sample_sessions_dir

    bad = tmp_path / "frames"
    bad.mkdir()
    ok, png = cv2.imencode(".png", np.full((480, 640, 3), 90, np.uint8))
    (bad / "f0.png").write_bytes(png.tobytes()[: len(png) // 2])    # cannot be decoded
    record = tmp_path / name
    settings = Settings(source=str(bad), camera=str(sample_sessions_dir() / "camera.yaml"),
                        layouts=[str(shipped_layouts_dir() / "drick-aruco-centre.json")],
                        record=str(record))
    svc = LiveService(settings, scene=False)
    try:
        with caplog.at_level("WARNING", logger="webtool"):
            svc.ensure_started()
            assert svc.error is None and svc._thread is not None
            svc._thread.join(60)            # the folder ends: the pipeline closes
            assert not svc._thread.is_alive()
    finally:
        svc.close()
    said = [r.getMessage() for r in caplog.records if r.name == "webtool"]
    assert said == [f"live: {record}: no frame was recorded; the empty recording was "
                    "removed"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames"]
