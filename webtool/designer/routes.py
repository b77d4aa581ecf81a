"""JSON API of the marker designer page, under ``/api/designer`` (the page and the tests share it).

=======  ==============================  ======================================================
GET      /state[?after=V]                everything the page shows; with ``after``, waits up to
                                         4 s for a version other than V (long poll; holds no
                                         worker thread)
GET      /viewer                         start the 3D viewer and give its URL,
                                         ``/designer/3d/`` (served through this app)
POST     /mesh?filename=F&units=U        upload a mesh: the request body is the file (STL, OBJ,
                                         PLY, GLB/GLTF, OFF); refused by size before reading
POST     /open   {example}               ``mesh:drick.stl`` or ``layout:NAME.json``
POST     /units  {units}                 mm, cm or m
POST     /frame  {action, angle_deg?}    origin_top_centre, align_x, turn, flip, reset
POST     /mode   {mode}                  what a click does: code, dot, select, origin
POST     /click  {origin, direction}     a click ray from the 3D view (world = brick frame);
                                         the viser click handler calls the same code
POST     /select {index}                 select a marker (null: none)
POST     /markers/{i}  {...}             size_mm, color, slot, rotate_deg, nudge_mm [r, u],
                                         centre
DELETE   /markers/{i}                    delete a marker
POST     /defaults {...}                 code_size_mm, dot_diameter_mm, dot_color, grid_mm,
                                         snap_mm (for the next markers)
POST     /layout {...}                   name, description, first_id (null = automatic),
                                         ids_per_instance, instances, symmetry, family
POST     /fix    {action}                perform a fix offered by a check
POST     /undo, /redo
POST     /save   {overwrite}             write NAME.json and meshes/NAME.stl into the layouts
                                         folder (never silently over an existing file)
GET      /export/layout.json             the layout file (validated)
GET      /export/mesh.stl                the mesh in the brick frame, metres
GET      /export/brick.glb               the mesh with the markers on it
GET      /export/sheet.pdf               the print sheet, true scale (all pages)
GET      /export/sheet.svg?page=N        one page of the print sheet, true scale
POST     /verify                         try the layout on a simulated photo (drovisio.synth):
                                         the detectors' errors and the photo (JPEG data URL)
=======  ==============================  ======================================================

Outside ``/api/designer`` (``viewer_router``): ``GET /designer/3d/`` is viser's client and
``WebSocket /designer/3d`` its socket, relayed to the viewer; the socket needs full access
(the 3D view edits the design), a view-only link gets it closed.

Bodies are pydantic models: finite numbers within stated bounds, no unknown fields. Mutating
calls answer the new state. Errors (one handler, :mod:`webtool.errors`) answer
``{"detail": "..."}``: 409 nothing loaded yet, 413 upload too big, 422 bad input or an
impossible edit, 503 the 3D view could not start.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from starlette.requests import HTTPConnection

from drovisio.designer.export import (
    build_layout,
    export_glb,
    mesh_stl_bytes,
    print_sheet_pdf,
    print_sheet_svg,
)
from drovisio.designer.model import DesignDocument, DesignError
from webtool.deps import DesignerDep
from webtool.designer.edits import (
    UNIT_NAMES,
    defaults_edit,
    frame_edit,
    frame_message,
    layout_edit,
    marker_edit,
    require_valid,
    verification,
)
from webtool.designer.scene import DesignerScene
from webtool.designer.schemas import (
    ClickBody,
    DefaultsBody,
    DesignerState,
    FixBody,
    FrameBody,
    LayoutBody,
    MarkerBody,
    ModeBody,
    OpenBody,
    SaveBody,
    SelectBody,
    UnitsBody,
    Verification,
)
from webtool.designer.service import MODE_LABELS, DesignerService
from webtool.errors import Conflict, ServiceError, TooBig, Unavailable
from webtool.responses import NO_STORE, JSONResponse
from webtool.schemas import SceneLink
from webtool.services import DESIGNER, get_service
from webtool.viewer.proxy import viewer_router as viewer_router_for

router = APIRouter(prefix="/api/designer", tags=["designer"])

LONG_POLL_S = 4.0


async def _viewer(conn: HTTPConnection) -> DesignerScene | None:
    """The designer's 3D view, started (None when it cannot start)."""
    designer = get_service(conn.app, DESIGNER)
    try:
        return await run_in_threadpool(designer.viewer)
    except (DesignError, OSError):
        return None


