"""The Study page: the evaluation reports of the data folder, and a study started on the
shipped protocol.

=======  ================================  ====================================================
GET      /api/study/reports                the reports (name, protocol, frames, seconds)
POST     /api/study/start                  run the shipped recorded-style protocol (409 while
                                           one runs)
GET      /api/study/progress               running, fraction, message, error, report,
                                           cancelled
GET      /study/reports/{name}/{file}      report.html or one of its figures
=======  ================================  ====================================================
"""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import FileResponse

from webtool.deps import StudyDep
from webtool.responses import NO_STORE, JSONResponse
from webtool.study.schemas import StudyProgress, StudyReports

router = APIRouter(prefix="/api/study", tags=["study"])
viewer_router = APIRouter(prefix="/study/reports", tags=["study"])



@router.get("/reports", response_model=StudyReports)
def reports(svc: StudyDep) -> JSONResponse:
    return JSONResponse({"folder": str(svc.folder), **svc.listing()}, headers=NO_STORE)


@router.post("/start", status_code=202, response_model=StudyProgress)
def start(svc: StudyDep) -> JSONResponse:
    return JSONResponse(svc.start(), status_code=202, headers=NO_STORE)


@router.get("/progress", response_model=StudyProgress)
def progress(svc: StudyDep) -> JSONResponse:
    return JSONResponse(svc.progress, headers=NO_STORE)


@viewer_router.get("/{name}/{file}")
def report_file(svc: StudyDep, name: str, file: str) -> FileResponse:
    return FileResponse(svc.report_file(name, file), headers=NO_STORE)
