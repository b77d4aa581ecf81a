"""The web tool's FastAPI application factory.

``create_app(settings)`` assembles: the access middleware (Host, Origin, tokens:
:mod:`webtool.access`), a body-size limit, a cap on open WebSockets, the one error handler
(:mod:`webtool.errors`), the services made on first use and closed in the lifespan
(:mod:`webtool.services`), one router per area (listed in :mod:`webtool.routes`), the Jinja2
pages and the static files (found with :mod:`importlib.resources`, so a wheel works like a
checkout).

The tool is built by area, one package each: ``calibration``, ``designer``, ``live``, ``mount``,
``replay``, ``study`` (each with ``routes`` — thin handlers —, ``schemas`` — request bodies and
response models —, ``service`` and, with a 3D view, ``scene``) and ``pages`` (the HTML pages and
the health check); ``viewer`` holds the base of the 3D views and the one proxy that serves them;
``deps`` the routers' typed dependencies.
"""

from __future__ import annotations

import json
from importlib.metadata import PackageNotFoundError, version

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drovisio.errors import LIMITS
from drovisio.resources import static_dir, templates_dir
from webtool.access import AccessMiddleware
from webtool.calibration import camera_in_use
from webtool.errors import install_error_handlers
from webtool.mount import mount_in_use
from webtool.responses import JSONResponse
from webtool.routes import (
    calibration,
    designer,
    fleet,
    health,
    live,
    mount,
    pages,
    replay,
    study,
)
from webtool.services import lifespan
from webtool.settings import Settings

#: routes whose body is a file, and the most bytes one request may send them: the mesh upload
#: checks its own limit while streaming (a setting); the picture uploads take files of up to
#: 64 MB each, but no request more than this in all. Every route that takes an UploadFile
#: must be here (a test walks the routes); the paths match exactly.
UPLOAD_REQUEST_BYTES = 512 * 2**20
_UPLOADS: dict[str, int | None] = {"/api/designer/mesh": None,
                                   "/api/calibration/upload": UPLOAD_REQUEST_BYTES,
                                   "/api/mount/measure": UPLOAD_REQUEST_BYTES}


def drovisio_version() -> str:
    try:
        return version("drovisio")
    except PackageNotFoundError:  # pragma: no cover - bare checkout without install
        return "0+unknown"


class BodyLimitMiddleware:
    """Refuse a request body larger than its route's limit (413): a JSON body
    :attr:`drovisio.errors.Limits.max_body_bytes`, an upload :data:`_UPLOADS`. A declared
    length over the limit is refused before anything is read; a body without one (chunked)
    is counted as it streams, cut at the limit, and whatever the route answered to the cut
    body is replaced by the 413."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        limit = _UPLOADS.get(path, self.limit) if scope["type"] == "http" else None
        if limit is None:
            await self.app(scope, receive, send)
            return
        length = dict(scope.get("headers", [])).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            await _answer_413(send, limit)
            return
        received, over, answered = 0, False, False

        async def counting() -> Message:
            nonlocal received, over
            if over:
                return {"type": "http.request", "body": b"", "more_body": False}
            message = await receive()
            received += len(message.get("body", b""))
            if received > limit:
                over = True
                return {"type": "http.request", "body": b"", "more_body": False}
            return message

        async def sending(message: Message) -> None:
            nonlocal answered
            if not over:
                await send(message)
            elif message["type"] == "http.response.start" and not answered:
                answered = True
                await _answer_413(send, limit)

        await self.app(scope, counting, sending)


async def _answer_413(send: Send, limit: int) -> None:
    size = f"{limit // 2**20} MiB" if limit >= 2**20 else f"{limit // 1024} KiB"
    body = b'{"detail": "request body too large (over %s)"}' % size.encode()
    await send({"type": "http.response.start", "status": 413,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})


class SocketLimitMiddleware:
    """At most ``limit`` WebSockets open at once, every socket of the tool counted (the live
    image streams and the relayed 3D views): one more is answered 503 with the reason before
    it opens, so a page's reconnects back off instead of piling up."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit
        self.open = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "websocket":
            await self.app(scope, receive, send)
            return
        if self.open >= self.limit:
            await _refuse_socket(scope, receive, send, self.limit)
            return
        self.open += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.open -= 1


async def _refuse_socket(scope: Scope, receive: Receive, send: Send, limit: int) -> None:
    why = (f"too many live views open (at most {limit} streams and 3D views at once); "
           "close one and reload")
    if (await receive())["type"] != "websocket.connect":
        return
    if "websocket.http.response" in scope.get("extensions", {}):
        body = json.dumps({"detail": why}).encode()
        await send({"type": "websocket.http.response.start", "status": 503,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode()),
                                (b"retry-after", b"5")]})
        await send({"type": "websocket.http.response.body", "body": body})
        return
    await send({"type": "websocket.close", "code": 1013, "reason": why[:120]})


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings if settings is not None else Settings()
    if settings.camera is None:
        # the calibration chosen on the calibration page ("Use this calibration") lasts
        # across restarts; a --camera given to `drovisio serve` takes precedence
        settings.camera = camera_in_use(settings)
    if settings.mount is None:
        # likewise the mount saved on the mount page (on the sample session too: what the
        # user saved is what the live view uses)
        settings.mount = mount_in_use(settings)
    app = FastAPI(
        title="Drovisio web tool",
        version=drovisio_version(),
        docs_url="/api/docs",
        redoc_url=None,
        openapi_url="/api/openapi.json",
        lifespan=lifespan,
        default_response_class=JSONResponse,  # JSON-safe: no route can answer NaN
    )
    app.state.settings = settings
    app.state.templates = Jinja2Templates(directory=str(templates_dir()))
    app.state.templates.env.globals["version"] = app.version
    install_error_handlers(app)

    app.include_router(pages.router)
    app.include_router(health.router)
    for area in (calibration, designer, live, mount, replay, study, fleet):
        app.include_router(area.router)
        if hasattr(area, "viewer_router"):
            app.include_router(area.viewer_router)
    app.mount("/static", StaticFiles(directory=str(static_dir())), name="static")

    app.add_middleware(BodyLimitMiddleware, limit=LIMITS.max_body_bytes)
    # inside the access check: a socket it refuses holds no slot
    app.add_middleware(SocketLimitMiddleware, limit=settings.max_sockets)
    app.add_middleware(AccessMiddleware, token=settings.token,
                       viewer_token=settings.viewer_token, bind_host=settings.host)
    return app
