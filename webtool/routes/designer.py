"""JSON API of the marker designer page, under ``/api/designer`` (the page and the tests share it).

=======  ==============================  ======================================================
GET      /state[?after=V]                everything the page shows; with ``after``, waits up to
                                         4 s for a version other than V (long poll)
GET      /viewer                         start the 3D viewer (viser, own port on 127.0.0.1) and
                                         give its URL: ``/designer/3d/``, served through this
                                         app (so the access token covers it)
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

Mutating calls answer the new state. Errors answer ``{"detail": "..."}`` in plain words: 409
(nothing loaded yet), 413 (upload too big), 422 (bad input or a design problem).
"""

from __future__ import annotations

import threading
from contextlib import asynccontextmanager
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, HTTPException, Query, Request, WebSocket
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response
from starlette.requests import HTTPConnection

from drovisio.designer.model import DesignError
from webtool.designer_scene import DesignerSession, viewer_url

_create_lock = threading.Lock()
NO_STORE = {"Cache-Control": "no-store"}
LONG_POLL_S = 4.0


@asynccontextmanager
async def _lifespan(app):
    yield
    close_session(app)


router = APIRouter(tags=["designer"], lifespan=_lifespan)


def get_session(request: HTTPConnection) -> DesignerSession:
    """The app's designer session (made on first use)."""
    app = request.app
    s = getattr(app.state, "designer", None)
    if s is None:
        with _create_lock:
            s = getattr(app.state, "designer", None)
            if s is None:
                s = DesignerSession.from_settings(app.state.settings)
                app.state.designer = s
    return s


def close_session(app) -> None:
    """Stop the designer's viewer (app shutdown)."""
    s = getattr(app.state, "designer", None)
    if s is not None:
        s.close()


Session = Annotated[DesignerSession, Depends(get_session)]


def _fail(e: Exception, status: int = 422) -> HTTPException:
    return HTTPException(status_code=status, detail=str(e))


def _state(session: DesignerSession, extra: dict | None = None) -> JSONResponse:
    data = session.state()
    if extra:
        data.update(extra)
    return JSONResponse(data, headers=NO_STORE)


def _need_mesh(session: DesignerSession) -> None:
    if not session.doc.has_mesh:
        raise HTTPException(409, "No 3D model loaded yet: upload one or open an example first.")


def _do(session: DesignerSession, fn, message: str | None = None, need_mesh: bool = True):
    if need_mesh:
        _need_mesh(session)
    try:
        session.edit(fn, message)
    except DesignError as e:
        raise _fail(e) from None
    return _state(session)


# ------------------------------------------------------------------------------ state


@router.get("/state")
def state(session: Session, after: int | None = None) -> JSONResponse:
    if after is not None:
        session.wait_for_change(after, LONG_POLL_S)
    return _state(session)


@router.get("/viewer")
def viewer(request: Request, session: Session) -> JSONResponse:
    try:
        v = session.viewer()
    except DesignError as e:
        raise _fail(e, 503) from None
    except OSError as e:
        raise HTTPException(503, f"The 3D view could not start ({e}). Reload the page.") from None
    from webtool.settings import is_loopback

    # a browser on this machine may also open viser's own port (debugging); others may not
    direct = viewer_url(request.url.hostname, v.port, request.url.scheme) \
        if request.client and is_loopback(request.client.host) else None
    return JSONResponse({"url": "/designer/3d/", "direct_url": direct, "port": v.port},
                        headers=NO_STORE)


# ------------------------------------------------------------------------------ 3D proxy

viewer_router = APIRouter(tags=["designer"])


@viewer_router.get("/designer/3d/{path:path}")
async def viewer_client(request: Request, path: str = "") -> Response:
    from webtool.viser_proxy import client_response

    return await client_response(request, path)


