"""Marker layouts: which markers a brick carries and where (``marker_layouts/*.json``).

One typed pydantic v2 model, :class:`MarkerLayout`, is the single source of truth for the
layout file format (contract: ``DESIGN.md``, "Marker layout file"). It validates files,
converts every problem into a :class:`LayoutError` that names the file, the marker and the
field, and emits the JSON Schema the web designer uses (:func:`layout_json_schema`).

Units: the model keeps the numbers in the file's ``units`` (so a layout written in
millimetres saves back in millimetres). Everything the rest of Drovisio consumes goes through
the ``*_m`` accessors, which return metres (convention: metres and radians inside).

Frames: all coordinates are in the brick frame defined by the layout. Shipped layouts put the
origin at the centre of the brick's top face, x along the length, y along the width, z up.

Ids: a layout with ArUco codes owns a block of ids. Instance ``k``'s code in slot ``s`` has
id ``first_id + k * ids_per_instance + s``.

Typical use::

    from drovisio.layout import load_layouts, shipped_layouts_dir
    layouts = load_layouts(sorted(shipped_layouts_dir().glob("*.json")))
    corners = layouts[1].code_corners_m()   # {slot: (4, 3) float64 array in metres}
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictFloat,
    StrictInt,
    ValidationError,
    field_validator,
    model_validator,
)

from drovisio.errors import LIMITS, InputError
from drovisio.fileio import atomic_write_bytes
from drovisio.textfile import check_regular_file, parse_json

__all__ = [
    "SCHEMA_ID",
    "UNITS_TO_M",
    "DEFAULT_PALETTE",
    "LayoutError",
    "ColorSpec",
    "ArucoMarker",
    "DotMarker",
    "Marker",
    "MarkerLayout",
    "aruco_dictionaries",
    "aruco_dictionary_id",
    "aruco_dictionary_size",
    "with_dictionary",
    "aruco_code_bits",
    "aruco_family",
    "square_corners",
    "parse_layout",
    "load_layout",
    "load_layouts",
    "save_layout",
    "layout_to_json",
    "check_id_clashes",
    "check_layout_set",
    "layout_json_schema",
    "shipped_layouts_dir",
    "list_shipped_layouts",
]

#: The exact value of a layout file's ``schema`` field.
SCHEMA_ID = "drovisio/marker-layout@1"

#: Metres per file unit.
UNITS_TO_M: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}

# Geometric tolerances (documented in the error messages).
SQUARE_SIDE_REL_TOL = 0.01  #: code sides must equal ``size`` within 1 %.
SQUARE_ANGLE_TOL_DEG = 1.0  #: code corners must be right angles within 1 degree.
SQUARE_PLANAR_REL_TOL = 0.01  #: code corners within 1 % of ``size`` of their plane.
DOT_COPLANAR_TOL_M = 0.001  #: dots within 1 mm of their common plane.
SYMMETRY_TOL_M = 0.001  #: a half-turn must map each dot onto a dot within 1 mm.
UP_MIN_ANGLE_DEG = 1.0  #: ``up`` must be at least 1 degree away from ``normal``.


class LayoutError(InputError):
    """A layout file (or a set of layouts) is invalid.

    The message is meant for the user: every line names the file, the place (marker index
    and kind/id, then the field) and says how to fix it. ``issues`` holds the same lines.
    """

    def __init__(self, message: str, issues: Sequence[str] | None = None):
        super().__init__(message)
        self.issues: list[str] = list(issues) if issues is not None else [message]


class _Issues(ValueError):
    """Internal: located problems raised inside validators (converted to LayoutError)."""

    def __init__(self, items: list[tuple[tuple[Any, ...], str]]):
        super().__init__("; ".join(msg for _, msg in items))
        self.items = items


# --------------------------------------------------------------------------------------
# ArUco dictionaries
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _DictInfo:
    name: str  # canonical name
    value: int  # cv2.aruco.DICT_* constant
    size: int  # number of codes
    family: str  # dictionaries of the same family share codes (prefix-nested)


@lru_cache(maxsize=1)
def _dictionary_table() -> tuple[dict[str, _DictInfo], tuple[str, ...]]:
    """Accepted names -> info, and the canonical names in cv2 constant order."""
    import cv2

    by_value: dict[int, list[str]] = {}
    for attr in dir(cv2.aruco):
        if attr.startswith("DICT_"):
            value = getattr(cv2.aruco, attr)
            if isinstance(value, int):
                by_value.setdefault(value, []).append(attr)
    table: dict[str, _DictInfo] = {}
    canonical: list[str] = []
    for value in sorted(by_value):
        names = sorted(by_value[value])
        # OpenCV's documented spelling has a lower-case 'h' (DICT_APRILTAG_36h11); the
        # upper-case aliases are accepted as well.
        name = next((n for n in names if n != n.upper()), names[0])
        size = int(cv2.aruco.getPredefinedDictionary(value).bytesList.shape[0])
        parts = name.split("_")  # DICT_4X4_50 -> ["DICT", "4X4", "50"]
        if len(parts) == 3 and parts[1][0].isdigit() and "X" in parts[1] and parts[2].isdigit():
            family = f"DICT_{parts[1]}"
        else:
            family = name.upper()
        info = _DictInfo(name=name, value=value, size=size, family=family)
        canonical.append(name)
        for n in names:
            table[n] = info
    return table, tuple(canonical)


def aruco_dictionaries() -> list[str]:
    """Names of the predefined ArUco dictionaries, in OpenCV's constant order.

    Returns:
        Canonical names such as ``"DICT_4X4_50"`` or ``"DICT_APRILTAG_36h11"``. The
        upper-case aliases OpenCV also defines (``"DICT_APRILTAG_36H11"``) are accepted in
        layout files too.
    """
    return list(_dictionary_table()[1])


def _dict_info(name: str) -> _DictInfo:
    table = _dictionary_table()[0]
    try:
        return table[name]
    except KeyError:
        raise ValueError(
            f"unknown dictionary {name!r}; use one of {', '.join(aruco_dictionaries())}"
        ) from None


def aruco_dictionary_id(name: str) -> int:
    """The ``cv2.aruco`` constant of a dictionary name.

    Args:
        name: a predefined dictionary name, e.g. ``"DICT_4X4_50"``.

    Returns:
        The integer for ``cv2.aruco.getPredefinedDictionary``.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    return _dict_info(name).value


def aruco_dictionary_size(name: str) -> int:
    """Number of codes (ids ``0 .. size-1``) in a predefined dictionary."""
    return _dict_info(name).size


