"""JSON API of the calibration page, under ``/api/calibration`` (the page and the tests share it).

=======  ===========================  =========================================================
GET      /state                       everything the page shows (views, coverage, hint,
                                      progress, camera status, solve status)
GET      /frame.jpg?after=SEQ         the latest live frame with the detected corners drawn
                                      (waits up to 1 s for a newer one; 503 while the camera
                                      is disconnected); ``X-Frame-Seq`` gives its number
POST     /auto  {"on": bool}          auto-capture on or off
POST     /capture                     keep the current frame (manual capture)
GET      /views/{id}/thumb.jpg        a kept view, small, corners drawn
DELETE   /views/{id}                  remove a view (its image moves to ``deleted/``)
POST     /upload  (multipart files)   images taken elsewhere; one message per file
POST     /solve                       solve in the background and show the result
GET      /result[?download=1]         the report (parameters ± σ, RMS, uncertainty, verdict…)
GET      /uncertainty.png             the projection-uncertainty map as an image
GET      /camera-file?format=F        the camera file: opencv (YAML, default), ros or json
POST     /use                         make the result this server's camera (settings.camera)
POST     /session  {board, square_m}  start a new session (the old one stays on disk)
=======  ===========================  =========================================================

Errors answer ``{"detail": "..."}`` in plain words, with 404 (nothing there yet), 409 (not
possible now), 422 (bad input).
"""

from __future__ import annotations

import json
import threading
from contextlib import asynccontextmanager
from typing import Annotated

from fastapi import APIRouter, Body, Depends, File, HTTPException, Request, UploadFile
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel

from webtool.calibration_service import CalibrationService, ServiceError

_create_lock = threading.Lock()


@asynccontextmanager
async def _lifespan(app):
    yield
    close_service(app)


router = APIRouter(tags=["calibration"], lifespan=_lifespan)

NO_STORE = {"Cache-Control": "no-store"}


def get_service(request: Request) -> CalibrationService:
    """The app's calibration service (made on first use), told that someone is watching."""
    app = request.app
    svc = getattr(app.state, "calibration", None)
    if svc is None:
        with _create_lock:
            svc = getattr(app.state, "calibration", None)
            if svc is None:
                svc = CalibrationService(app.state.settings)
                app.state.calibration = svc
    svc.touch()
    return svc


def close_service(app) -> None:
    svc = getattr(app.state, "calibration", None)
    if svc is not None:
        svc.close()


Service = Annotated[CalibrationService, Depends(get_service)]


def _fail(e: ServiceError) -> HTTPException:
    return HTTPException(status_code=e.status, detail=str(e))


@router.get("/state")
def state(svc: Service) -> JSONResponse:
    return JSONResponse(svc.state(), headers=NO_STORE)


@router.get("/frame.jpg")
def frame(svc: Service, after: int = -1) -> Response:
    data, seq = svc.latest_frame(after, wait=1.0)
    if data is None:
        return JSONResponse({"detail": svc.camera_message or "no picture from the camera yet"},
                            status_code=503, headers={**NO_STORE, "X-Frame-Seq": str(seq)})
    return Response(data, media_type="image/jpeg", headers={**NO_STORE, "X-Frame-Seq": str(seq)})


class AutoBody(BaseModel):
    on: bool


@router.post("/auto")
def auto(svc: Service, body: AutoBody) -> dict:
    svc.set_auto(body.on)
    return {"auto_capture": svc.auto_capture}


@router.post("/capture")
def capture(svc: Service) -> dict:
    try:
        return svc.capture()
    except ServiceError as e:
        raise _fail(e) from None


@router.get("/views/{view_id}/thumb.jpg")
def thumb(svc: Service, view_id: int) -> Response:
    try:
        data = svc.thumbnail(view_id)
    except ServiceError as e:
        raise _fail(e) from None
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "max-age=3600"})


@router.delete("/views/{view_id}")
def delete_view(svc: Service, view_id: int) -> dict:
    try:
        svc.delete_view(view_id)
    except ServiceError as e:
        raise _fail(e) from None
    return {"deleted": view_id, "views": len(svc.session.views)}


@router.post("/upload")
def upload(svc: Service, files: Annotated[list[UploadFile], File()]) -> dict:
    try:
        return svc.upload([(f.filename or "", f.file) for f in files])
    except ServiceError as e:
        raise _fail(e) from None


@router.post("/solve", status_code=202)
def solve(svc: Service) -> dict:
    try:
        return svc.request_solve()
    except ServiceError as e:
        raise _fail(e) from None


@router.get("/result")
def result(svc: Service, download: bool = False) -> Response:
    try:
        rep = svc.report()
    except ServiceError as e:
        raise _fail(e) from None
    headers = dict(NO_STORE)
    if download:
        headers["Content-Disposition"] = (f'attachment; filename="calibration-report-'
                                          f'{svc.session_id}.json"')
    return Response(json.dumps(rep, indent=1), media_type="application/json", headers=headers)


@router.get("/uncertainty.png")
def uncertainty(svc: Service) -> Response:
    try:
        data = svc.uncertainty_png()
    except ServiceError as e:
        raise _fail(e) from None
    return Response(data, media_type="image/png", headers=NO_STORE)


@router.get("/camera-file")
def camera_file(svc: Service, format: str = "opencv") -> Response:
    try:
        data, name = svc.camera_file(format)
    except ServiceError as e:
        raise _fail(e) from None
    media = "application/json" if format == "json" else "application/x-yaml"
    return Response(data, media_type=media,
                    headers={**NO_STORE, "Content-Disposition": f'attachment; filename="{name}"'})


@router.post("/use")
def use(svc: Service) -> dict:
    try:
        return svc.use_result()
    except ServiceError as e:
        raise _fail(e) from None


class SessionBody(BaseModel):
    board: str | None = None
    square_m: float | None = None


@router.post("/session")
def new_session(svc: Service, body: Annotated[SessionBody | None, Body()] = None) -> dict:
    body = body or SessionBody()
    try:
        svc.new_session(body.board, body.square_m)
    except ServiceError as e:
        raise _fail(e) from None
    return {"session": svc.session_id, "folder": str(svc.folder),
            "board": svc.session.board.spec()}
