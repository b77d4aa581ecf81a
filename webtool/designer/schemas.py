"""The marker designer API's request bodies and response models (``/api/designer``).

Lengths in the bodies are millimetres (people's unit), angles degrees.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, field_validator

from drovisio.designer.model.edits import MAX_MARKER_SIZE_M, MIN_MARKER_SIZE_M
from webtool.schemas import Answer, Body, Json

__all__ = ["ClickBody", "DefaultsBody", "DesignerState", "FixAction", "FixBody", "FrameBody",
           "LayoutBody", "MarkerBody", "ModeBody", "OpenBody", "SaveBody", "SelectBody",
           "UnitsBody", "Verification"]


# ------------------------------------------------------------------------------ requests
#: a code side or dot diameter in millimetres, in the designer model's bounds (one range for
#: the page's sizes, its defaults and its fixes)
Size = Annotated[float, Field(ge=MIN_MARKER_SIZE_M * 1000, le=MAX_MARKER_SIZE_M * 1000)]
Angle = Annotated[float, Field(ge=-3600, le=3600)]      # degrees
Coord = Annotated[float, Field(ge=-1e6, le=1e6)]
Whole = Annotated[int, Field(ge=0, le=1_000_000)]


class OpenBody(Body):
    example: Annotated[str, Field(min_length=1, max_length=300)]


class UnitsBody(Body):
    units: Literal["mm", "cm", "m"]


class FrameBody(Body):
    action: Literal["origin_top_centre", "align_x", "turn", "flip", "reset"]
    angle_deg: Angle = 90.0


class ModeBody(Body):
    mode: Literal["code", "dot", "select", "origin"]


class ClickBody(Body):
    origin: tuple[Coord, Coord, Coord]
    direction: tuple[Coord, Coord, Coord]

    @field_validator("direction")
    @classmethod
    def _not_zero(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if math.hypot(*v) < 1e-12:
            raise ValueError("a click direction must not be zero")
        return v


class SelectBody(Body):
    index: Whole | None = None


class MarkerBody(Body):
    size_mm: Size | None = None
    color: Annotated[str, Field(min_length=1, max_length=40)] | None = None
    slot: Annotated[int, Field(ge=0, le=10_000)] | None = None
    rotate_deg: Angle | None = None
    nudge_mm: tuple[Annotated[float, Field(ge=-5000, le=5000)],
                    Annotated[float, Field(ge=-5000, le=5000)]] | None = None
    centre: bool = False


class DefaultsBody(Body):
    code_size_mm: Size | None = None
    dot_diameter_mm: Size | None = None
    dot_color: Annotated[str, Field(min_length=1, max_length=40)] | None = None
    grid_mm: Annotated[float, Field(ge=0, le=5000)] | None = None
    snap_mm: Annotated[float, Field(ge=0, le=5000)] | None = None


AutoInt = Whole | Literal["auto", ""] | None


class LayoutBody(Body):
    name: Annotated[str, Field(max_length=100)] | None = None
    description: Annotated[str, Field(max_length=2000)] | None = None
    first_id: AutoInt = None
    ids_per_instance: AutoInt = None
    instances: AutoInt = None
    symmetry: Literal["none", "rot180_z"] | None = None
    family: Annotated[str, Field(max_length=40)] | None = None


class FixAction(Body):
    op: Annotated[str, Field(min_length=1, max_length=40)]
    marker: Whole | None = None
    markers: Annotated[list[Whole], Field(min_length=1, max_length=200)] | None = None
    color: Annotated[str, Field(max_length=40)] | None = None
    size: Annotated[float, Field(ge=MIN_MARKER_SIZE_M, le=MAX_MARKER_SIZE_M)] | None = None  # m
    value: Annotated[str, Field(max_length=40)] | Whole | None = None
    units: Literal["mm", "cm", "m"] | None = None


class FixBody(Body):
    action: FixAction


class SaveBody(Body):
    overwrite: bool = False


# ----------------------------------------------------------------------------- answers
class DesignerState(Answer):
    """Everything the page shows (lengths in mm); mutating calls answer it too (``save`` adds
    ``saved``: the files written)."""

    version: int
    message: str
    notes: list[str]
    mode: str
    modes: list[dict[str, str]]
    can_undo: bool
    can_redo: bool
    layouts_dir: str
    max_upload_mb: float
    camera: str
    examples: list[dict[str, str]]
    families: list[dict[str, str]]
    palette: list[dict[str, Json]]
    defaults: dict[str, Json]
    checks: list[dict[str, Json]]
    can_export: bool
    viewer_port: int | None
    mesh: dict[str, Json] | None
    markers: list[dict[str, Json]]
    selected: int | None


class Verification(Answer):
    """The layout tried on a simulated photo: the detectors' errors, and the photo."""

    results: list[dict[str, Json]]
    image: str
    """a JPEG data URL"""