@viewer_router.websocket("/designer/3d")
async def viewer_socket(ws: WebSocket) -> None:
    from webtool.access import access_level
    from webtool.viser_proxy import proxy_socket

    if access_level(ws) != "full":
        await ws.close(code=1008)      # view-only links cannot edit the design
        return
    session = get_session(ws)
    try:
        v = await run_in_threadpool(session.viewer)
    except (DesignError, OSError):
        await ws.close(code=1011)
        return
    await proxy_socket(ws, v.port)


# ------------------------------------------------------------------------------ mesh


def _too_big(size: int, limit: int, claimed: bool) -> HTTPException:
    mb = size / (1024 * 1024)
    what = f"is {mb:.0f} MB" if claimed else f"is more than {limit / (1024 * 1024):.0f} MB"
    return HTTPException(413, f"This file {what}; the limit is {limit / (1024 * 1024):.0f} MB. "
                              "Simplify the model in your CAD program (fewer triangles, e.g. "
                              "'decimate' or a coarser STL export) and upload it again.")


@router.post("/mesh")
async def upload_mesh(request: Request, session: Session,
                      filename: Annotated[str, Query(min_length=1, max_length=255)],
                      units: str = "auto") -> JSONResponse:
    """Upload a mesh as the raw request body. The size is checked from Content-Length before
    anything is read, and again while streaming (for uploads without a length)."""
    limit = session.max_upload_bytes
    claimed = request.headers.get("content-length")
    if claimed is not None:
        try:
            n = int(claimed)
        except ValueError:
            raise HTTPException(400, "Bad Content-Length header.") from None
        if n > limit:
            raise _too_big(n, limit, True)
    if units not in ("auto", "mm", "cm", "m"):
        raise HTTPException(422, "units must be auto, mm, cm or m")
    buf = bytearray()
    async for chunk in request.stream():
        buf += chunk
        if len(buf) > limit:
            raise _too_big(len(buf), limit, False)
    try:
        await run_in_threadpool(session.load_mesh, bytes(buf), filename, units)
    except DesignError as e:
        raise _fail(e) from None
    return _state(session)


@router.post("/open")
def open_example(session: Session, example: Annotated[str, Body(embed=True)]) -> JSONResponse:
    try:
        session.open_example(example)
    except DesignError as e:
        raise _fail(e) from None
    return _state(session)


@router.post("/units")
def set_units(session: Session, units: Annotated[str, Body(embed=True)]) -> JSONResponse:
    names = {"mm": "millimetres", "cm": "centimetres", "m": "metres"}
    return _do(session, lambda d: d.set_units(units),
               f"The model's numbers are now read as {names.get(units, units)}.")


@router.post("/frame")
def set_frame(session: Session, action: Annotated[str, Body()],
              angle_deg: Annotated[float, Body()] = 90.0) -> JSONResponse:
    def run(d):
        if action == "origin_top_centre":
            d.origin_to_top_centre()
        elif action == "align_x":
            if not d.align_x_with_longest_edge():
                raise DesignError("the model has no straight horizontal edge to align x with")
        elif action == "turn":
            d.turn_frame(angle_deg)
        elif action == "flip":
            d.flip_frame()
        elif action == "reset":
            d.reset_frame()
        else:
            raise DesignError(f"unknown frame action {action!r}")

    messages = {"origin_top_centre": "Origin moved to the centre of the top of the model.",
                "align_x": "x now runs along the longest horizontal edge.",
                "turn": f"Axes turned by {angle_deg:g}° about z.",
                "flip": "Axes turned upside down.", "reset": "Axes back to the file's own."}
    return _do(session, run, messages.get(action))


@router.post("/mode")
def set_mode(session: Session, mode: Annotated[str, Body(embed=True)]) -> JSONResponse:
    from webtool.designer_scene import MODE_LABELS

    return _do(session, lambda d: d.set_mode(mode),
               f"A click on the model now does: {MODE_LABELS.get(mode, mode)}.",
               need_mesh=False)


