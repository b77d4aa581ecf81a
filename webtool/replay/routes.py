"""Replay of simulated mission recordings (:mod:`webtool.replay.service`), on the live page.

=========  ========================  ==========================================================
GET        /api/replay/runs          the recordings in ``Settings.replay_dir`` (404 without one)
POST       /api/replay/load          ``{"name": FOLDER}`` or ``{"path": DIR}`` (inside
                                     replay_dir; any other folder is refused)
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

Every POST is a write: the access middleware refuses it to viewer tokens and other sites.
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter

from webtool.deps import ReplayDep
from webtool.errors import Unavailable
from webtool.replay.schemas import (
    LoadBody,
    ReplayRuns,
    ReplayScene,
    ReplayState,
    SeekBody,
    SpeedBody,
)
from webtool.responses import NO_STORE, JSONResponse
from webtool.services import REPLAY, get_service
from webtool.viewer.proxy import viewer_router as viewer_router_for

router = APIRouter(prefix="/api/replay", tags=["replay"])
async def _scene(conn):
    return await asyncio.to_thread(get_service(conn.app, REPLAY).start_scene)


# the viser client and its WebSocket, through this app (same client files as /live/3d/)
viewer_router = viewer_router_for("/replay/3d", "replay", _scene)


async def _call(fn, *args) -> JSONResponse:
    return JSONResponse(await asyncio.to_thread(fn, *args), headers=NO_STORE)


def _now(fn, *args) -> JSONResponse:
    """The state and the clock's controls, answered on the event loop: they never wait
    (:class:`webtool.replay.service.Playback`), while the shared worker threads may all be
    waiting on another area (the live pipeline starting)."""
    return JSONResponse(fn(*args), headers=NO_STORE)


@router.get("/runs", response_model=ReplayRuns)
async def runs(svc: ReplayDep) -> JSONResponse:
    items = await asyncio.to_thread(svc.runs)
    return JSONResponse({"folder": str(svc.folder()), "runs": items}, headers=NO_STORE)


@router.post("/load", response_model=ReplayState)
async def load(svc: ReplayDep, body: LoadBody) -> JSONResponse:
    return await _call(svc.load, body.name, body.path)


@router.post("/play", response_model=ReplayState)
async def play(svc: ReplayDep) -> JSONResponse:
    return _now(svc.play)


@router.post("/pause", response_model=ReplayState)
async def pause(svc: ReplayDep) -> JSONResponse:
    return _now(svc.pause)


@router.post("/seek", response_model=ReplayState)
async def seek(svc: ReplayDep, body: SeekBody) -> JSONResponse:
    return _now(svc.seek, body.t)


@router.post("/speed", response_model=ReplayState)
async def speed(svc: ReplayDep, body: SpeedBody) -> JSONResponse:
    return _now(svc.set_speed, body.x)


@router.get("/state", response_model=ReplayState)
async def state(svc: ReplayDep) -> JSONResponse:
    return _now(svc.state)


@router.get("/scene", response_model=ReplayScene)
async def scene(svc: ReplayDep) -> JSONResponse:
    sc = await asyncio.to_thread(svc.start_scene)
    if sc is None or sc.port is None:
        raise Unavailable("the 3D view is not available")
    return JSONResponse({"url": "/replay/3d/", "port": sc.port, "clients": sc.clients(),
                         "updates": sc.updates}, headers=NO_STORE)
