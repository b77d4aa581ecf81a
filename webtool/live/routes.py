"""The live view's API and streams (the page itself is ``/live``, in :mod:`webtool.pages.routes`).

=========  ========================  ==========================================================
GET        /api/live/status          figures: fps, detect time, latency, bricks, source state,
                                     viewers, stream rate; ``access`` (full / viewer)
GET        /api/live/bricks          the bricks of the newest frame (poses, body frame, age)
GET        /api/live/frame.jpg       the newest annotated frame (``?level=N``: size/quality
                                     level, 0 = full size, quality 80); 503 before the first
POST       /api/live/target          ``{"spec": "nearest" | "LAYOUT" | "LAYOUT:INSTANCE" |
                                     "track:N" | "none"}``: the brick sent to the flight
                                     controller (a write: refused to viewer tokens and to other
                                     sites' pages)
GET        /api/live/scene           where the 3D view is: ``{"url": "/live/3d/", ...}``
WebSocket  /api/live/ws              the stream: text ``{"type": "state", ...}`` (figures,
                                     bricks, stream info) ≤ 5 per second, and binary JPEG
                                     frames; the page answers each frame with ``"ack"``
GET        /live/3d/                 the viser client of the 3D scene, served through this app
WebSocket  /live/3d                  …and its WebSocket, proxied to the viser server (bound to
                                     127.0.0.1), so the token and origin checks cover it too
=========  ========================  ==========================================================
"""

from __future__ import annotations

import asyncio
import time
from typing import Annotated

from fastapi import APIRouter, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import Response
from starlette.requests import HTTPConnection

from webtool.access import access_level
from webtool.deps import LiveStarted, started_live
from webtool.errors import BadInput, Conflict, Forbidden, Unavailable
from webtool.live.schemas import Bricks, LiveScene, LiveStatus, TargetBody, TargetSet
from webtool.live.service import LEVELS
from webtool.responses import NO_STORE, JSONResponse, json_safe
from webtool.viewer.proxy import viewer_router as viewer_router_for

router = APIRouter(prefix="/api/live", tags=["live"])


async def _scene(conn: HTTPConnection):
    svc = await started_live(conn)
    return await asyncio.to_thread(svc.start_scene)


viewer_router = viewer_router_for("/live/3d", "live", _scene)


@router.get("/status", response_model=LiveStatus)
async def status(request: Request, svc: LiveStarted) -> JSONResponse:
    st = svc.status()
    st["access"] = access_level(request)
    return JSONResponse(st, headers=NO_STORE)


@router.get("/bricks", response_model=Bricks)
async def bricks(svc: LiveStarted) -> JSONResponse:
    return JSONResponse({"seq": svc.seq, "bricks": svc.bricks_json()}, headers=NO_STORE)


@router.get("/frame.jpg")
async def frame(svc: LiveStarted, level: Annotated[int, Query(ge=0, lt=len(LEVELS))] = 0) -> Response:
    if svc.seq == 0:
        await svc.wait_frame(0, timeout=3.0)
    r = await asyncio.to_thread(svc.jpeg, level)
    if r is None:
        raise Unavailable(svc.error or "no frame yet: the source is starting or lost")
    seq, data = r
    return Response(data, media_type="image/jpeg",
                    headers={**NO_STORE, "X-Frame-Seq": str(seq)})


@router.post("/target", response_model=TargetSet)
async def target(request: Request, svc: LiveStarted, body: TargetBody) -> JSONResponse:
    if access_level(request) != "full":  # the middleware already refuses viewer writes
        raise Forbidden("read-only access")
    try:
        t = await asyncio.to_thread(svc.set_target, body.spec)
    except (ValueError, TypeError) as e:
        raise BadInput(f"bad target: {e}") from None
    except RuntimeError as e:
        raise Conflict(str(e)) from None
    return JSONResponse({"target": t}, headers=NO_STORE)


@router.get("/scene", response_model=LiveScene)
async def scene(svc: LiveStarted) -> JSONResponse:
    sc = await asyncio.to_thread(svc.start_scene)
    if sc is None or sc.port is None:
        raise Unavailable("the 3D view is not available")
    return JSONResponse({"url": "/live/3d/", "port": sc.port}, headers=NO_STORE)


# ------------------------------------------------------------------------------------------
# The image stream
# ------------------------------------------------------------------------------------------


@router.websocket("/ws")
async def live_ws(ws: WebSocket) -> None:
    svc = await started_live(ws)
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
                await ws.send_json(json_safe({
                    "type": "state", "access": access, "seq": seq, "status": svc.status(),
                    "bricks": svc.bricks_json(), "stream": st.info()}))
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