@router.post("/click")
def click(session: Session, origin: Annotated[list[float], Body()],
          direction: Annotated[list[float], Body()]) -> JSONResponse:
    try:
        res = session.click(origin, direction)
    except DesignError as e:
        raise _fail(e) from None
    return _state(session, {"click": {"action": res.action, "message": res.message,
                                      "marker": res.marker}})


@router.post("/select")
def select(session: Session, index: Annotated[int | None, Body(embed=True)] = None
           ) -> JSONResponse:
    return _do(session, lambda d: d.select(index))


@router.post("/markers/{index}")
def edit_marker(session: Session, index: int, body: Annotated[dict[str, Any], Body()]
                ) -> JSONResponse:
    allowed = {"size_mm", "color", "slot", "rotate_deg", "nudge_mm", "centre"}
    unknown = set(body) - allowed
    if unknown:
        raise HTTPException(422, f"unknown field(s) {', '.join(sorted(unknown))}; use "
                                 f"{', '.join(sorted(allowed))}")

    def run(d):
        d.select(index)
        if "size_mm" in body or "color" in body or "slot" in body:
            size = body.get("size_mm")
            d.set_marker(index, size=None if size is None else float(size) / 1000.0,
                         color=body.get("color"), slot=body.get("slot"))
        if body.get("rotate_deg"):
            d.rotate_marker(index, float(body["rotate_deg"]))
        if body.get("nudge_mm"):
            r, u = (float(v) for v in body["nudge_mm"])
            d.nudge_marker(index, r / 1000.0, u / 1000.0)
        if body.get("centre"):
            d.centre_marker(index)

    try:
        return _do(session, run)
    except (TypeError, ValueError) as e:
        if isinstance(e, DesignError):
            raise
        raise HTTPException(422, f"bad value: {e}") from None


@router.delete("/markers/{index}")
def delete_marker(session: Session, index: int) -> JSONResponse:
    return _do(session, lambda d: d.delete_marker(index), "Marker deleted.")


@router.post("/defaults")
def set_defaults(session: Session, body: Annotated[dict[str, Any], Body()]) -> JSONResponse:
    def mm(key):
        v = body.get(key)
        return None if v is None else float(v) / 1000.0

    try:
        kw = dict(code_size=mm("code_size_mm"), dot_diameter=mm("dot_diameter_mm"),
                  dot_color=body.get("dot_color"), grid=mm("grid_mm"), snap_radius=mm("snap_mm"))
    except (TypeError, ValueError):
        raise HTTPException(422, "sizes must be numbers (millimetres)") from None
    return _do(session, lambda d: d.set_defaults(**kw), need_mesh=False)


@router.post("/layout")
def set_layout(session: Session, body: Annotated[dict[str, Any], Body()]) -> JSONResponse:
    allowed = {"name", "description", "first_id", "ids_per_instance", "instances", "symmetry",
               "family"}
    unknown = set(body) - allowed
    if unknown:
        raise HTTPException(422, f"unknown field(s) {', '.join(sorted(unknown))}")

    def num(key):
        if key not in body:
            return "keep"
        v = body[key]
        if v in (None, "", "auto"):
            return None
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise DesignError(f"{key.replace('_', ' ')} must be a whole number or 'auto'"
                              ) from None
        if f != int(f):
            raise DesignError(f"{key.replace('_', ' ')} must be a whole number")
        return int(f)

    def run(d):
        inst = num("instances")
        d.set_layout_fields(name=body.get("name"), description=body.get("description"),
                            first_id=num("first_id"), ids_per_instance=num("ids_per_instance"),
                            instances=None if inst in ("keep", None) else inst,
                            symmetry=body.get("symmetry"), code_family=body.get("family"))

    return _do(session, run)


@router.post("/fix")
def fix(session: Session, action: Annotated[dict[str, Any], Body(embed=True)]) -> JSONResponse:
    return _do(session, lambda d: _apply(session, action))


def _apply(session: DesignerSession, action: dict) -> None:
    from drovisio.designer.checks import apply_fix

    apply_fix(session.doc, action)
    session.message = "Fixed."


