"""The marker designer's JSON API (``/api/designer``), through FastAPI's TestClient, a raw ASGI
call and a live server: uploads (good, bad, too big), clicks, checks, fixes, saving, exports,
the 3D viewer's URL and its real click handler, shutdown."""

from __future__ import annotations

import asyncio
import socket
import threading
import time

import pytest
from fastapi.testclient import TestClient

from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.meshes import drick_mesh
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"  # the Host a browser on this machine sends
LOCAL_WS = "ws://127.0.0.1:8080"

DRICK = (shipped_layouts_dir() / "meshes" / "drick.stl").read_bytes()
API = "/api/designer"
CODE_RAYS = [([-0.076, 0.003, 1.0], [0.0, 0.0, -1.0]), ([0.074, -0.002, 1.0], [0.0, 0.0, -1.0])]
DOT_RAYS = [([x + 0.0012, y - 0.0014, 1.0], [0.0, 0.0, -1.0])
            for x in (-0.1, 0.0, 0.1) for y in (0.05, -0.05)]


@pytest.fixture
def app(tmp_path):
    a = create_app(Settings(designer_layouts_dir=tmp_path))
    yield a
    from webtool.services import close_services

    close_services(a)  # stops a viewer started without the lifespan


@pytest.fixture
def client(app):
    return TestClient(app, base_url=LOCAL)


def upload(client, data=DRICK, name="drick.stl", units="auto"):
    return client.post(f"{API}/mesh?filename={name}&units={units}", content=data)


def keys(state):
    return [c["key"] for c in state["checks"]]


def place_all(client):
    assert client.post(f"{API}/mode", json={"mode": "code"}).status_code == 200
    for o, d in CODE_RAYS:
        r = client.post(f"{API}/click", json={"origin": o, "direction": d})
        assert r.status_code == 200 and r.json()["click"]["action"] == "added"
    client.post(f"{API}/mode", json={"mode": "dot"})
    for o, d in DOT_RAYS:
        r = client.post(f"{API}/click", json={"origin": o, "direction": d})
    return r.json()


# ------------------------------------------------------------------ uploads


def test_upload_drick(client):
    r = upload(client)
    assert r.status_code == 200
    mesh = r.json()["mesh"]
    assert mesh["name"] == "drick.stl" and mesh["size_mm"] == [300.0, 150.0, 120.0]
    assert mesh["units"] == "m" and mesh["units_guessed"]
    assert "no-markers" in keys(r.json())


def test_upload_not_a_mesh(client):
    r = upload(client, b"Dear engineer,\nthis is a letter, not a model.\n", "letter.stl")
    assert r.status_code == 422
    assert "not a STL 3D model" in r.json()["detail"]
    r = upload(client, b"%PDF-1.4 ...", "drawing.pdf")
    assert r.status_code == 422 and "not 3D models this tool can read" in r.json()["detail"]


def test_upload_empty_mesh(client):
    r = upload(client, bytes(80) + (0).to_bytes(4, "little"), "empty.stl")
    assert r.status_code == 422 and "no triangles" in r.json()["detail"]
    r = upload(client, b"", "nothing.obj")
    assert r.status_code == 422 and "empty (0 bytes)" in r.json()["detail"]


def test_upload_in_mm_declared_as_m_warns(client):
    mm = drick_mesh()
    mm.apply_scale(1000)
    r = upload(client, mm.export(file_type="stl"), "drick-mm.stl", units="m")
    assert r.status_code == 200
    check = next(c for c in r.json()["checks"] if c["key"] == "units-suspect")
    assert check["severity"] == "warning" and "millimetres" in check["message"]
    r = client.post(f"{API}/fix", json={"action": check["fixes"][0]["action"]})
    assert r.json()["mesh"]["units"] == "mm" and "units-suspect" not in keys(r.json())


