"""The web tool's services: one per area, made on first use, closed when the app stops.

=============  ======================================================================
calibration    :class:`webtool.calibration.service.CalibrationService`
designer       :class:`webtool.designer.service.DesignerService`
live           :class:`webtool.live.service.LiveService`
mount          :class:`webtool.mount.service.MountService`
study          :class:`webtool.study.service.StudyService`
replay         :class:`webtool.replay.service.ReplayService`
=============  ======================================================================

Routers ask for them with :func:`service` (``Annotated[..., Depends(service("live"))]``); a
service with a ``touch()`` method is told on every request that someone is watching (the
camera of the calibration page stops when nobody is). Tests may put their own object in
``app.state.<name>`` before the first request.
"""

from __future__ import annotations

import asyncio
import importlib
import logging
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from starlette.requests import HTTPConnection

__all__ = ["SERVICES", "close_services", "lifespan", "service"]

#: name → "module:factory" (the factory takes the app's Settings)
SERVICES: dict[str, str] = {
    "calibration": "webtool.calibration.service:CalibrationService",
    "designer": "webtool.designer.service:DesignerService",
    "live": "webtool.live.service:LiveService",
    "mount": "webtool.mount.service:MountService",
    "study": "webtool.study.service:StudyService",
    "replay": "webtool.replay.service:ReplayService",
}
_lock = threading.Lock()
log = logging.getLogger("webtool")


def get_service(app: FastAPI, name: str) -> Any:
    """The app's ``name`` service, made on first use."""
    svc = getattr(app.state, name, None)
    if svc is None:
        with _lock:
            svc = getattr(app.state, name, None)
            if svc is None:
                module, _, factory = SERVICES[name].partition(":")
                make = getattr(importlib.import_module(module), factory)
                svc = make(app.state.settings)
                setattr(app.state, name, svc)
    return svc


def service(name: str) -> Callable[[HTTPConnection], Any]:
    """A FastAPI dependency giving the ``name`` service (and touching it)."""
    def dependency(conn: HTTPConnection) -> Any:
        svc = get_service(conn.app, name)
        touch = getattr(svc, "touch", None)
        if touch is not None:
            touch()
        return svc
    dependency.__name__ = f"{name}_service"
    return dependency


def close_services(app: FastAPI) -> None:
    for name in SERVICES:
        svc = getattr(app.state, name, None)
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
            svc = get_service(app, "live")
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
    yield
    await asyncio.to_thread(close_services, app)