# the 3D view edits the design: its socket needs full access; it starts with the socket
viewer_router = viewer_router_for("/designer/3d", "designer", _viewer, full_access_only=True,
                                  start_for_client=False)


# ------------------------------------------------------------------------------ helpers


def _state(designer: DesignerService, extra: dict | None = None) -> JSONResponse:
    data = designer.state()
    if extra:
        data.update(extra)
    return JSONResponse(data, headers=NO_STORE)


def _need_mesh(designer: DesignerService) -> None:
    if not designer.doc.has_mesh:
        raise Conflict("No 3D model loaded yet: upload one or open an example first.")


def _do(designer: DesignerService, fn, message: str | None = None,
        need_mesh: bool = True) -> JSONResponse:
    if need_mesh:
        _need_mesh(designer)
    designer.edit(fn, message)
    return _state(designer)


# ------------------------------------------------------------------------------ state


@router.get("/state", response_model=DesignerState)
async def state(designer: DesignerDep,
                after: Annotated[int | None, Query(ge=0)] = None) -> JSONResponse:
    if after is not None:
        await designer.wait_for_change_async(after, LONG_POLL_S)
    return _state(designer)


@router.get("/viewer", response_model=SceneLink)
def viewer(designer: DesignerDep) -> JSONResponse:
    try:
        v = designer.viewer()
    except (DesignError, OSError) as e:
        raise Unavailable(f"The 3D view could not start ({e}). Reload the page.") \
            from None
    return JSONResponse({"url": "/designer/3d/", "port": v.port}, headers=NO_STORE)


# ------------------------------------------------------------------------------ 3D proxy


# ------------------------------------------------------------------------------ mesh


def _too_big(size: int, limit: int, claimed: bool) -> ServiceError:
    mb = size / (1024 * 1024)
    what = f"is {mb:.0f} MB" if claimed else f"is more than {limit / (1024 * 1024):.0f} MB"
    return TooBig(f"This file {what}; the limit is {limit / (1024 * 1024):.0f} MB. "
                        "Simplify the model in your CAD program (fewer triangles, e.g. "
                        "'decimate' or a coarser STL export) and upload it again.")


@router.post("/mesh", response_model=DesignerState)
async def upload_mesh(request: Request, designer: DesignerDep,
                      filename: Annotated[str, Query(min_length=1, max_length=255)],
                      units: Literal["auto", "mm", "cm", "m"] = "auto") -> JSONResponse:
    """Upload a mesh as the raw request body. The size is checked from Content-Length before
    anything is read, and again while streaming (for uploads without a length)."""
    limit = designer.max_upload_bytes
    claimed = request.headers.get("content-length")
    if claimed is not None:
        try:
            n = int(claimed)
        except ValueError:
            raise ServiceError("Bad Content-Length header.", 400) from None
        if n > limit:
            raise _too_big(n, limit, True)
    buf = bytearray()
    async for chunk in request.stream():
        buf += chunk
        if len(buf) > limit:
            raise _too_big(len(buf), limit, False)
    await run_in_threadpool(designer.load_mesh, bytes(buf), filename, units)
    return _state(designer)


@router.post("/open", response_model=DesignerState)
def open_example(designer: DesignerDep, body: OpenBody) -> JSONResponse:
    designer.open_example(body.example)
    return _state(designer)


@router.post("/units", response_model=DesignerState)
def set_units(designer: DesignerDep, body: UnitsBody) -> JSONResponse:
    return _do(designer, lambda d: d.set_units(body.units),
               f"The model's numbers are now read as {UNIT_NAMES[body.units]}.")


@router.post("/frame", response_model=DesignerState)
def set_frame(designer: DesignerDep, body: FrameBody) -> JSONResponse:
    return _do(designer, frame_edit(body), frame_message(body))


@router.post("/mode", response_model=DesignerState)
def set_mode(designer: DesignerDep, body: ModeBody) -> JSONResponse:
    return _do(designer, lambda d: d.set_mode(body.mode),
               f"A click on the model now does: {MODE_LABELS[body.mode]}.", need_mesh=False)


@router.post("/click", response_model=DesignerState)
def click(designer: DesignerDep, body: ClickBody) -> JSONResponse:
    res = designer.click(list(body.origin), list(body.direction))
    return _state(designer, {"click": {"action": res.action, "message": res.message,
                                       "marker": res.marker}})


