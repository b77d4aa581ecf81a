"""The web tool's services: one per area, made on first use, closed when the app stops.

=============  ======================================================================
calibration    :class:`webtool.calibration.service.CalibrationService`
designer       :class:`webtool.designer.service.DesignerService`
live           :class:`webtool.live.service.LiveService`
mount          :class:`webtool.mount.service.MountService`
study          :class:`webtool.study.service.StudyService`
replay         :class:`webtool.replay.service.ReplayService`
fleet          :class:`webtool.fleet.service.FleetService` (``drovisio station``)
=============  ======================================================================

Each is an :class:`Area`: its name (the ``app.state`` attribute that holds it) and its
factory (takes the app's Settings). Routers ask for them through the typed dependencies of
:mod:`webtool.deps`; a service with a ``touch()`` method is told on every request that someone
is watching (the camera of the calibration page stops when nobody is). Tests may put their own
object in ``app.state.<name>`` before the first request.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar, overload

from fastapi import FastAPI
from starlette.requests import HTTPConnection

from webtool.access import refuse_other_sites
from webtool.calibration.service import CalibrationService
from webtool.designer.service import DesignerService
from webtool.fleet.service import FleetService
from webtool.live.service import LiveService
from webtool.mount.service import MountService
from webtool.replay.service import ReplayService
from webtool.settings import Settings
from webtool.study.service import StudyService

__all__ = ["AREAS", "CALIBRATION", "DESIGNER", "FLEET", "LIVE", "MOUNT", "REPLAY", "SERVICES", "STUDY",
           "Area", "close_services", "get_service", "lifespan", "service"]


class Service(Protocol):
    """What the app needs of every service: to close it when the app stops."""

    def close(self) -> None: ...


S = TypeVar("S", bound=Service)


@dataclass(frozen=True)
class Area(Generic[S]):
    """One area's service: where the app keeps it and how it is made."""

    name: str
    """The ``app.state`` attribute that holds it."""
    make: Callable[[Settings], S]
    """Makes it from the app's settings."""


CALIBRATION: Area[CalibrationService] = Area("calibration", CalibrationService)
DESIGNER: Area[DesignerService] = Area("designer", DesignerService)
LIVE: Area[LiveService] = Area("live", LiveService)
MOUNT: Area[MountService] = Area("mount", MountService)
STUDY: Area[StudyService] = Area("study", StudyService)
REPLAY: Area[ReplayService] = Area("replay", ReplayService)
FLEET: Area[FleetService] = Area("fleet", FleetService)

#: every area, in the order they are closed
AREAS: tuple[Area[Any], ...] = (CALIBRATION, DESIGNER, LIVE, MOUNT, STUDY, REPLAY, FLEET)
#: name → area
SERVICES: dict[str, Area[Any]] = {a.name: a for a in AREAS}

_lock = threading.Lock()
log = logging.getLogger("webtool")


@overload
def get_service(app: FastAPI, area: Area[S]) -> S: ...


@overload
def get_service(app: FastAPI, area: str) -> Any: ...


def get_service(app: FastAPI, area: Area[Any] | str) -> Any:
    """The app's service of ``area`` (an :class:`Area`, or its name), made on first use."""
    a = SERVICES[area] if isinstance(area, str) else area
    svc = getattr(app.state, a.name, None)
    if svc is None:
        with _lock:
            svc = getattr(app.state, a.name, None)
            if svc is None:
                svc = a.make(app.state.settings)
                setattr(app.state, a.name, svc)
    return svc


def service(area: Area[S]) -> Callable[[HTTPConnection], S]:
    """A FastAPI dependency giving the ``area``'s service (and touching it: a touch starts
    work, e.g. the calibration camera, so it is refused to another site's page, GET
    included: :func:`~webtool.access.refuse_other_sites`)."""
    def dependency(conn: HTTPConnection) -> S:
        svc = get_service(conn.app, area)
        touch = getattr(svc, "touch", None)
        if touch is not None:
            refuse_other_sites(conn)
            touch()
        return svc
    dependency.__name__ = f"{area.name}_service"
    return dependency


def close_services(app: FastAPI) -> None:
    for area in AREAS:
        svc = getattr(app.state, area.name, None)
        if svc is not None:
            svc.close()


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """The app's lifespan: services start on first use, except the live pipeline when it
    feeds sinks (the flight controller: it runs from the start, watched or not); every service
    made is closed at shutdown."""
    app.state.startup_error = None
    if app.state.settings.flying:
        try:
            svc = get_service(app, LIVE)
            await asyncio.to_thread(svc.ensure_started)
            error = svc.error
        except Exception as e:  # noqa: BLE001 - never raised to uvicorn (a 29-frame traceback)
            error = f"{type(e).__name__}: {e}"
        if error:
            # `drovisio serve` checked the options before; what fails here (a link lost in
            # between) is said in one line and ends the server (exit 2), never a traceback
            app.state.startup_error = f"the pipeline could not start: {error}"
            log.error("%s", app.state.startup_error)
            server = getattr(app.state, "uvicorn_server", None)
            if server is not None:
                server.should_exit = True
    if app.state.settings.is_station:
        # a station hears its drones from the start, watched or not
        await asyncio.to_thread(get_service, app, FLEET)
    yield
    await asyncio.to_thread(close_services, app)
