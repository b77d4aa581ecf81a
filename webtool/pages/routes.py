"""The HTML pages: the start page, the parts of the tool, and the field guide (Help)."""

import re

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.templating import Jinja2Templates
from markdown_it import MarkdownIt

from drovisio.resources import docs_dir, static_dir
from webtool.deps import CurrentSettings, Templates
from webtool.settings import Settings

router = APIRouter(tags=["pages"], default_response_class=HTMLResponse)

# path -> (template, page title); the start page's sections link to these.
PAGES = {
    "/": ("index.html", "Drovisio"),
    "/calibration": ("calibration.html", "Camera calibration"),
    "/designer": ("designer.html", "Marker designer"),
    "/live": ("live.html", "Live view"),
    "/mount": ("mount.html", "Camera mount"),
    "/study": ("study.html", "Study"),
    "/fleet": ("fleet.html", "Fleet"),
    "/help": ("help.html", "Field guide"),
}



def _render(request: Request, templates: Jinja2Templates, settings: Settings, path: str):
    name, title = PAGES[path]
    return templates.TemplateResponse(
        request, name, {"title": title, "settings": settings, "active": path}
    )


def _page(path: str):
    def page(request: Request, templates: Templates, settings: CurrentSettings):
        return _render(request, templates, settings, path)
    page.__name__ = "page_" + (path.strip("/") or "index")
    return page


# every page but the guide is its template (the guide renders docs/field-guide.md)
for _path in PAGES:
    if _path != "/help":
        router.add_api_route(_path, _page(_path), methods=["GET"])


_IMAGE_NAME = re.compile(r"^[a-z0-9][a-z0-9-]{0,80}\.(jpg|png)$")
_guide_cache: dict[str, tuple[float, str]] = {}


def field_guide_html() -> str:
    """``docs/field-guide.md`` as HTML (CommonMark, raw HTML off), its pictures under
    ``/help/images/``; cached until the file changes."""
    f = docs_dir() / "field-guide.md"
    mtime = f.stat().st_mtime
    hit = _guide_cache.get("guide")
    if hit is None or hit[0] != mtime:
        html = MarkdownIt("commonmark", {"html": False}).render(f.read_text(encoding="utf-8"))
        html = html.replace('src="images/', 'src="/help/images/')
        _guide_cache["guide"] = (mtime, html)
    return _guide_cache["guide"][1]


@router.get("/help")
def help_page(request: Request, templates: Templates, settings: CurrentSettings):
    name, title = PAGES["/help"]
    return templates.TemplateResponse(request, name, {
        "title": title, "settings": settings, "active": "/help", "guide": field_guide_html()})


@router.get("/favicon.ico", include_in_schema=False)
def favicon() -> FileResponse:
    """Browsers ask for it on every page: the tool's icon, not a 404."""
    return FileResponse(static_dir() / "favicon.svg", media_type="image/svg+xml",
                        headers={"Cache-Control": "max-age=86400"})


@router.get("/help/images/{name}")
def help_image(name: str) -> FileResponse:
    f = docs_dir() / "images" / name
    if not _IMAGE_NAME.match(name) or not f.is_file():
        raise HTTPException(404, "no such picture in the field guide")
    return FileResponse(f, headers={"Cache-Control": "no-cache"})
