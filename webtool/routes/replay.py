"""Replay of simulated mission recordings (:mod:`webtool.replay`), shown in the live page.

=========  ========================  ==========================================================
GET        /api/replay/runs          the recordings in ``Settings.replay_dir`` (404 without one)
POST       /api/replay/load          ``{"name": FOLDER}`` (in replay_dir) or ``{"path": DIR}``
POST       /api/replay/play          start (or restart at the end) the playback
POST       /api/replay/pause         stop the clock
POST       /api/replay/seek          ``{"t": seconds}``
POST       /api/replay/speed         ``{"x": factor}`` (0.05 to 64)
GET        /api/replay/state         t, duration, playing, speed, state of the machine, drone
                                     pose and setpoint, events so far (count and the last
                                     ones in plain words), placed bricks
GET        /api/replay/scene         ``{"url": "/replay/3d/"}`` (starts the replay's viser)
GET        /replay/3d/               the viser client of the replay scene, through this app
WebSocket  /replay/3d                …and its WebSocket, proxied to the viser server
=========  ========================  ==========================================================

Every POST is a write: the token middleware refuses it to viewer tokens.
"""

from __future__ import annotations

import asyncio
import threading
from contextlib import asynccontextmanager
from typing import Annotated

from fastapi import (
    APIRouter,
    Body,
    HTTPException,
    Request,
    WebSocket,
)
from fastapi.responses import JSONResponse, Response

from webtool.replay import ReplayError, ReplayService
from webtool.viser_proxy import client_response, proxy_socket

_create_lock = threading.Lock()
NO_STORE = {"Cache-Control": "no-store"}


@asynccontextmanager
async def _lifespan(app):
    yield
    svc = getattr(app.state, "replay", None)
    if svc is not None:
        await asyncio.to_thread(svc.close)


router = APIRouter(tags=["replay"], lifespan=_lifespan)


def get_replay(app) -> ReplayService:
    svc = getattr(app.state, "replay", None)
    if svc is None:
        with _create_lock:
            svc = getattr(app.state, "replay", None)
            if svc is None:
                svc = app.state.replay = ReplayService(app.state.settings)
    return svc


async def _call(fn, *args) -> JSONResponse:
    try:
        out = await asyncio.to_thread(fn, *args)
    except ReplayError as e:
        raise HTTPException(e.status, str(e)) from None
    return JSONResponse(out, headers=NO_STORE)


def _number(body, key: str) -> float:
    v = body.get(key) if isinstance(body, dict) else body
    try:
        return float(v)
    except (TypeError, ValueError):
        raise HTTPException(422, f'give {{"{key}": a number}}') from None


@router.get("/api/replay/runs")
async def runs(request: Request) -> JSONResponse:
    svc = get_replay(request.app)
    try:
        items = await asyncio.to_thread(svc.runs)
    except ReplayError as e:
        raise HTTPException(e.status, str(e)) from None
    return JSONResponse({"folder": str(svc.settings.replay_dir), "runs": items},
                        headers=NO_STORE)


@router.post("/api/replay/load")
async def load(request: Request, body: Annotated[dict, Body()]) -> JSONResponse:
    svc = get_replay(request.app)
    return await _call(svc.load, body.get("name"), body.get("path"))


@router.post("/api/replay/play")
async def play(request: Request) -> JSONResponse:
    return await _call(get_replay(request.app).play)


@router.post("/api/replay/pause")
async def pause(request: Request) -> JSONResponse:
    return await _call(get_replay(request.app).pause)


@router.post("/api/replay/seek")
async def seek(request: Request, body: Annotated[dict, Body()]) -> JSONResponse:
    return await _call(get_replay(request.app).seek, _number(body, "t"))


@router.post("/api/replay/speed")
async def speed(request: Request, body: Annotated[dict, Body()]) -> JSONResponse:
    return await _call(get_replay(request.app).set_speed, _number(body, "x"))


@router.get("/api/replay/state")
async def state(request: Request) -> JSONResponse:
    return await _call(get_replay(request.app).state)


@router.get("/api/replay/scene")
async def scene(request: Request) -> JSONResponse:
    svc = get_replay(request.app)
    sc = await asyncio.to_thread(svc.start_scene)
    if sc is None or sc.port is None:
        raise HTTPException(503, "the 3D view is not available")
    return JSONResponse({"url": "/replay/3d/", "port": sc.port, "clients": sc.clients(),
                         "updates": sc.updates}, headers=NO_STORE)


# ------------------------------------------------------------------------------------------
# The viser client and its WebSocket, through this app (same client files as /live/3d/)
# ------------------------------------------------------------------------------------------


@router.get("/replay/3d/{path:path}")
async def viser_client(request: Request, path: str = "") -> Response:
    await asyncio.to_thread(get_replay(request.app).start_scene)
    return await client_response(request, path)


@router.websocket("/replay/3d")
async def viser_socket(ws: WebSocket) -> None:
    sc = await asyncio.to_thread(get_replay(ws.app).start_scene)
    await proxy_socket(ws, sc.port if sc is not None else None)