@router.post("/undo")
def undo(session: Session) -> JSONResponse:
    return _do(session, lambda d: d.undo() or None, "Undone.", need_mesh=False)


@router.post("/redo")
def redo(session: Session) -> JSONResponse:
    return _do(session, lambda d: d.redo() or None, "Redone.", need_mesh=False)


@router.post("/save")
def save(session: Session, overwrite: Annotated[bool, Body(embed=True)] = False
         ) -> JSONResponse:
    _need_mesh(session)
    try:
        saved = session.save(overwrite=overwrite)
    except DesignError as e:
        raise _fail(e) from None
    return _state(session, {"saved": {"layout": str(saved.layout_path),
                                      "mesh": str(saved.mesh_path)}})


# ------------------------------------------------------------------------------ export


def _export(session: DesignerSession, fn):
    _need_mesh(session)
    with session.lock:
        doc = session.doc.copy()
    try:
        return fn(doc)
    except DesignError as e:
        raise _fail(e) from None


def _download(data: bytes | str, media: str, filename: str) -> Response:
    return Response(data, media_type=media, headers={
        **NO_STORE, "Content-Disposition": f'attachment; filename="{filename}"'})


@router.get("/export/layout.json")
def export_layout(session: Session) -> Response:
    from drovisio.designer.checks import blocking, check_design
    from drovisio.designer.export import build_layout

    def run(doc):
        errors = blocking(check_design(doc, session.camera))
        if errors:
            raise DesignError("Fix these problems first: " + " ".join(f.message for f in errors))
        return build_layout(doc).to_json()

    doc_name = session.doc.name
    return _download(_export(session, run), "application/json", f"{doc_name}.json")


@router.get("/export/mesh.stl")
def export_mesh(session: Session) -> Response:
    from drovisio.designer.export import mesh_stl_bytes

    return _download(_export(session, mesh_stl_bytes), "model/stl", f"{session.doc.name}.stl")


@router.get("/export/brick.glb")
def export_glb(session: Session) -> Response:
    from drovisio.designer.export import export_glb as glb

    return _download(_export(session, glb), "model/gltf-binary", f"{session.doc.name}.glb")


@router.get("/export/sheet.pdf")
def export_pdf(session: Session) -> Response:
    from drovisio.designer.export import print_sheet_pdf

    return _download(_export(session, print_sheet_pdf), "application/pdf",
                     f"{session.doc.name}-print-sheet.pdf")


@router.get("/export/sheet.svg")
def export_svg(session: Session, page: Annotated[int, Query(ge=1)] = 1) -> Response:
    from drovisio.designer.export import print_sheet_svg

    return _download(_export(session, lambda d: print_sheet_svg(d, page)), "image/svg+xml",
                     f"{session.doc.name}-print-sheet-{page}.svg")


@router.post("/verify")
def verify(session: Session) -> JSONResponse:
    """Render one brick of the current design and detect it (see
    :func:`drovisio.designer.verify.verify_layout`)."""
    import base64
    import tempfile
    from pathlib import Path

    import cv2

    from drovisio.designer.checks import blocking, check_design
    from drovisio.designer.export import save_design
    from drovisio.designer.verify import verify_layout
    from drovisio.layout import load_layout

    def run(doc):
        errors = blocking(check_design(doc, session.camera))
        if errors:
            raise DesignError("Fix these problems first: " + " ".join(f.message for f in errors))
        with tempfile.TemporaryDirectory(prefix="drovisio-verify-") as tmp:
            saved = save_design(doc, Path(tmp))
            results, image = verify_layout(load_layout(saved.layout_path),
                                           camera=session.camera)
        ok, jpg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
        return {"results": [r.to_json() for r in results],
                "image": "data:image/jpeg;base64," + base64.b64encode(jpg.tobytes()).decode()}

    return JSONResponse(_export(session, run), headers=NO_STORE)