@lru_cache(maxsize=1024)
def aruco_code_bits(dictionary: str | int, marker_id: int) -> np.ndarray:
    """A code's cells, its black border included: (n, n) uint8, 1 = white, 0 = black; row 0
    is the printed image's top edge, column 0 its left edge (read-only, cached).

    Args:
        dictionary: The dictionary's name (``DICT_4X4_50``) or OpenCV's id for it.
        marker_id: The code's id in the dictionary.
    """
    import cv2

    did = aruco_dictionary_id(dictionary) if isinstance(dictionary, str) else int(dictionary)
    d = cv2.aruco.getPredefinedDictionary(did)
    n = d.markerSize + 2
    img = cv2.aruco.generateImageMarker(d, int(marker_id), n, borderBits=1)
    out = (img > 127).astype(np.uint8)
    out.flags.writeable = False
    return out


def aruco_family(name: str) -> str:
    """Family of a predefined dictionary: dictionaries of one family share their codes.

    ``DICT_4X4_50`` is the first 50 codes of ``DICT_4X4_100``, and so on up to
    ``_1000``; the same holds for 5X5, 6X6 and 7X7. ``DICT_ARUCO_ORIGINAL``,
    ``DICT_ARUCO_MIP_36h12`` and each ``DICT_APRILTAG_*`` are their own family.

    Returns:
        ``"DICT_4X4"`` etc. for the nested families, else the upper-cased name.
    """
    return _dict_info(name).family


# --------------------------------------------------------------------------------------
# Colours
# --------------------------------------------------------------------------------------

HsvTriple = tuple[StrictInt, StrictInt, StrictInt]
BgrTriple = tuple[StrictInt, StrictInt, StrictInt]
#: no coordinate or size beyond a kilometre in millimetres: such numbers are not a brick (and
#: overflow the geometry checks)
MAX_COORD = 1e6
Coord = Annotated[StrictFloat, Field(ge=-MAX_COORD, le=MAX_COORD)]
Vec3 = tuple[Coord, Coord, Coord]
PositiveFloat = Annotated[StrictFloat, Field(gt=0, le=MAX_COORD)]


