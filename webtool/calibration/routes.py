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
GET      /board.pdf?paper=P           this session's board to print, true scale (A4, A3,
                                      Letter), with a 100 mm ruler
POST     /square  {"square_m": S}     the square size measured on the print (metres): the
                                      views stay, the result is solved again
POST     /lens  {"model": M}          lens model of the solves: auto, plumb_bob, rational,
                                      fisheye
POST     /use                         make the result this server's camera (settings.camera)
POST     /session  {board, square_m}  start a new session (the old one stays on disk)
=======  ===========================  =========================================================

Errors (one handler, :mod:`webtool.errors`) answer ``{"detail": "..."}`` in plain words, with
404 (nothing there yet), 409 (not possible now), 422 (bad input), 507 (disk full).
"""

from __future__ import annotations

import json
from typing import Annotated, Literal

from fastapi import APIRouter, File, Path, Query, Request, UploadFile
from fastapi.responses import Response

from drovisio.calibration.printout import board_pdf_bytes, print_square_mm
from webtool.calibration.schemas import (
    AutoBody,
    AutoCapture,
    CalibrationReport,
    CalibrationState,
    Captured,
    InUse,
    LensBody,
    LensSet,
    NewSession,
    SessionBody,
    SolveRequested,
    SquareBody,
    SquareSet,
    UploadResult,
    ViewDeleted,
)
from webtool.deps import CalibrationDep
from webtool.responses import NO_STORE, JSONResponse

router = APIRouter(prefix="/api/calibration", tags=["calibration"])

ViewId = Annotated[int, Path(ge=0, le=1_000_000)]


@router.get("/state", response_model=CalibrationState)
def state(svc: CalibrationDep) -> JSONResponse:
    return JSONResponse(svc.state(), headers=NO_STORE)


@router.get("/frame.jpg")
async def frame(svc: CalibrationDep, after: Annotated[int, Query(ge=-1)] = -1) -> Response:
    data, seq = await svc.latest_frame(after, wait=1.0)
    if data is None:
        return JSONResponse({"detail": svc.camera_message or "no picture from the camera yet"},
                            status_code=503, headers={**NO_STORE, "X-Frame-Seq": str(seq)})
    return Response(data, media_type="image/jpeg", headers={**NO_STORE, "X-Frame-Seq": str(seq)})


@router.post("/auto", response_model=AutoCapture)
def auto(svc: CalibrationDep, body: AutoBody) -> JSONResponse:
    svc.set_auto(body.on)
    return JSONResponse({"auto_capture": svc.auto_capture})


@router.post("/capture", response_model=Captured)
def capture(svc: CalibrationDep) -> JSONResponse:
    return JSONResponse(svc.capture())


@router.get("/views/{view_id}/thumb.jpg")
def thumb(svc: CalibrationDep, view_id: ViewId) -> Response:
    return Response(svc.thumbnail(view_id), media_type="image/jpeg",
                    headers={"Cache-Control": "max-age=3600"})


@router.delete("/views/{view_id}", response_model=ViewDeleted)
def delete_view(svc: CalibrationDep, view_id: ViewId) -> JSONResponse:
    svc.delete_view(view_id)
    return JSONResponse({"deleted": view_id, "views": len(svc.session.views)})


@router.post("/upload", response_model=UploadResult)
def upload(svc: CalibrationDep, files: Annotated[list[UploadFile], File()]) -> JSONResponse:
    return JSONResponse(svc.upload([(f.filename or "", f.file) for f in files]))


@router.post("/square", response_model=SquareSet)
def square(svc: CalibrationDep, body: SquareBody) -> JSONResponse:
    return JSONResponse(svc.set_square(body.square_m))


@router.post("/lens", response_model=LensSet)
def lens(svc: CalibrationDep, body: LensBody) -> JSONResponse:
    return JSONResponse(svc.set_lens_model(body.model))


@router.post("/solve", status_code=202, response_model=SolveRequested)
def solve(svc: CalibrationDep) -> JSONResponse:
    return JSONResponse(svc.request_solve(), status_code=202)


@router.get("/result", response_model=CalibrationReport)
def result(svc: CalibrationDep, download: bool = False) -> Response:
    headers = dict(NO_STORE)
    if download:
        headers["Content-Disposition"] = (f'attachment; filename="calibration-report-'
                                          f'{svc.session_id}.json"')
    return Response(json.dumps(svc.report(), indent=1), media_type="application/json",
                    headers=headers)


@router.get("/uncertainty.png")
def uncertainty(svc: CalibrationDep) -> Response:
    return Response(svc.uncertainty_png(), media_type="image/png", headers=NO_STORE)


@router.get("/camera-file")
def camera_file(svc: CalibrationDep,
                format: Literal["opencv", "ros", "json"] = "opencv") -> Response:  # noqa: A002
    data, name = svc.camera_file(format)
    media = "application/json" if format == "json" else "application/x-yaml"
    return Response(data, media_type=media,
                    headers={**NO_STORE, "Content-Disposition": f'attachment; filename="{name}"'})


@router.get("/board.pdf")
def board_pdf(svc: CalibrationDep, paper: Literal["A4", "A3", "Letter"] = "A4") -> Response:
    board = svc.session.board
    square = print_square_mm(board, paper)
    data, _ = board_pdf_bytes(board, paper, square)
    name = f"{board.kind}-{board.cols}x{board.rows}-{paper}.pdf"
    return Response(data, media_type="application/pdf",
                    headers={**NO_STORE, "Content-Disposition": f'attachment; filename="{name}"',
                             "X-Square-mm": f"{square:g}"})


@router.post("/use", response_model=InUse)
def use(svc: CalibrationDep, request: Request) -> JSONResponse:
    out = svc.use_result()
    # the live view uses the chosen calibration at once (if it was made already)
    live = getattr(request.app.state, "live", None)
    if live is not None and hasattr(live, "reconfigure"):
        live.reconfigure()
    return JSONResponse(out)


@router.post("/session", response_model=NewSession)
def new_session(svc: CalibrationDep, body: SessionBody | None = None) -> JSONResponse:
    body = body or SessionBody()
    svc.new_session(body.board, body.square_m)
    return JSONResponse({"session": svc.session_id, "folder": str(svc.folder),
                         "board": svc.session.board.spec()})
