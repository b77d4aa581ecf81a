"""The live view's API and streams (the page itself is ``/live``, in :mod:`webtool.routes.pages`).

=========  ========================  ==========================================================
GET        /api/live/status          figures: fps, detect time, latency, bricks, source state,
                                     viewers, stream rate; ``access`` (full / viewer)
GET        /api/live/bricks          the bricks of the newest frame (poses, body frame, age)
GET        /api/live/frame.jpg       the newest annotated frame (``?level=N``: size/quality
                                     level, 0 = full size, quality 80); 503 before the first
POST       /api/live/target          ``{"spec": "nearest" | "LAYOUT" | "LAYOUT:INSTANCE" |
                                     "track:N" | "none"}``: the brick sent to the flight
                                     controller (a write: refused to viewer tokens)
GET        /api/live/scene           where the 3D view is: ``{"url": "/live/3d/", ...}``
WebSocket  /api/live/ws              the stream: text ``{"type": "state", ...}`` (figures,
                                     bricks, stream info) ≤ 5 per second, and binary JPEG
                                     frames; the page answers each frame with ``"ack"``
GET        /live/3d/                 the viser client of the 3D scene, served through this app
WebSocket  /live/3d                  …and its WebSocket, proxied to the viser server (bound to
                                     127.0.0.1), so the token protects the 3D view too
=========  ========================  ==========================================================
"""

from __future__ import annotations

import asyncio
import threading
import time
from contextlib import asynccontextmanager

from fastapi import (
    APIRouter,
    Body,
    HTTPException,
    Request,
    WebSocket,
    WebSocketDisconnect,
)
from fastapi.responses import JSONResponse, Response

from webtool.access import access_level
from webtool.live_service import LEVELS, LiveService
from webtool.viser_proxy import client_response, proxy_socket

_create_lock = threading.Lock()


@asynccontextmanager
async def _lifespan(app):
    yield
    svc = getattr(app.state, "live", None)
    if svc is not None:
        await asyncio.to_thread(svc.close)


router = APIRouter(tags=["live"], lifespan=_lifespan)
NO_STORE = {"Cache-Control": "no-store"}


def get_live(app) -> LiveService:
    """The app's live service (made on first use; tests may put their own in app.state.live)."""
    svc = getattr(app.state, "live", None)
    if svc is None:
        with _create_lock:
            svc = getattr(app.state, "live", None)
            if svc is None:
                svc = LiveService(app.state.settings)
                app.state.live = svc
    svc.touch()
    return svc


async def _started(app) -> LiveService:
    svc = get_live(app)
    await asyncio.to_thread(svc.ensure_started)
    return svc


@router.get("/api/live/status")
async def status(request: Request) -> JSONResponse:
    svc = await _started(request.app)
    st = svc.status()
    st["access"] = access_level(request)
    return JSONResponse(st, headers=NO_STORE)


@router.get("/api/live/bricks")
async def bricks(request: Request) -> JSONResponse:
    svc = await _started(request.app)
    return JSONResponse({"seq": svc.seq, "bricks": svc.bricks_json()}, headers=NO_STORE)


@router.get("/api/live/frame.jpg")
async def frame(request: Request, level: int = 0) -> Response:
    svc = await _started(request.app)
    if not 0 <= level < len(LEVELS):
        raise HTTPException(422, f"level must be 0 to {len(LEVELS) - 1}")
    if svc.seq == 0:
        await svc.wait_frame(0, timeout=3.0)
    r = await asyncio.to_thread(svc.jpeg, level)
    if r is None:
        raise HTTPException(503, svc.error or "no frame yet: the source is starting or lost")
    seq, data = r
    return Response(data, media_type="image/jpeg",
                    headers={**NO_STORE, "X-Frame-Seq": str(seq)})


@router.post("/api/live/target")
async def target(request: Request, body: dict = Body(...)) -> JSONResponse:
    if access_level(request) != "full":  # the middleware already refuses viewer writes
        raise HTTPException(403, "read-only access")
    svc = await _started(request.app)
    spec = body.get("spec", body) if isinstance(body, dict) else body
    try:
        t = await asyncio.to_thread(svc.set_target, spec)
    except (ValueError, TypeError) as e:
        raise HTTPException(422, f"bad target: {e}") from None
    except RuntimeError as e:
        raise HTTPException(409, str(e)) from None
    return JSONResponse({"target": t}, headers=NO_STORE)


@router.get("/api/live/scene")
async def scene(request: Request) -> JSONResponse:
    svc = await _started(request.app)
    sc = await asyncio.to_thread(svc.start_scene)
    if sc is None or sc.port is None:
        raise HTTPException(503, "the 3D view is not available")
    from webtool.settings import is_loopback

    settings = request.app.state.settings
    direct = None
    if is_loopback(settings.host) and request.client and is_loopback(request.client.host):
        host = request.url.hostname or "127.0.0.1"
        host = f"[{host}]" if ":" in host and not host.startswith("[") else host
        direct = f"{request.url.scheme}://{host}:{sc.port}/"  # the host the page came from
    return JSONResponse({"url": "/live/3d/", "direct_url": direct, "port": sc.port},
                        headers=NO_STORE)


# ------------------------------------------------------------------------------------------
# The image stream
# ------------------------------------------------------------------------------------------


@router.websocket("/api/live/ws")
async def live_ws(ws: WebSocket) -> None:
    svc = await _started(ws.app)
    await ws.accept()
    vid, st = svc.add_viewer()
    access = access_level(ws)
    closed = asyncio.Event()

    async def reader() -> None:
        try:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                if (msg.get("text") or "").startswith("ack"):
                    st.on_ack()
                # nothing else is accepted here: changes go through POST (token-checked)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            closed.set()

    task = asyncio.create_task(reader())
    sent_seq = 0
    last_state = 0.0
    try:
        while not closed.is_set():
            seq = await svc.wait_frame(sent_seq, timeout=0.25)
            now = time.monotonic()
            if now - last_state >= 0.2:
                last_state = now
                stt = svc.status()
                await ws.send_json({"type": "state", "access": access, "seq": seq,
                                    "status": stt, "bricks": svc.bricks_json(),
                                    "stream": st.info()})
            if seq > sent_seq:
                if st.ready():
                    st.fps = svc.stream_fps()
                    r = await asyncio.to_thread(svc.jpeg, st.level)
                    if r is not None:
                        sent_seq, data = r
                        await ws.send_bytes(data)
                        st.on_sent(len(data))
                else:
                    await asyncio.sleep(0.01)
            svc.touch()
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass
    finally:
        svc.remove_viewer(vid)
        task.cancel()


# ------------------------------------------------------------------------------------------
# The viser client and its WebSocket, through this app
# ------------------------------------------------------------------------------------------

@router.get("/live/3d/{path:path}")
async def viser_client(request: Request, path: str = "") -> Response:
    svc = await _started(request.app)
    await asyncio.to_thread(svc.start_scene)
    return await client_response(request, path)


@router.websocket("/live/3d")
async def viser_socket(ws: WebSocket) -> None:
    svc = await _started(ws.app)
    sc = await asyncio.to_thread(svc.start_scene)
    await proxy_socket(ws, sc.port if sc is not None else None)
