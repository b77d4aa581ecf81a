"""The web tool's FastAPI application factory."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates

from drovisio.resources import static_dir, templates_dir
from webtool.access import TokenAccessMiddleware
from webtool.routes import calibration, designer, health, pages
from webtool.routes import live as live_routes
from webtool.routes import replay as replay_routes
from webtool.settings import Settings


def drovisio_version() -> str:
    try:
        return version("drovisio")
    except PackageNotFoundError:  # pragma: no cover - bare checkout without install
        return "0+unknown"


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings if settings is not None else Settings()
    if settings.camera is None:
        # the calibration chosen on the calibration page ("Use this calibration") lasts
        # across restarts; a --camera given to `drovisio serve` takes precedence
        from webtool.calibration_service import camera_in_use

        settings.camera = camera_in_use(settings)
    app = FastAPI(
        title="Drovisio web tool",
        version=drovisio_version(),
        docs_url="/api/docs",
        redoc_url=None,
        openapi_url="/api/openapi.json",
    )
    app.state.settings = settings
    app.state.templates = Jinja2Templates(directory=str(templates_dir()))
    app.state.templates.env.globals["version"] = app.version

    # One router per area. Calibration, designer and live APIs go here as they arrive, e.g.
    # app.include_router(calibration.router, prefix="/api/calibration").
    app.include_router(pages.router)
    app.include_router(health.router, prefix="/api")
    app.include_router(calibration.router, prefix="/api/calibration")
    app.include_router(designer.router, prefix="/api/designer")
    app.include_router(designer.viewer_router)  # /designer/3d: the 3D view, proxied
    app.include_router(live_routes.router)  # /api/live/..., /live/3d (issue #7)
    app.include_router(replay_routes.router)  # /api/replay/..., /replay/3d (issue #8)
    app.mount("/static", StaticFiles(directory=str(static_dir())), name="static")

    app.add_middleware(TokenAccessMiddleware, token=settings.token)
    return app
