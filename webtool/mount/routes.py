"""The camera mount: where the camera sits on the drone, as people measure it.

=======  =====================================  ================================================
GET      /api/mount                             the mount (tilt, pan, roll in degrees, offset
                                                in metres; FRD body frame), its matrix, the
                                                ground in view at the preview height, the file
POST     /api/mount/preview                     ``{"angles": {...}, "height_m": h}``: show it
                                                (not saved)
POST     /api/mount/save                        write the mount file (angles and matrix)
POST     /api/mount/measure?aligned=B           pictures (multipart ``files``) of a code lying
                                                flat, the drone level: proposed tilt and roll
                                                (and pan when the code's x points to the nose)
POST     /api/mount/measure-live  {"aligned"}   the same from the live camera's next frames
GET      /api/mount/scene                       ``{"url": "/mount/3d/"}`` (starts the preview)
GET      /mount/3d/                             the viser client of the preview, through this app
WebSocket /mount/3d                             …and its WebSocket
=======  =====================================  ================================================
Every POST is a write: the access middleware refuses it to viewer tokens and other sites.
"""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, File, Request, UploadFile

from webtool.deps import LiveDep, MountDep
from webtool.errors import Unavailable
from webtool.mount.schemas import LiveBody, MountMeasured, MountScene, MountState, PreviewBody
from webtool.responses import NO_STORE, JSONResponse
from webtool.services import MOUNT, get_service
from webtool.viewer.proxy import viewer_router as viewer_router_for

router = APIRouter(prefix="/api/mount", tags=["mount"])
async def _scene(conn):
    return await asyncio.to_thread(get_service(conn.app, MOUNT).start_scene)


viewer_router = viewer_router_for("/mount/3d", "mount", _scene)



async def _call(fn, *args) -> JSONResponse:
    return JSONResponse(await asyncio.to_thread(fn, *args), headers=NO_STORE)


@router.get("", response_model=MountState)
async def get_mount(svc: MountDep) -> JSONResponse:
    return await _call(svc.state)


@router.post("/preview", response_model=MountState)
async def preview(svc: MountDep, body: PreviewBody) -> JSONResponse:
    return await _call(svc.preview, body.angles, body.height_m)


@router.post("/save", response_model=MountState)
async def save(svc: MountDep, request: Request) -> JSONResponse:
    out = await _call(svc.save)
    await asyncio.to_thread(_live_reconfigure, request)
    return out


def _live_reconfigure(request: Request) -> None:
    """The live view uses the saved mount at once (if it was made already)."""
    live = getattr(request.app.state, "live", None)
    if live is not None and hasattr(live, "reconfigure"):
        live.reconfigure()


@router.post("/measure", response_model=MountMeasured)
def measure(svc: MountDep, files: Annotated[list[UploadFile], File()],
            aligned: bool = False) -> JSONResponse:
    got = svc.measure_pictures([(f.filename or "", f.file) for f in files], aligned)
    return JSONResponse(got, headers=NO_STORE)


@router.post("/measure-live", response_model=MountMeasured)
def measure_live(svc: MountDep, live: LiveDep, body: LiveBody) -> JSONResponse:
    return JSONResponse(svc.measure_live(live, body.aligned), headers=NO_STORE)


@router.get("/scene", response_model=MountScene)
async def scene(svc: MountDep) -> JSONResponse:
    sc = await asyncio.to_thread(svc.start_scene)
    if sc is None or sc.port is None:
        raise Unavailable("the 3D preview is not available")
    return JSONResponse({"url": "/mount/3d/", "port": sc.port, "clients": sc.clients(),
                         "shown": sc.shown}, headers=NO_STORE)
