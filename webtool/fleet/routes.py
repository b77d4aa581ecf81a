"""The Fleet page's API (the page itself is ``/fleet``, in :mod:`webtool.pages.routes`).

=========  =================================  ====================================================
GET        /api/fleet/status                  every drone heard: live/lost, rate, latency,
                                              bricks, target, thumbnail, its web tool
GET        /api/fleet/drones/{id}/image.jpg   a drone's latest camera thumbnail (404 before one)
GET        /api/fleet/scene                   where the 3D view is: ``{"url": "/fleet/3d/"}``
GET        /fleet/3d/                         the viser client of the fleet's 3D view, and its
WebSocket  /fleet/3d                          WebSocket, proxied (access rules apply)
=========  =================================  ====================================================
"""

from __future__ import annotations

import asyncio
import re

from fastapi import APIRouter
from fastapi.responses import Response
from starlette.requests import HTTPConnection

from webtool.deps import FleetDep
from webtool.errors import NotFound
from webtool.fleet.scene import FleetScene
from webtool.fleet.schemas import FleetStatus
from webtool.fleet.service import FleetService
from webtool.responses import NO_STORE, JSONResponse
from webtool.schemas import SceneLink
from webtool.services import FLEET, get_service
from webtool.viewer.proxy import viewer_router as viewer_router_for

router = APIRouter(prefix="/api/fleet", tags=["fleet"])

_DRONE_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,31}$")


async def _scene(conn: HTTPConnection) -> FleetScene:
    svc: FleetService = get_service(conn.app, FLEET)
    return await asyncio.to_thread(svc.start_scene)


viewer_router = viewer_router_for("/fleet/3d", "fleet", _scene)


@router.get("/status", response_model=FleetStatus)
def status(svc: FleetDep) -> JSONResponse:
    return JSONResponse(svc.status(), headers=NO_STORE)


@router.get("/drones/{drone}/image.jpg")
def image(svc: FleetDep, drone: str) -> Response:
    if not _DRONE_ID.match(drone):
        raise NotFound(f"no drone {drone[:40]!r}: a drone id is a letter, then letters, "
                       "digits or _")
    return Response(svc.image(drone), media_type="image/jpeg", headers=NO_STORE)


@router.get("/scene", response_model=SceneLink)
async def scene(svc: FleetDep) -> JSONResponse:
    sc = await asyncio.to_thread(svc.start_scene)
    return JSONResponse({"url": "/fleet/3d/", "port": sc.port}, headers=NO_STORE)