@router.post("/select", response_model=DesignerState)
def select(designer: DesignerDep, body: SelectBody) -> JSONResponse:
    return _do(designer, lambda d: d.select(body.index))


@router.post("/markers/{index}", response_model=DesignerState)
def edit_marker(designer: DesignerDep, index: Annotated[int, PathParam(ge=0, le=1_000_000)],
                body: MarkerBody) -> JSONResponse:
    return _do(designer, marker_edit(index, body))


@router.delete("/markers/{index}", response_model=DesignerState)
def delete_marker(designer: DesignerDep, index: Annotated[int, PathParam(ge=0, le=1_000_000)]
                  ) -> JSONResponse:
    return _do(designer, lambda d: d.delete_marker(index), "Marker deleted.")


@router.post("/defaults", response_model=DesignerState)
def set_defaults(designer: DesignerDep, body: DefaultsBody) -> JSONResponse:
    return _do(designer, defaults_edit(body), need_mesh=False)


@router.post("/layout", response_model=DesignerState)
def set_layout(designer: DesignerDep, body: LayoutBody) -> JSONResponse:
    return _do(designer, layout_edit(body))


@router.post("/fix", response_model=DesignerState)
def fix(designer: DesignerDep, body: FixBody) -> JSONResponse:
    _need_mesh(designer)
    designer.apply_fix(body.action.model_dump(exclude_unset=True))
    return _state(designer)


@router.post("/undo", response_model=DesignerState)
def undo(designer: DesignerDep) -> JSONResponse:
    return _do(designer, lambda d: d.undo() or None, "Undone.", need_mesh=False)


@router.post("/redo", response_model=DesignerState)
def redo(designer: DesignerDep) -> JSONResponse:
    return _do(designer, lambda d: d.redo() or None, "Redone.", need_mesh=False)


@router.post("/save", response_model=DesignerState)
def save(designer: DesignerDep, body: SaveBody | None = None) -> JSONResponse:
    _need_mesh(designer)
    saved = designer.save(overwrite=bool(body and body.overwrite))
    return _state(designer, {"saved": {"layout": str(saved.layout_path),
                                       "mesh": str(saved.mesh_path)}})


# ------------------------------------------------------------------------------ export


def _export(designer: DesignerService, fn):
    _need_mesh(designer)
    with designer.lock:
        doc = designer.doc.copy()
    return fn(doc)


def _download(data: bytes | str, media: str, filename: str) -> Response:
    return Response(data, media_type=media, headers={
        **NO_STORE, "Content-Disposition": f'attachment; filename="{filename}"'})


@router.get("/export/layout.json")
def export_layout(designer: DesignerDep) -> Response:
    def run(doc: DesignDocument) -> str:
        require_valid(doc, designer.camera)
        return build_layout(doc).to_json()

    return _download(_export(designer, run), "application/json", f"{designer.doc.name}.json")


@router.get("/export/mesh.stl")
def export_mesh(designer: DesignerDep) -> Response:
    return _download(_export(designer, mesh_stl_bytes), "model/stl", f"{designer.doc.name}.stl")


@router.get("/export/brick.glb")
def export_brick_glb(designer: DesignerDep) -> Response:
    return _download(_export(designer, export_glb), "model/gltf-binary", f"{designer.doc.name}.glb")


@router.get("/export/sheet.pdf")
def export_pdf(designer: DesignerDep) -> Response:
    return _download(_export(designer, print_sheet_pdf), "application/pdf",
                     f"{designer.doc.name}-print-sheet.pdf")


@router.get("/export/sheet.svg")
def export_svg(designer: DesignerDep, page: Annotated[int, Query(ge=1, le=1000)] = 1) -> Response:
    return _download(_export(designer, lambda d: print_sheet_svg(d, page)), "image/svg+xml",
                     f"{designer.doc.name}-print-sheet-{page}.svg")


@router.post("/verify", response_model=Verification)
def verify(designer: DesignerDep) -> JSONResponse:
    """Render one brick of the current design and detect it (see
    :func:`drovisio.designer.verify.verify_layout`)."""
    return JSONResponse(_export(designer, lambda doc: verification(doc, designer.camera)),
                        headers=NO_STORE)
