"""The designer page's requests as steps on a design document: reframing the model, editing a
marker, the layout's fields and the defaults (millimetres from the page, metres in the
document), checking a design before export, and trying it on a simulated photo.

Each ``*_edit`` gives a function of the document that :meth:`DesignerService.edit
<webtool.designer.service.DesignerService.edit>` runs under the service's lock.
"""

from __future__ import annotations

import base64
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2

from drovisio.camera import Camera
from drovisio.designer.checks import blocking, check_design
from drovisio.designer.export import save_design
from drovisio.designer.model import DesignDocument, DesignError
from drovisio.designer.verify import verify_layout
from drovisio.layout import load_layout
from webtool.designer.schemas import DefaultsBody, FrameBody, LayoutBody, MarkerBody

__all__ = ["MM", "UNIT_NAMES", "defaults_edit", "frame_edit", "frame_message", "layout_edit",
           "marker_edit", "require_valid", "verification"]

MM = 1000.0  # millimetres per metre
UNIT_NAMES = {"mm": "millimetres", "cm": "centimetres", "m": "metres"}
Edit = Callable[[DesignDocument], Any]


def frame_edit(body: FrameBody) -> Edit:
    """Move the brick frame: origin to the top centre, x along the longest edge, turn about
    z, flip, or back to the file's own."""
    def run(d: DesignDocument) -> None:
        if body.action == "origin_top_centre":
            d.origin_to_top_centre()
        elif body.action == "align_x":
            if not d.align_x_with_longest_edge():
                raise DesignError("the model has no straight horizontal edge to align x with")
        elif body.action == "turn":
            d.turn_frame(body.angle_deg)
        elif body.action == "flip":
            d.flip_frame()
        else:
            d.reset_frame()
    return run


def frame_message(body: FrameBody) -> str:
    """What the page says after a frame move."""
    messages = {"origin_top_centre": "Origin moved to the centre of the top of the model.",
                "align_x": "x now runs along the longest horizontal edge.",
                "turn": f"Axes turned by {body.angle_deg:g}° about z.",
                "flip": "Axes turned upside down.", "reset": "Axes back to the file's own."}
    return messages[body.action]


def marker_edit(index: int, body: MarkerBody) -> Edit:
    """Select marker ``index`` and change what the body gives (size, colour, slot; rotate,
    nudge in mm along its right and up, centre on its face)."""
    def run(d: DesignDocument) -> None:
        d.select(index)
        if body.size_mm is not None or body.color is not None or body.slot is not None:
            d.set_marker(index, size=None if body.size_mm is None else body.size_mm / MM,
                         color=body.color, slot=body.slot)
        if body.rotate_deg:
            d.rotate_marker(index, body.rotate_deg)
        if body.nudge_mm:
            d.nudge_marker(index, body.nudge_mm[0] / MM, body.nudge_mm[1] / MM)
        if body.centre:
            d.centre_marker(index)
    return run


def defaults_edit(body: DefaultsBody) -> Edit:
    """The next markers' defaults (sizes, grid and snap radius in mm)."""
    def mm(v: float | None) -> float | None:
        return None if v is None else v / MM

    def run(d: DesignDocument) -> Any:
        return d.set_defaults(code_size=mm(body.code_size_mm),
                              dot_diameter=mm(body.dot_diameter_mm), dot_color=body.dot_color,
                              grid=mm(body.grid_mm), snap_radius=mm(body.snap_mm))
    return run


def layout_edit(body: LayoutBody) -> Edit:
    """The layout's fields; a number left out keeps its value, ``auto`` (or empty) makes it
    automatic."""
    given = body.model_fields_set

    def num(key: str) -> Any:
        if key not in given:
            return "keep"
        v = getattr(body, key)
        return None if v in (None, "", "auto") else int(v)

    def run(d: DesignDocument) -> None:
        inst = num("instances")
        d.set_layout_fields(name=body.name, description=body.description,
                            first_id=num("first_id"), ids_per_instance=num("ids_per_instance"),
                            instances=None if inst in ("keep", None) else inst,
                            symmetry=body.symmetry, code_family=body.family)
    return run


def require_valid(doc: DesignDocument, camera: Camera) -> None:
    """Raise :class:`DesignError` naming the problems that block an export."""
    errors = blocking(check_design(doc, camera))
    if errors:
        raise DesignError("Fix these problems first: " + " ".join(f.message for f in errors))


def verification(doc: DesignDocument, camera: Camera) -> dict[str, Any]:
    """Render one brick of the design and detect it (see
    :func:`drovisio.designer.verify.verify_layout`): the detectors' errors and the photo as a
    JPEG data URL."""
    require_valid(doc, camera)
    with tempfile.TemporaryDirectory(prefix="drovisio-verify-") as tmp:
        saved = save_design(doc, Path(tmp))
        results, image = verify_layout(load_layout(saved.layout_path), camera=camera)
    ok, jpg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return {"results": [r.to_json() for r in results],
            "image": "data:image/jpeg;base64," + base64.b64encode(jpg.tobytes()).decode()}