class ColorSpec(BaseModel):
    """A named dot colour: its HSV threshold range and optionally its paint colour.

    HSV is in OpenCV units: H 0-179, S and V 0-255. A range whose low hue exceeds its high
    hue wraps through 0 (red: H 170 -> 10).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    hsv: tuple[HsvTriple, HsvTriple] = Field(
        description="[[h, s, v] low, [h, s, v] high] in OpenCV units (H 0-179, S/V 0-255); "
        "low hue > high hue wraps through 0."
    )
    bgr: BgrTriple | None = Field(
        default=None, description="Optional paint/display colour [b, g, r], 0-255."
    )

    @field_validator("hsv")
    @classmethod
    def _check_hsv(cls, v: tuple[HsvTriple, HsvTriple]) -> tuple[HsvTriple, HsvTriple]:
        for which, (h, s, val) in zip(("low", "high"), v):
            if not 0 <= h <= 179:
                raise ValueError(f"{which} hue {h} is outside 0..179 (OpenCV hue units)")
            if not (0 <= s <= 255 and 0 <= val <= 255):
                raise ValueError(f"{which} saturation/value must be within 0..255")
        if v[0][1] > v[1][1] or v[0][2] > v[1][2]:
            raise ValueError("low saturation/value must not exceed high (only hue may wrap)")
        return v

    @field_validator("bgr")
    @classmethod
    def _check_bgr(cls, v: BgrTriple | None) -> BgrTriple | None:
        if v is not None and not all(0 <= c <= 255 for c in v):
            raise ValueError("bgr components must be within 0..255")
        return v

    @property
    def wraps(self) -> bool:
        """True when the hue range wraps through 0 (low hue > high hue)."""
        return self.hsv[0][0] > self.hsv[1][0]

    def cv_ranges(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Ranges for ``cv2.inRange`` (a wrapping hue range gives two).

        Returns:
            A list of ``(low, high)`` uint8 arrays of shape (3,), to OR together.
        """
        lo, hi = np.array(self.hsv[0], np.uint8), np.array(self.hsv[1], np.uint8)
        if not self.wraps:
            return [(lo, hi)]
        lo2, hi2 = lo.copy(), hi.copy()
        hi1 = hi.copy()
        hi1[0] = 179
        lo2[0] = 0
        return [(lo, hi1), (lo2, hi2)]

    def contains(self, hsv: Sequence[int]) -> bool:
        """Whether one OpenCV HSV pixel ``(h, s, v)`` falls inside this range."""
        h, s, v = (int(c) for c in hsv)
        (h0, s0, v0), (h1, s1, v1) = self.hsv
        hue_ok = (h0 <= h <= h1) if not self.wraps else (h >= h0 or h <= h1)
        return hue_ok and s0 <= s <= s1 and v0 <= v <= v1

    def display_bgr(self) -> tuple[int, int, int]:
        """``bgr`` if given, else a colour at the middle of the HSV range (for drawing)."""
        if self.bgr is not None:
            return self.bgr
        import cv2

        (h0, s0, v0), (h1, s1, v1) = self.hsv
        h = ((h0 + ((h1 - h0) % 180) / 2) % 180) if self.wraps else (h0 + h1) / 2
        px = np.array([[[round(h) % 180, (s0 + s1) // 2, (v0 + v1) // 2]]], np.uint8)
        b, g, r = cv2.cvtColor(px, cv2.COLOR_HSV2BGR)[0, 0]
        return int(b), int(g), int(r)

    def display_rgb(self) -> tuple[int, int, int]:
        """:meth:`display_bgr` in RGB order (viser, PDF, glTF, the web pages)."""
        b, g, r = self.display_bgr()
        return r, g, b


#: The default dot colours (OpenCV HSV units). Layouts may override or add colours.
#: Each paint ``bgr`` falls inside its own range and outside the others (tested).
DEFAULT_PALETTE: dict[str, ColorSpec] = {
    "red": ColorSpec(hsv=((170, 80, 70), (10, 255, 255)), bgr=(40, 40, 210)),
    "yellow": ColorSpec(hsv=((20, 80, 80), (35, 255, 255)), bgr=(30, 210, 230)),
    "green": ColorSpec(hsv=((40, 80, 60), (75, 255, 255)), bgr=(50, 170, 40)),
    "blue": ColorSpec(hsv=((80, 85, 75), (115, 255, 255)), bgr=(200, 120, 20)),
}


# --------------------------------------------------------------------------------------
# Markers
# --------------------------------------------------------------------------------------


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def square_corners(center: Sequence[float], normal: Sequence[float], up: Sequence[float],
                   size: float) -> np.ndarray:
    """Corners of a square code from its centre, facing direction and up direction.

    n = normalize(normal), u = normalize(up - (up.n) n), r = u x n;
    TL = c - r s/2 + u s/2, TR = c + r s/2 + u s/2, BR = c + r s/2 - u s/2,
    BL = c - r s/2 - u s/2 (OpenCV / ``cv2.aruco.Board`` order). With n = +z, up = +y this
    is OpenCV's square object points (-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0),
    (-s/2, -s/2, 0).

    Args:
        center: square centre [x, y, z] (any length unit).
        normal: direction the printed face looks toward (out of the surface).
        up: direction toward the printed image's top edge (need not be exactly
            perpendicular to ``normal``).
        size: side of the outer black border, same unit as ``center``.

    Returns:
        (4, 3) float64 array TL, TR, BR, BL, in the unit of ``center``.
    """
    c = np.asarray(center, np.float64)
    n = _unit(np.asarray(normal, np.float64))
    up_v = np.asarray(up, np.float64)
    u = _unit(up_v - np.dot(up_v, n) * n)
    r = np.cross(u, n)
    h = size / 2.0
    return np.array([c - r * h + u * h, c + r * h + u * h, c + r * h - u * h, c - r * h - u * h])


class ArucoMarker(BaseModel):
    """A square ArUco code printed on the brick.

    Give either ``corners`` or ``center`` + ``normal`` + ``up`` (they mean the same square).
    Lengths are in the layout's ``units``.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    kind: Literal["aruco"] = Field(description="Marker kind.")
    dictionary: str = Field(
        description="cv2.aruco predefined dictionary name, e.g. DICT_4X4_50.",
        json_schema_extra={"enum": sorted(_dictionary_table()[0], key=lambda n: (
            _dictionary_table()[0][n].value, n))},
    )
    id: StrictInt = Field(
        ge=0,
        description="Slot s in the instance's id block (0 <= s < ids_per_instance); "
        "full id = first_id + instance * ids_per_instance + s."
    )
    size: StrictFloat = Field(gt=0, le=MAX_COORD, description="Side of the outer black border.")
    corners: tuple[Vec3, Vec3, Vec3, Vec3] | None = Field(
        default=None,
        description="Outer border corners [x, y, z] in OpenCV order: top-left, top-right, "
        "bottom-right, bottom-left of the printed image seen from the front.",
    )
    center: Vec3 | None = Field(default=None, description="Code centre [x, y, z].")
    normal: Vec3 | None = Field(
        default=None, description="Direction the printed face looks toward [x, y, z]."
    )
    up: Vec3 | None = Field(
        default=None, description="Direction toward the printed image's top edge [x, y, z]."
    )

    @field_validator("dictionary")
    @classmethod
    def _check_dictionary(cls, v: str) -> str:
        _dict_info(v)  # raises with the list of valid names
        return v

    @model_validator(mode="after")
    def _check_geometry(self) -> ArucoMarker:
        frame = [self.center is not None, self.normal is not None, self.up is not None]
        if self.corners is not None:
            if any(frame):
                raise _Issues([((), "give either 'corners' or 'center' + 'normal' + 'up', "
                                    "not both")])
            self._check_square(np.array(self.corners, np.float64))
        elif all(frame):
            n = np.array(self.normal, np.float64)
            up = np.array(self.up, np.float64)
            if np.linalg.norm(n) < 1e-12:
                raise _Issues([(("normal",), "normal is the zero vector; give the direction "
                                             "the printed face looks toward, e.g. [0, 0, 1]")])
            if np.linalg.norm(up) < 1e-12:
                raise _Issues([(("up",), "up is the zero vector; give the direction toward "
                                         "the printed image's top edge, e.g. [0, 1, 0]")])
            sin = np.linalg.norm(np.cross(_unit(n), _unit(up)))
            if sin < math.sin(math.radians(UP_MIN_ANGLE_DEG)):
                raise _Issues([(("up",), "up is parallel to normal; up must point along the "
                                         "code's surface, toward the printed image's top edge")])
        else:
            missing = [k for k, given in zip(("center", "normal", "up"), frame) if not given]
            raise _Issues([((missing[0],) if any(frame) else (),
                            "give either 'corners' (4 x [x, y, z]) or 'center' + 'normal' + "
                            f"'up'; missing: {', '.join(missing)}")])
        return self

    def _check_square(self, c: np.ndarray) -> None:
        s = self.size
        issues: list[tuple[tuple[Any, ...], str]] = []
        names = ("top-left", "top-right", "bottom-right", "bottom-left")
        for i in range(4):
            side = float(np.linalg.norm(c[(i + 1) % 4] - c[i]))
            if abs(side - s) > SQUARE_SIDE_REL_TOL * s:
                issues.append((("corners",), f"side {names[i]} -> {names[(i + 1) % 4]} is "
                               f"{side:.6g} but size is {s:.6g} (must agree within "
                               f"{SQUARE_SIDE_REL_TOL:.0%}); list the 4 corners of a square "
                               "of side 'size' in order TL, TR, BR, BL"))
                break
        if not issues:
            for i in range(4):
                a = c[(i + 1) % 4] - c[i]
                b = c[i - 1] - c[i]
                cosang = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
                ang = math.degrees(math.acos(max(-1.0, min(1.0, cosang))))
                if abs(ang - 90.0) > SQUARE_ANGLE_TOL_DEG:
                    issues.append((("corners",), f"angle at the {names[i]} corner is "
                                   f"{ang:.2f} deg, not 90 (tolerance {SQUARE_ANGLE_TOL_DEG:g} "
                                   "deg); the corners must form a square, in order TL, TR, BR, "
                                   "BL"))
                    break
        if not issues:
            centred = c - c.mean(axis=0)
            normal = np.linalg.svd(centred)[2][2]
            dev = float(np.max(np.abs(centred @ normal)))
            if dev > SQUARE_PLANAR_REL_TOL * s:
                issues.append((("corners",), f"the corners are not planar ({dev:.6g} off "
                               f"their plane, tolerance {SQUARE_PLANAR_REL_TOL:.0%} of size)"))
        if issues:
            raise _Issues(issues)

    def corners_array(self) -> np.ndarray:
        """Corners TL, TR, BR, BL as a (4, 3) float64 array, in the layout's units."""
        if self.corners is not None:
            return np.array(self.corners, np.float64)
        assert self.center is not None and self.normal is not None and self.up is not None
        return square_corners(self.center, self.normal, self.up, self.size)

    def center_array(self) -> np.ndarray:
        """Centre of the square, (3,) float64, in the layout's units."""
        if self.center is not None:
            return np.array(self.center, np.float64)
        return self.corners_array().mean(axis=0)

    def normal_array(self) -> np.ndarray:
        """Unit vector the printed face looks toward, (3,) float64."""
        if self.normal is not None:
            return _unit(np.array(self.normal, np.float64))
        c = self.corners_array()
        right = c[1] - c[0] + c[2] - c[3]
        upv = c[0] - c[3] + c[1] - c[2]
        return _unit(np.cross(right, upv))

    def up_array(self) -> np.ndarray:
        """Unit vector toward the printed image's top edge (in the code plane), (3,)."""
        c = self.corners_array()
        return _unit(c[0] - c[3] + c[1] - c[2])

    def describe(self) -> str:
        """Short label used in messages, e.g. ``"aruco id 1"``."""
        return f"aruco id {self.id}"


class DotMarker(BaseModel):
    """A round colour dot painted on the brick. Lengths are in the layout's ``units``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    kind: Literal["dot"] = Field(description="Marker kind.")
    color: str = Field(
        min_length=1,
        description="Colour name: a key of the layout's 'colors' or of the default palette "
        f"({', '.join(DEFAULT_PALETTE)}).",
    )
    diameter: StrictFloat = Field(gt=0, le=MAX_COORD, description="Dot diameter.")
    center: Vec3 = Field(description="Dot centre [x, y, z].")
    normal: Vec3 = Field(default=(0.0, 0.0, 1.0),
                         description="Direction the dot faces [x, y, z] (default +z).")

    @field_validator("normal")
    @classmethod
    def _check_normal(cls, v: Vec3) -> Vec3:
        if np.linalg.norm(v) < 1e-12:
            raise ValueError("normal is the zero vector; give the direction the dot faces, "
                             "e.g. [0, 0, 1]")
        return v

    def center_array(self) -> np.ndarray:
        """Dot centre, (3,) float64, in the layout's units."""
        return np.array(self.center, np.float64)

    def normal_array(self) -> np.ndarray:
        """Unit vector the dot faces, (3,) float64."""
        return _unit(np.array(self.normal, np.float64))

    def describe(self) -> str:
        """Short label used in messages, e.g. ``"dot red"``."""
        return f"dot {self.color}"


Marker = Annotated[ArucoMarker | DotMarker, Field(discriminator="kind")]


# --------------------------------------------------------------------------------------
# Layout
# --------------------------------------------------------------------------------------


class MarkerLayout(BaseModel):
    """A brick type's markers (the ``marker_layouts/*.json`` file format).

    Numbers are stored in ``units``; use the ``*_m`` accessors for metres. Build one from a
    file with :func:`load_layout` or from a dict/JSON text with :func:`parse_layout` (both
    raise :class:`LayoutError`; ``MarkerLayout.model_validate`` raises pydantic's
    ``ValidationError``). Immutable; ``model_copy(update=...)`` does not re-validate, so
    send edited data through :func:`parse_layout`. Equality compares content only.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, populate_by_name=True,
                              frozen=True, title="Drovisio marker layout")

    schema_id: Literal["drovisio/marker-layout@1"] = Field(
        alias="schema", description=f"File format id, exactly {SCHEMA_ID!r}."
    )
    name: str = Field(min_length=1, description="Layout name, used in detection output.")
    description: str | None = Field(
        default=None, description="Free text describing the physical brick."
    )
    units: Literal["m", "cm", "mm"] = Field(
        description="Length unit of every coordinate, size, diameter and of the mesh."
    )
    dimensions: tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = Field(
        default=None,
        description="Bounding box size [x, y, z] of the brick, each > 0; when absent, the "
        "bounding box of the markers (and of the mesh) is used.",
    )
    mesh: str | None = Field(
        default=None,
        description="Mesh file (STL, OBJ, PLY...) relative to the layout file, in 'units'.",
    )
    first_id: StrictInt | None = Field(
        default=None, ge=0, description="First ArUco id of the block (null with no codes)."
    )
    ids_per_instance: StrictInt | None = Field(
        default=None, ge=1, description="Ids (slots) per brick instance (null with no codes)."
    )
    instances: StrictInt | None = Field(
        default=None, ge=1, description="Number of brick instances the block covers "
        "(null with no codes)."
    )
    symmetry: Literal["none", "rot180_z"] = Field(
        default="none",
        description="'rot180_z' when a half-turn about z maps the markers onto themselves "
        "(yaw then is ambiguous by 180 deg).",
    )
    colors: dict[str, ColorSpec] | None = Field(
        default=None, description="Dot colours overriding/adding to the default palette."
    )
    markers: list[Marker] = Field(min_length=1, max_length=LIMITS.max_markers,
                                  description="The markers on the brick (at most "
                                  f"{LIMITS.max_markers}).")

    _source: Path | None = PrivateAttr(default=None)

    def __eq__(self, other: object) -> bool:
        """Equal content (the source file does not matter)."""
        if not isinstance(other, MarkerLayout):
            return NotImplemented
        return self.model_dump() == other.model_dump()

    __hash__ = None  # type: ignore[assignment]

    # ---- validation -------------------------------------------------------------------

    @field_validator("mesh")
    @classmethod
    def _check_mesh(cls, v: str | None) -> str | None:
        if v is not None:
            if not v.strip():
                raise ValueError("mesh path is empty; give a path relative to the layout "
                                 "file or null")
            if Path(v).is_absolute() or v.startswith(("/", "\\")) or ":" in v[:3]:
                raise ValueError(f"mesh path {v!r} is absolute; give it relative to the "
                                 "layout file, e.g. 'meshes/drick.stl'")
        return v

    @field_validator("name")
    @classmethod
    def _check_name(cls, v: str) -> str:
        if v != v.strip():
            raise ValueError("name must not start or end with whitespace")
        return v

    @model_validator(mode="after")
    def _check_layout(self) -> MarkerLayout:
        issues: list[tuple[tuple[Any, ...], str]] = []
        codes = [(i, m) for i, m in enumerate(self.markers) if isinstance(m, ArucoMarker)]
        dots = [(i, m) for i, m in enumerate(self.markers) if isinstance(m, DotMarker)]

        # ids
        if codes:
            missing = [k for k in ("first_id", "ids_per_instance", "instances")
                       if getattr(self, k) is None]
            for k in missing:
                issues.append(((k,), "required when the layout has ArUco codes; give an "
                                     "integer (ids = first_id + instance * ids_per_instance "
                                     "+ slot)"))
            seen: dict[int, int] = {}
            ipi = self.ids_per_instance
            for i, m in codes:
                if m.id in seen:
                    issues.append((("markers", i, "id"), f"duplicate slot {m.id}: already "
                                   f"used by markers[{seen[m.id]}]; give each code its own "
                                   "slot"))
                else:
                    seen[m.id] = i
                if ipi is not None and m.id >= ipi:
                    issues.append((("markers", i, "id"), f"slot {m.id} is out of range: "
                                   f"ids_per_instance is {ipi}, so slots are 0..{ipi - 1}; "
                                   "raise ids_per_instance or renumber the slot"))
            if not missing:
                assert self.first_id is not None and self.ids_per_instance is not None
                assert self.instances is not None
                end = self.first_id + self.ids_per_instance * self.instances
                reported: set[str] = set()
                for i, m in codes:
                    size = aruco_dictionary_size(m.dictionary)
                    if end > size and m.dictionary not in reported:
                        reported.add(m.dictionary)
                        issues.append((("markers", i, "dictionary"), f"ids run up to "
                                       f"{end - 1} (first_id {self.first_id} + "
                                       f"ids_per_instance {self.ids_per_instance} x instances "
                                       f"{self.instances}) but {m.dictionary} has only {size} "
                                       f"ids (0..{size - 1}); use a larger dictionary or lower "
                                       "first_id/instances"))

        # colours
        palette = self.palette()
        for i, m in dots:
            if m.color not in palette:
                issues.append((("markers", i, "color"), f"unknown colour {m.color!r}; use one "
                               f"of {', '.join(palette)} or define it in 'colors'"))

        # dots coplanar
        if len(dots) >= 4:
            pts = np.array([m.center for _, m in dots], np.float64) * self.scale_to_m
            centred = pts - pts.mean(axis=0)
            sv = np.linalg.svd(centred)
            dist = np.abs(centred @ sv[2][2])
            worst = int(np.argmax(dist))
            if dist[worst] > DOT_COPLANAR_TOL_M:
                i = dots[worst][0]
                issues.append((("markers", i, "center"), f"dots are not coplanar: this dot is "
                               f"{dist[worst] * 1000:.1f} mm off the best-fit plane of the "
                               f"layout's dots (tolerance {DOT_COPLANAR_TOL_M * 1000:g} mm); put "
                               "all dots on one plane"))

        # symmetry (dots decide: ArUco ids fix the orientation by themselves)
        if not issues and dots:
            sym = self._dots_rot180_z_symmetric()
            if self.symmetry == "rot180_z" and not sym:
                issues.append((("symmetry",), "'rot180_z' but a half-turn about z does not map "
                               "the dots onto dots of the same colour and diameter; use 'none'"))
            elif self.symmetry == "none" and sym and not codes:
                issues.append((("symmetry",), "the dots look the same after a half-turn about z, "
                               "so the yaw is ambiguous by 180 deg; set 'rot180_z' (or make the "
                               "pattern asymmetric)"))
        if issues:
            raise _Issues(issues)
        return self

    def _dots_rot180_z_symmetric(self) -> bool:
        dots = self.dot_markers()
        pts = self.dot_centers_m()
        rot = pts * np.array([-1.0, -1.0, 1.0])
        for j, d in enumerate(dots):
            dist = np.linalg.norm(pts - rot[j], axis=1)
            ok = [k for k in np.flatnonzero(dist <= SYMMETRY_TOL_M)
                  if dots[k].color == d.color
                  and abs(dots[k].diameter - d.diameter) * self.scale_to_m <= SYMMETRY_TOL_M]
            if not ok:
                return False
        return True

    # ---- units and geometry (metres) --------------------------------------------------

    @property
    def scale_to_m(self) -> float:
        """Metres per file unit (1, 0.01 or 0.001)."""
        return UNITS_TO_M[self.units]

    @property
    def dimensions_m(self) -> np.ndarray:
        """Bounding box size [x, y, z] in metres, (3,) float64: ``dimensions`` when the file
        gives them, else the bounding box of the markers and of the mesh (each side at
        least 1 mm: a flat tag still has a thickness to draw)."""
        if self.dimensions is not None:
            return np.array(self.dimensions, np.float64) * self.scale_to_m
        lo, hi = self._markers_bounds_m()
        mesh = self._mesh_bounds_m()
        if mesh is not None:
            lo, hi = np.minimum(lo, mesh[0]), np.maximum(hi, mesh[1])
        return np.maximum(hi - lo, 0.001)

    def _markers_bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners of the box around every code square and dot disc, metres."""
        pts = [c for c in self.code_corners_m().values()]
        lo = [p.min(axis=0) for p in pts]
        hi = [p.max(axis=0) for p in pts]
        if self.has_dots:
            centres, normals = self.dot_centers_m(), self.dot_normals()
            radii = self.dot_diameters_m() / 2
            # a disc of radius r and normal n reaches r·sqrt(1 − n_e²) along axis e
            reach = radii[:, None] * np.sqrt(np.clip(1 - normals ** 2, 0, 1))
            lo.append((centres - reach).min(axis=0))
            hi.append((centres + reach).max(axis=0))
        return np.min(lo, axis=0), np.max(hi, axis=0)

    def _mesh_bounds_m(self) -> tuple[np.ndarray, np.ndarray] | None:
        path = self.mesh_path()
        if path is None or not path.is_file():
            return None
        return _mesh_bounds(str(path), path.stat().st_mtime_ns, self.scale_to_m)

    @property
    def source(self) -> Path | None:
        """The file this layout was loaded from (or last saved to), if any."""
        return self._source

    def code_markers(self) -> list[ArucoMarker]:
        """The ArUco markers, in file order."""
        return [m for m in self.markers if isinstance(m, ArucoMarker)]

    def _codes_by_slot(self) -> list[ArucoMarker]:
        return sorted(self.code_markers(), key=lambda m: m.id)

    def dot_markers(self) -> list[DotMarker]:
        """The dot markers, in file order (the row order of the ``dot_*`` arrays)."""
        return [m for m in self.markers if isinstance(m, DotMarker)]

    @property
    def has_codes(self) -> bool:
        """True if the layout carries ArUco codes."""
        return any(isinstance(m, ArucoMarker) for m in self.markers)

    @property
    def has_dots(self) -> bool:
        """True if the layout carries colour dots."""
        return any(isinstance(m, DotMarker) for m in self.markers)

    def code_corners_m(self) -> dict[int, np.ndarray]:
        """Corners of every code in the brick frame, in metres.

        Returns:
            ``{slot: (4, 3) float64}``, corners in OpenCV order TL, TR, BR, BL (the
            ``cv2.aruco.Board`` object-point order), ordered by slot.
        """
        s = self.scale_to_m
        return {m.id: m.corners_array() * s for m in self._codes_by_slot()}

    def code_centers_m(self) -> dict[int, np.ndarray]:
        """Centre of every code in metres: ``{slot: (3,) float64}``."""
        s = self.scale_to_m
        return {m.id: m.center_array() * s for m in self._codes_by_slot()}

    def code_normals(self) -> dict[int, np.ndarray]:
        """Unit facing direction of every code: ``{slot: (3,) float64}`` (unitless)."""
        return {m.id: m.normal_array() for m in self._codes_by_slot()}

    def code_sizes_m(self) -> dict[int, float]:
        """Outer border side of every code in metres: ``{slot: size}``."""
        return {m.id: m.size * self.scale_to_m for m in self._codes_by_slot()}

    def code_dictionaries(self) -> dict[int, str]:
        """Dictionary name of every code: ``{slot: name}``."""
        return {m.id: m.dictionary for m in self._codes_by_slot()}

    def dictionaries(self) -> list[str]:
        """Distinct dictionary names used by the codes, in first-use order."""
        return list(dict.fromkeys(m.dictionary for m in self.code_markers()))

    def dot_centers_m(self) -> np.ndarray:
        """Dot centres in the brick frame, in metres: (N, 3) float64, file order."""
        dots = self.dot_markers()
        if not dots:
            return np.zeros((0, 3), np.float64)
        return np.array([d.center for d in dots], np.float64) * self.scale_to_m

    def dot_normals(self) -> np.ndarray:
        """Unit facing direction of every dot: (N, 3) float64, file order."""
        dots = self.dot_markers()
        return np.array([d.normal_array() for d in dots], np.float64).reshape(-1, 3)

    def dot_diameters_m(self) -> np.ndarray:
        """Dot diameters in metres: (N,) float64, file order."""
        return np.array([d.diameter for d in self.dot_markers()], np.float64) * self.scale_to_m

    def dot_colors(self) -> list[str]:
        """Dot colour names, file order."""
        return [d.color for d in self.dot_markers()]

    def palette(self) -> dict[str, ColorSpec]:
        """The default palette overridden/extended by this layout's ``colors``."""
        return {**DEFAULT_PALETTE, **(self.colors or {})}

    def mesh_path(self) -> Path | None:
        """The mesh file, resolved relative to the layout file (or the working directory
        if the layout has no source file); None if the layout names no mesh. The mesh is in
        the layout's ``units``."""
        if self.mesh is None:
            return None
        base = self._source.parent if self._source is not None else Path.cwd()
        return (base / self.mesh).resolve()

    # ---- ids ----------------------------------------------------------------------------

    def id_block(self) -> range:
        """All ids the layout owns, ``first_id .. first_id + ids_per_instance*instances - 1``
        (an empty range when the layout has no codes)."""
        if not self.has_codes or None in (self.first_id, self.ids_per_instance, self.instances):
            return range(0)
        first, ipi, n = self.first_id, self.ids_per_instance, self.instances
        return range(first, first + ipi * n)  # type: ignore[operator]

    def marker_id(self, instance: int, slot: int) -> int:
        """Full ArUco id of instance ``instance``'s code in slot ``slot``.

        Args:
            instance: brick instance k, ``0 <= k < instances``.
            slot: code slot s, ``0 <= s < ids_per_instance``.

        Returns:
            ``first_id + instance * ids_per_instance + slot``.

        Raises:
            ValueError: the layout has no codes, or instance/slot out of range.
        """
        if not self.has_codes:
            raise ValueError(f"layout {self.name!r} has no ArUco codes, so no ids")
        assert self.first_id is not None and self.ids_per_instance is not None
        assert self.instances is not None
        if not 0 <= instance < self.instances:
            raise ValueError(f"instance {instance} out of range 0..{self.instances - 1}")
        if not 0 <= slot < self.ids_per_instance:
            raise ValueError(f"slot {slot} out of range 0..{self.ids_per_instance - 1}")
        return self.first_id + instance * self.ids_per_instance + slot

    def instance_slot(self, marker_id: int) -> tuple[int, int] | None:
        """Which instance and slot a detected id belongs to.

        Args:
            marker_id: a full ArUco id.

        Returns:
            ``(instance, slot)``, or None when the id is outside this layout's block or
            its slot carries no code in this layout.
        """
        block = self.id_block()
        if marker_id not in block:
            return None
        assert self.ids_per_instance is not None
        instance, slot = divmod(marker_id - block.start, self.ids_per_instance)
        if slot not in {m.id for m in self.code_markers()}:
            return None
        return instance, slot

    def all_ids(self) -> list[int]:
        """Every id a code of this layout can carry, sorted (instances x used slots)."""
        if not self.has_codes:
            return []
        slots = sorted({m.id for m in self.code_markers()})
        assert self.instances is not None
        return sorted(self.marker_id(k, s) for k in range(self.instances) for s in slots)

    # ---- serialisation ----------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The layout as a JSON-ready dict in the file format (file units, nulls dropped
        for optional fields that are unset)."""
        return self.model_dump(mode="json", by_alias=True, exclude_none=True)

    def to_json(self) -> str:
        """The layout as JSON text in the file format (see :func:`layout_to_json`)."""
        return layout_to_json(self)


# --------------------------------------------------------------------------------------
# Error conversion
# --------------------------------------------------------------------------------------


def _marker_label(raw: Any) -> str:
    if not isinstance(raw, dict):
        return ""
    kind = raw.get("kind")
    if kind == "aruco":
        return f" (aruco id {raw.get('id')})" if "id" in raw else " (aruco)"
    if kind == "dot":
        return f" (dot {raw.get('color')})" if "color" in raw else " (dot)"
    return f" ({kind})" if isinstance(kind, str) else ""


def _format_loc(loc: Sequence[Any], data: Any) -> str:
    """('markers', 2, 'aruco', 'corners', 1) -> 'markers[2] (aruco id 1): corners[1]'."""
    loc = list(loc)
    prefix = ""
    if len(loc) >= 2 and loc[0] == "markers" and isinstance(loc[1], int):
        raw = None
        if isinstance(data, dict) and isinstance(data.get("markers"), list):
            if 0 <= loc[1] < len(data["markers"]):
                raw = data["markers"][loc[1]]
        prefix = f"markers[{loc[1]}]{_marker_label(raw)}"
        loc = loc[2:]
        if loc and loc[0] in ("aruco", "dot"):  # discriminated-union tag
            loc = loc[1:]
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    if prefix and out:
        return f"{prefix}: {out}"
    return prefix or out or "(layout)"


_Located = tuple[tuple[Any, ...], str]


def _error_message(err: dict[str, Any]) -> _Located | list[_Located]:
    typ = err["type"]
    ctx = err.get("ctx") or {}
    inp = err.get("input")
    loc = tuple(err["loc"])
    if typ == "value_error" and isinstance(ctx.get("error"), _Issues):
        return [(loc + sub, msg) for sub, msg in ctx["error"].items]
    field = next((p for p in reversed(loc) if isinstance(p, str)), "")
    if typ == "missing":
        if loc and isinstance(loc[-1], int):  # a fixed-length list such as [x, y, z]
            return loc[:-1], f"too few items (item [{loc[-1]}] is missing)"
        return loc, "required field is missing; add it"
    if typ == "extra_forbidden":
        return loc, "unknown field; remove it or fix its spelling"
    if typ == "literal_error":
        if field == "schema":
            return loc, f"unsupported schema {inp!r}; this version reads exactly {SCHEMA_ID!r}"
        if field == "units":
            return loc, f"unknown units {inp!r}; use one of 'm', 'cm', 'mm'"
        return loc, f"invalid value {inp!r}; use one of {ctx.get('expected')}"
    if typ == "union_tag_invalid":
        return loc + ("kind",), (f"unknown marker kind {ctx.get('tag')!r}; use "
                                 f"{ctx.get('expected_tags')}")
    if typ == "union_tag_not_found":
        return loc + ("kind",), "missing 'kind'; use 'aruco' or 'dot'"
    if typ in ("greater_than", "greater_than_equal"):
        op = ">" if typ == "greater_than" else ">="
        bound = ctx.get("gt", ctx.get("ge"))
        return loc, f"must be {op} {bound:g} (got {inp!r})"
    if typ in ("too_short", "too_long"):
        if field == "markers":
            return loc, "a layout needs at least one marker"
        want = ctx.get("min_length") if typ == "too_short" else ctx.get("max_length")
        if field in ("corners",) and isinstance(inp, (list, tuple)):
            return loc, f"expected 4 corners [[x, y, z], ...], got {len(inp)}"
        if isinstance(inp, (list, tuple)):
            return loc, f"expected {want} items, got {len(inp)}"
        return loc, f"expected {want} items"
    if typ in ("float_type", "int_type", "string_type", "tuple_type", "list_type",
               "dict_type", "model_type", "model_attributes_type", "finite_number",
               "int_from_float", "float_parsing", "int_parsing"):
        want = {"float_type": "a number", "finite_number": "a finite number",
                "int_type": "an integer", "int_from_float": "an integer",
                "int_parsing": "an integer", "float_parsing": "a number",
                "string_type": "a string", "tuple_type": "a list", "list_type": "a list",
                "dict_type": "an object", "model_type": "an object",
                "model_attributes_type": "an object"}[typ]
        return loc, f"expected {want}, got {json.dumps(inp) if _jsonable(inp) else repr(inp)}"
    msg = err.get("msg", "invalid value")
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    return loc, msg


def _jsonable(x: Any) -> bool:
    try:
        json.dumps(x)
        return True
    except (TypeError, ValueError):
        return False


def _convert_validation_error(exc: ValidationError, data: Any, source: str) -> LayoutError:
    items: list[tuple[tuple[Any, ...], str]] = []
    for err in exc.errors(include_url=False):
        res = _error_message(err)
        items.extend(res if isinstance(res, list) else [res])
    lines = [f"{source}: {_format_loc(loc, data)}: {msg}" for loc, msg in items]
    lines = list(dict.fromkeys(lines))
    return LayoutError("\n".join(lines), lines)


# --------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------


@lru_cache(maxsize=32)
def _mesh_bounds(path: str, _mtime_ns: int, scale: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Bounds of a mesh file in metres (None when it cannot be read: the markers decide)."""
    try:
        import trimesh

        mesh = trimesh.load(path, force="mesh")
        b = np.asarray(mesh.bounds, np.float64) * scale
    except Exception:  # noqa: BLE001 - a broken mesh is reported where it is drawn
        return None
    return (b[0], b[1]) if b.shape == (2, 3) and np.all(np.isfinite(b)) else None


def _reject_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


class _DuplicateKey(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def parse_layout(data: dict[str, Any] | str | bytes, source: str | os.PathLike[str] = "<layout>",
                 ) -> MarkerLayout:
    """Validate a layout given as a dict or JSON text.

    Args:
        data: the parsed JSON object, or JSON text.
        source: what to call it in error messages (a file name; mesh paths are resolved
            relative to it when it is a path).

    Returns:
        The validated layout, in the units of ``data``.

    Raises:
        LayoutError: invalid JSON or an invalid layout (message names source, marker, field).
    """
    src = os.fspath(source)
    if isinstance(data, (str, bytes)):
        try:
            text = data.decode("utf-8") if isinstance(data, bytes) else data
            data = parse_json(text, src, object_pairs_hook=_reject_duplicate_keys)
        except UnicodeDecodeError as e:
            raise LayoutError(f"{src}: not UTF-8 text ({e.reason} at byte {e.start})") from None
        except _DuplicateKey as e:
            raise LayoutError(f"{src}: duplicate key {e.key!r} in a JSON object; keep only "
                              "one") from None
        except InputError as e:
            raise LayoutError(str(e)) from None
    if not isinstance(data, dict):
        raise LayoutError(f"{src}: a layout file must hold one JSON object {{...}}, "
                          f"not {type(data).__name__}")
    try:
        layout = MarkerLayout.model_validate(data)
    except ValidationError as e:
        raise _convert_validation_error(e, data, src) from None
    if src and not src.startswith("<"):
        layout._source = Path(src)
    return layout


def load_layout(path: str | os.PathLike[str]) -> MarkerLayout:
    """Read and validate one layout file.

    Args:
        path: the ``.json`` file. Errors name it as given.

    Returns:
        The layout (numbers in the file's units; ``source`` set to ``path``).

    Raises:
        LayoutError: missing/unreadable file, invalid JSON or invalid layout.
    """
    src = os.fspath(path)
    try:
        p = check_regular_file(path, "layout file")
        if p.stat().st_size > LIMITS.max_file_bytes:
            raise LayoutError(f"{src}: larger than {LIMITS.max_file_bytes // 1024} KiB; is it "
                              "the right file?")
        raw = p.read_bytes()
    except InputError as e:
        raise LayoutError(str(e).replace("layout file not found", "no such layout file")) \
            from None
    except OSError as e:
        raise LayoutError(f"{src}: cannot read: {e.strerror}") from None
    return parse_layout(raw, src)


def _where(layout: MarkerLayout) -> str:
    return f"{layout.name!r} ({layout.source if layout.source is not None else 'not from a file'})"


def check_id_clashes(layouts: Sequence[MarkerLayout]) -> None:
    """Raise if layouts meant to be used together could see the same code.

    Each layout owns its whole id block (:meth:`MarkerLayout.id_block`) in every dictionary
    family its codes use; two layouts clash when they share a family and their blocks
    overlap.

    Raises:
        LayoutError: naming both layouts (name and file) and the overlapping ids.
    """
    lines: list[str] = []
    for a_i, a in enumerate(layouts):
        fam_a = {aruco_family(d) for d in a.dictionaries()}
        block_a = a.id_block()
        for b in layouts[a_i + 1:]:
            block_b = b.id_block()
            common = sorted(fam_a & {aruco_family(d) for d in b.dictionaries()})
            lo, hi = max(block_a.start, block_b.start), min(block_a.stop, block_b.stop)
            if common and lo < hi:
                ids = f"{lo}" if hi - lo == 1 else f"{lo}..{hi - 1}"
                lines.append(
                    f"layouts {_where(a)} and {_where(b)} share ids {ids} in the "
                    f"{'/'.join(common)} dictionary family ({a.name}: "
                    f"{block_a.start}..{block_a.stop - 1}, {b.name}: "
                    f"{block_b.start}..{block_b.stop - 1}); give one of them another "
                    "first_id or another dictionary family")
    if lines:
        raise LayoutError("\n".join(lines), lines)


def check_layout_set(layouts: Sequence[MarkerLayout]) -> None:
    """Checks for layouts used together: unique names and no id clashes.

    Raises:
        LayoutError: two layouts with the same name, or clashing ids (see
            :func:`check_id_clashes`).
    """
    seen: dict[str, MarkerLayout] = {}
    for lay in layouts:
        if lay.name in seen:
            raise LayoutError(f"layouts {_where(seen[lay.name])} and {_where(lay)} have the "
                              "same name; detections are reported by layout name, so rename "
                              "one")
        seen[lay.name] = lay
    check_id_clashes(layouts)


def load_layouts(paths: Iterable[str | os.PathLike[str]]) -> list[MarkerLayout]:
    """Load layouts meant to be used together and check them as a set.

    Args:
        paths: layout files.

    Returns:
        The layouts, in the order given.

    Raises:
        LayoutError: any invalid file, duplicate names, or overlapping ids
            (:func:`check_layout_set`).
    """
    layouts = [load_layout(p) for p in paths]
    check_layout_set(layouts)
    return layouts


def _dump_compact(obj: Any, indent: int = 0) -> str:
    """JSON with objects indented and short lists of numbers kept on one line."""
    pad, inner = "  " * indent, "  " * (indent + 1)
    if isinstance(obj, dict):
        if not obj:
            return "{}"
        items = [f"{inner}{json.dumps(k)}: {_dump_compact(v, indent + 1)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(obj, list):
        flat = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in obj)
        nested = all(isinstance(x, list) and all(isinstance(y, (int, float)) for y in x)
                     for x in obj)
        if flat or (nested and obj):
            return json.dumps(obj, allow_nan=False)
        if not obj:
            return "[]"
        items = [f"{inner}{_dump_compact(v, indent + 1)}" for v in obj]
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    return json.dumps(obj, allow_nan=False, ensure_ascii=False)


def layout_to_json(layout: MarkerLayout) -> str:
    """The layout as JSON text in the file format: file units, full float precision
    (``repr``), readable layout (one marker per block, coordinates on one line)."""
    data = layout.to_dict()
    # Files without codes state their id fields explicitly as null (contract example).
    for k in ("first_id", "ids_per_instance", "instances"):
        data.setdefault(k, None)
    order = ["schema", "name", "description", "units", "dimensions", "mesh", "first_id",
             "ids_per_instance", "instances", "symmetry", "colors", "markers"]
    data = {k: data[k] for k in order if k in data} | {k: v for k, v in data.items()
                                                      if k not in order}
    return _dump_compact(data) + "\n"


def save_layout(layout: MarkerLayout, path: str | os.PathLike[str], overwrite: bool = False
                ) -> Path:
    """Write a layout file atomically (temp file in the same folder, then rename).

    The numbers are written in the layout's own units. ``mesh`` is written as is (it stays
    relative to the new file's folder).

    Args:
        layout: the layout to write.
        path: destination ``.json`` file; its folder must exist.
        overwrite: replace an existing file; without it an existing file is an error.

    Returns:
        The path written.

    Raises:
        LayoutError: the file exists and ``overwrite`` is False.
        drovisio.errors.WriteError: it cannot be written (any previous file is kept).
    """
    dest = Path(path)
    src = os.fspath(path)
    if not overwrite and dest.exists():
        raise LayoutError(f"{src}: already exists; choose another file name or pass "
                          "overwrite=True to replace it")
    text = layout_to_json(layout)
    folder = dest.parent if str(dest.parent) else Path(".")
    if not folder.is_dir():
        raise LayoutError(f"{src}: folder {os.fspath(folder)} does not exist")
    def verify(tmp: Path) -> None:
        if parse_layout(tmp.read_bytes(), src) != layout:
            raise ValueError("the layout read back differs from the one written")

    try:
        atomic_write_bytes(dest, text.encode("utf-8"), overwrite=overwrite, verify=verify)
    except FileExistsError:
        raise LayoutError(f"{src}: already exists; choose another file name or pass "
                          "overwrite=True to replace it") from None
    layout._source = dest
    return dest


def layout_json_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of the layout file, generated from :class:`MarkerLayout`.

    Returns:
        A JSON-ready dict; markers are a ``oneOf`` discriminated on ``kind``. Checks that
        need the whole layout (slots, colours, coplanarity, id ranges) are not expressible
        in the schema; :func:`parse_layout` does them.
    """
    schema = MarkerLayout.model_json_schema(by_alias=True, mode="validation")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    return schema


def shipped_layouts_dir() -> Path:
    """The shipped ``marker_layouts/`` folder (installed with the package)."""
    from drovisio.resources import layouts_dir

    return layouts_dir()


def list_shipped_layouts() -> list[Path]:
    """The shipped layout files, sorted by name."""
    d = shipped_layouts_dir()
    return sorted(d.glob("*.json")) if d.is_dir() else []


def with_dictionary(layout: MarkerLayout, dictionary: str) -> MarkerLayout:
    """The layout with every code in ``dictionary`` (same ids), named ``NAME@DICT`` (without
    the ``DICT_`` prefix): the same brick for a detector that reads another family, e.g.
    AprilTag 3 and ``DICT_APRILTAG_36h11``.

    Raises:
        LayoutError: unknown dictionary, or too few codes in it for the layout's ids.
    """
    try:
        size = aruco_dictionary_size(dictionary)
    except ValueError as e:
        raise LayoutError(str(e)) from None
    need = (layout.first_id or 0) + (layout.instances or 0) * (layout.ids_per_instance or 1)
    if size < need:
        raise LayoutError(f"{dictionary} has {size} codes, {layout.name} needs ids up to "
                          f"{need - 1}")
    data = layout.model_dump(mode="json", by_alias=True)
    data["name"] = f"{layout.name}@{dictionary.removeprefix('DICT_')}"
    for m in data["markers"]:
        if m.get("kind") == "aruco":
            m["dictionary"] = dictionary
    return parse_layout(data, layout.source or "<layout>")