def test_200_mb_upload_refused_before_reading(app):
    """Raw ASGI call claiming 200 MB: the answer is 413 and the body is never read."""
    reads = []

    async def receive():
        reads.append(1)
        return {"type": "http.request", "body": b"x" * 65536, "more_body": True}

    sent = []

    async def send(message):
        sent.append(message)

    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
             "method": "POST", "scheme": "http", "path": f"{API}/mesh",
             "raw_path": f"{API}/mesh".encode(), "query_string": b"filename=big.stl",
             "root_path": "", "client": ("127.0.0.1", 50000), "server": ("127.0.0.1", 8080),
             "headers": [(b"host", b"127.0.0.1:8080"),
                         (b"content-length", str(200 * 1024 * 1024).encode()),
                         (b"content-type", b"application/octet-stream")]}
    asyncio.run(app(scope, receive, send))
    start = next(m for m in sent if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    assert start["status"] == 413
    assert reads == []  # not one byte of the body was read
    assert b"200 MB" in body and b"limit is 50 MB" in body and b"Simplify the model" in body


def test_200_mb_upload_refused_by_live_server(live_server_factory, tmp_path):
    """The same over a real socket: headers claim 200 MB, only 64 KB follow; the server
    answers 413 without waiting for the rest (which never comes: an answer at all shows it)."""
    base = live_server_factory(Settings(designer_layouts_dir=tmp_path))
    host, port = base.replace("http://", "").split(":")
    with socket.create_connection((host, int(port)), timeout=60) as s:
        s.sendall((f"POST {API}/mesh?filename=big.stl HTTP/1.1\r\nHost: {host}:{port}\r\n"
                   f"Content-Type: application/octet-stream\r\n"
                   f"Content-Length: {200 * 1024 * 1024}\r\n\r\n").encode() + b"x" * 65536)
        reply = b""
        while b"\r\n\r\n" not in reply or b"limit" not in reply:
            chunk = s.recv(65536)
            if not chunk:
                break
            reply += chunk
    assert reply.startswith(b"HTTP/1.1 413")
    assert b"limit is 50 MB" in reply


def test_streamed_upload_without_length_is_cut_at_the_limit(tmp_path):
    app = create_app(Settings(designer_layouts_dir=tmp_path, designer_max_upload_mb=0.001))
    c = TestClient(app, base_url=LOCAL)

    def chunks():
        for _ in range(100):
            yield b"y" * 1024

    r = c.post(f"{API}/mesh?filename=big.stl", content=chunks())
    assert r.status_code == 413 and "limit is 0 MB" in r.json()["detail"]


# ------------------------------------------------------------------ designing


def test_design_fix_save_export(client, tmp_path):
    upload(client)
    s = place_all(client)
    assert len(s["markers"]) == 8 and [m["id"] for m in s["markers"][:2]] == [70, 71]
    sym = next(c for c in s["checks"] if c["key"] == "symmetric-dots")
    assert sym["severity"] == "warning" and s["can_export"]
    s = client.post(f"{API}/fix", json={"action": sym["fixes"][0]["action"]}).json()
    assert "symmetric-dots" not in keys(s)
    assert client.post(f"{API}/layout", json={"name": "drick-x"}).status_code == 200
    r = client.post(f"{API}/save", json={"overwrite": False})
    assert r.status_code == 200, r.text
    assert (tmp_path / "drick-x.json").is_file() and (tmp_path / "meshes/drick-x.stl").is_file()
    lay = load_layout(tmp_path / "drick-x.json")
    assert lay.first_id == 70 and len(lay.markers) == 8
    r = client.post(f"{API}/save", json={})
    assert r.status_code == 422 and "already exists" in r.json()["detail"]
    assert client.post(f"{API}/save", json={"overwrite": True}).status_code == 200

    for path, ctype in [("layout.json", "application/json"), ("mesh.stl", "model/stl"),
                        ("brick.glb", "model/gltf-binary"), ("sheet.pdf", "application/pdf"),
                        ("sheet.svg?page=1", "image/svg+xml")]:
        r = client.get(f"{API}/export/{path}")
        assert r.status_code == 200 and r.headers["content-type"].startswith(ctype), path
        assert "attachment" in r.headers["content-disposition"]
    assert client.get(f"{API}/export/layout.json").json()["name"] == "drick-x"
    assert client.get(f"{API}/export/sheet.pdf").content.startswith(b"%PDF-1.4")
    assert client.get(f"{API}/export/sheet.svg?page=99").status_code == 422


def test_verify_on_a_simulated_photo(client):
    upload(client)
    s = place_all(client)
    sym = next(c for c in s["checks"] if c["key"] == "symmetric-dots")
    client.post(f"{API}/fix", json={"action": sym["fixes"][0]["action"]})
    r = client.post(f"{API}/verify")
    assert r.status_code == 200, r.text
    data = r.json()
    assert data["image"].startswith("data:image/jpeg;base64,")
    by = {x["method"]: x for x in data["results"]}
    assert by["aruco"]["found"] and by["dots"]["found"]
    assert by["aruco"]["position_error_mm"] < 10 and by["dots"]["position_error_mm"] < 10


def test_errors_block_export(client):
    upload(client)
    place_all(client)
    s = client.post(f"{API}/layout", json={"first_id": 20}).json()
    assert "ids-clash" in keys(s) and not s["can_export"]
    r = client.get(f"{API}/export/layout.json")
    assert r.status_code == 422 and "drick-aruco-pyramids" in r.json()["detail"]
    assert client.post(f"{API}/save", json={}).status_code == 422
    assert client.post(f"{API}/verify").status_code == 422


def test_marker_edits_and_undo(client):
    upload(client)
    place_all(client)
    s = client.post(f"{API}/markers/0", json={"size_mm": 50, "rotate_deg": 90}).json()
    assert s["markers"][0]["size_mm"] == 50 and s["selected"] == 0
    s = client.post(f"{API}/markers/2", json={"nudge_mm": [5, 0]}).json()
    assert s["markers"][2]["center_mm"] == [-95.0, 50.0, 0.0]
    s = client.post(f"{API}/markers/2", json={"centre": True}).json()
    assert s["markers"][2]["center_mm"] == [0.0, 0.0, 0.0]
    s = client.delete(f"{API}/markers/7").json()
    assert len(s["markers"]) == 7
    s = client.post(f"{API}/undo").json()
    assert len(s["markers"]) == 8 and s["can_redo"]
    assert client.post(f"{API}/markers/0", json={"colour": "red"}).status_code == 422
    assert client.post(f"{API}/markers/0", json={"color": "red"}).status_code == 422  # code
    assert client.post(f"{API}/markers/42", json={"size_mm": 3}).status_code == 422
    r = client.post(f"{API}/click", json={"origin": [0, 0], "direction": [0, 0, -1]})
    assert r.status_code == 422


def test_marker_sizes_are_bounded_like_the_layouts_checks(client):
    upload(client)
    place_all(client)
    before = client.get(f"{API}/state").json()
    for path, body, field, bound in [
            ("/defaults", {"code_size_mm": 1e-300}, "code_size_mm", "greater than or equal to 1"),
            ("/defaults", {"dot_diameter_mm": 0.5}, "dot_diameter_mm", "greater than or equal to 1"),
            ("/defaults", {"code_size_mm": 5001}, "code_size_mm", "less than or equal to 5000"),
            ("/markers/0", {"size_mm": 1e-9}, "size_mm", "greater than or equal to 1"),
            ("/fix", {"action": {"op": "set_size", "marker": 0, "size": 1e-6}}, "action.size",
             "greater than or equal to 0.001")]:
        r = client.post(API + path, json=body)
        assert r.status_code == 422, (path, body, r.text)
        assert r.json()["detail"] == f"{field}: Input should be {bound}", r.text
    after = client.get(f"{API}/state").json()
    assert after["markers"] == before["markers"] and after["defaults"] == before["defaults"]
    # the core's own check says the same range (the 3D view's and the fixes' path)
    from drovisio.designer.model import DesignError
    from drovisio.designer.model.edits import check_size

    with pytest.raises(DesignError, match="from 1 mm to 5 m"):
        check_size(0.0005)
    s = client.post(f"{API}/markers/0", json={"size_mm": 1}).json()
    assert s["markers"][0]["size_mm"] == 1.0


def test_frame_open_and_nothing_loaded(client):
    assert client.post(f"{API}/click", json={"origin": [0, 0, 1],
                                             "direction": [0, 0, -1]}).json()["click"][
        "action"] == "none"
    assert client.post(f"{API}/units", json={"units": "mm"}).status_code == 409
    s = client.post(f"{API}/open", json={"example": "layout:drick-dots-2x3.json"}).json()
    assert len(s["markers"]) == 6 and s["layout"]["symmetry"] == "rot180_z"
    assert "symmetric-declared" in keys(s)
    s = client.post(f"{API}/frame", json={"action": "turn", "angle_deg": 90}).json()
    assert s["mesh"]["size_mm"] == [150.0, 300.0, 120.0]
    s = client.post(f"{API}/frame", json={"action": "align_x"}).json()
    assert s["mesh"]["size_mm"] == [300.0, 150.0, 120.0]
    assert client.post(f"{API}/frame", json={"action": "spin"}).status_code == 422
    assert client.post(f"{API}/open", json={"example": "layout:nope.json"}).status_code == 422


def test_long_poll_wakes_on_change(client, monkeypatch):
    from webtool.designer import routes

    # a poll that is not woken waits two minutes: an answer within one shows the wake-up,
    # however slow a loaded machine is
    monkeypatch.setattr(routes, "LONG_POLL_S", 120.0)
    upload(client)
    v = client.get(f"{API}/state").json()["version"]
    t = threading.Timer(0.3, lambda: client.post(f"{API}/mode", json={"mode": "dot"}))
    t.start()
    t0 = time.monotonic()
    s = client.get(f"{API}/state?after={v}").json()
    assert s["version"] != v and s["mode"] == "dot" and time.monotonic() - t0 < 60
    t.join()


# ------------------------------------------------------------------ the 3D viewer


def test_viewer_url_click_handler_and_shutdown(tmp_path):
    """The viewer's URL uses the host the page was reached at; a click on the mesh node in
    viser (a world-frame ray) goes through the registered handler and places a marker; app
    shutdown stops the viewer."""
    from viser._scene_handles import SceneNodePointerEvent

    app = create_app(Settings(designer_layouts_dir=tmp_path))
    with TestClient(app, base_url="http://192.168.7.21:8080") as c:
        upload(c)
        v = c.get(f"{API}/viewer").json()
        assert v["url"] == "/designer/3d/"
        session = app.state.designer
        viewer = session.viewer()
        mesh_node = viewer.mesh_handle
        # the viser click callback, with a synthetic ray from above the +x pyramid
        c.post(f"{API}/mode", json={"mode": "code"})
        event = SceneNodePointerEvent(client=None, client_id=0, event="click", target=mesh_node,
                                      ray_origin=(0.074, 0.002, 1.0),
                                      ray_direction=(0.0, 0.0, -1.0), screen_pos=(0.5, 0.5),
                                      instance_index=None, modifier=None)
        callbacks = [e.callback for e in mesh_node._impl.click_cb]
        assert len(callbacks) == 1
        callbacks[0](event)
        s = c.get(f"{API}/state").json()
        assert len(s["markers"]) == 1 and s["markers"][0]["center_mm"] == [75.0, 0.0, 20.0]
        assert len(viewer._marker_handles) == 1  # the code's image node (+ label)
        # the scene's world frame is the brick frame: the mesh node is posed brick_from_mesh
        c.post(f"{API}/frame", json={"action": "turn", "angle_deg": 90})
        wx = viewer.model.wxyz
        assert abs(abs(wx[0]) - 0.7071) < 1e-3 and abs(abs(wx[3]) - 0.7071) < 1e-3
        event2 = SceneNodePointerEvent(client=None, client_id=0, event="click", target=mesh_node,
                                       ray_origin=(0.002, 0.075, 1.0),
                                       ray_direction=(0.0, 0.0, -1.0), screen_pos=(0.5, 0.5),
                                       instance_index=None, modifier=None)
        callbacks[0](event2)  # the same pyramid, now at brick y = +0.075
        s = c.get(f"{API}/state").json()
        assert len(s["markers"]) == 2
        assert s["markers"][1]["center_mm"] == pytest.approx([0.0, 75.0, 20.0], abs=1e-6)
        # dragging code 1 in the 3D view: rays from the viewer's camera through the pointer
        from types import SimpleNamespace

        node = viewer._marker_handles[1][0]
        drag = [e.callback for e in node._impl.drag_cb]
        assert len(drag) == 1
        cam = SimpleNamespace(camera=SimpleNamespace(position=(0.0, 0.3, 1.0)))
        for phase, target in (("start", (0.0, 0.075, 0.02)), ("update", (0.0, 0.08, 0.02)),
                              ("end", (-0.012, 0.093, 0.02))):
            drag[0](SimpleNamespace(client=cam, phase=phase, end_position=target))
        s = c.get(f"{API}/state").json()
        # beyond the 10 mm centre snap: on the 5 mm grid of the face
        assert s["markers"][1]["center_mm"] == pytest.approx([-10.0, 95.0, 20.0], abs=1e-6)
        assert s["message"].startswith("Moved code 1")
        c.post(f"{API}/undo")  # one undo step for the whole drag
        s = c.get(f"{API}/state").json()
        assert s["markers"][1]["center_mm"] == pytest.approx([0.0, 75.0, 20.0], abs=1e-6)
        port = v["port"]
        with socket.create_connection(("127.0.0.1", port), timeout=2):
            pass
    # lifespan shutdown stopped the viewer
    deadline = time.monotonic() + 60     # a bound for failures only
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                pass
        except OSError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("the viewer still listens after app shutdown")


def test_page_has_the_panel_and_viewer(client):
    html = client.get("/designer").text
    for needle in ('id="viewer"', 'id="upload-input"', 'id="checks"', 'id="marker-list"',
                   'id="save-button"', 'id="dl-pdf"', '/static/designer.js'):
        assert needle in html
    js = client.get("/static/designer.js")
    assert js.status_code == 200 and "/api/designer" in js.text


def test_viewer_is_proxied_and_needs_full_access(tmp_path):
    """The designer's viser listens on 127.0.0.1 only, even when the tool serves the network;
    the page reaches it through the app (/designer/3d), under the token; a view-only link
    cannot open its socket (the 3D view edits the design)."""
    import viser
    from starlette.websockets import WebSocketDisconnect

    from webtool.access import COOKIE_NAME

    full, view = "full-token-abc", "view-token-def"
    app = create_app(Settings(host="0.0.0.0", token=full, viewer_token=view,
                              designer_layouts_dir=tmp_path))
    proto = [f"viser-v{viser.__version__}"]
    with TestClient(app, base_url=LOCAL) as remote:          # client "testclient": not loopback
        assert remote.get("/designer/3d/").status_code == 401
        remote.cookies.set(COOKIE_NAME, full)
        v = remote.get(f"{API}/viewer").json()
        assert v["url"] == "/designer/3d/" and "direct_url" not in v
        server = app.state.designer.viewer().server
        assert server.get_host() == "127.0.0.1"
        r = remote.get("/designer/3d/")
        assert r.status_code == 200 and b"<html" in r.content[:2000].lower()
        with remote.websocket_connect(LOCAL_WS + "/designer/3d", subprotocols=proto) as ws:
            assert ws.receive().get("bytes")          # viser's first message, relayed
        remote.cookies.set(COOKIE_NAME, view)
        with pytest.raises(WebSocketDisconnect) as e, \
                remote.websocket_connect(LOCAL_WS + "/designer/3d", subprotocols=proto) as ws:
            ws.receive()
        assert e.value.code == 1008
