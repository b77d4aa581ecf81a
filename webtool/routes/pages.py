"""The HTML pages: start page and the three parts of the tool."""

from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse
from fastapi.templating import Jinja2Templates

from webtool.routes.deps import get_settings, get_templates
from webtool.settings import Settings

router = APIRouter(tags=["pages"], default_response_class=HTMLResponse)

# path -> (template, page title); the start page's sections link to these.
PAGES = {
    "/": ("index.html", "Drovisio"),
    "/calibration": ("calibration.html", "Camera calibration"),
    "/designer": ("designer.html", "Marker designer"),
    "/live": ("live.html", "Live view"),
}

Templates = Annotated[Jinja2Templates, Depends(get_templates)]
CurrentSettings = Annotated[Settings, Depends(get_settings)]


def _render(request: Request, templates: Jinja2Templates, settings: Settings, path: str):
    name, title = PAGES[path]
    return templates.TemplateResponse(
        request, name, {"title": title, "settings": settings, "active": path}
    )


@router.get("/")
def index(request: Request, templates: Templates, settings: CurrentSettings):
    return _render(request, templates, settings, "/")


@router.get("/calibration")
def calibration(request: Request, templates: Templates, settings: CurrentSettings):
    return _render(request, templates, settings, "/calibration")


@router.get("/designer")
def designer(request: Request, templates: Templates, settings: CurrentSettings):
    return _render(request, templates, settings, "/designer")


@router.get("/live")
def live(request: Request, templates: Templates, settings: CurrentSettings):
    return _render(request, templates, settings, "/live")
