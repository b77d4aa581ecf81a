"""The routers' dependencies, declared once and typed: the settings, the templates, and each
area's service (``Annotated[...]`` types a route names as a parameter's type)."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import Depends, Request
from fastapi.templating import Jinja2Templates
from starlette.requests import HTTPConnection

from webtool.access import refuse_other_sites
from webtool.calibration.service import CalibrationService
from webtool.designer.service import DesignerService
from webtool.fleet.service import FleetService
from webtool.live.service import LiveService
from webtool.mount.service import MountService
from webtool.replay.service import ReplayService
from webtool.services import (
    CALIBRATION,
    DESIGNER,
    FLEET,
    LIVE,
    MOUNT,
    REPLAY,
    STUDY,
    get_service,
    service,
)
from webtool.settings import Settings
from webtool.study.service import StudyService

__all__ = ["CalibrationDep", "CurrentSettings", "DesignerDep", "FleetDep", "LiveDep", "LiveStarted",
           "MountDep", "ReplayDep", "StudyDep", "Templates", "get_settings", "get_templates",
           "started_live"]


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def get_templates(request: Request) -> Jinja2Templates:
    templates: Jinja2Templates = request.app.state.templates
    return templates


async def started_live(conn: HTTPConnection) -> LiveService:
    """The app's live service, its pipeline running (started for the tool's own pages and
    programs only, GET included: :func:`~webtool.access.refuse_other_sites`)."""
    refuse_other_sites(conn)
    svc = get_service(conn.app, LIVE)
    svc.touch()
    await asyncio.to_thread(svc.ensure_started)
    return svc


CurrentSettings = Annotated[Settings, Depends(get_settings)]
Templates = Annotated[Jinja2Templates, Depends(get_templates)]
CalibrationDep = Annotated[CalibrationService, Depends(service(CALIBRATION))]
DesignerDep = Annotated[DesignerService, Depends(service(DESIGNER))]
FleetDep = Annotated[FleetService, Depends(service(FLEET))]
LiveDep = Annotated[LiveService, Depends(service(LIVE))]
"""The live service as it is (the mount page reads its camera's frames when it runs)."""
LiveStarted = Annotated[LiveService, Depends(started_live)]
"""The live service, its pipeline started."""
MountDep = Annotated[MountService, Depends(service(MOUNT))]
ReplayDep = Annotated[ReplayService, Depends(service(REPLAY))]
StudyDep = Annotated[StudyService, Depends(service(STUDY))]
