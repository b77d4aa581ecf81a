"""The two marker kinds a layout holds: square ArUco codes and round colour dots.

Lengths are in the layout's ``units``; directions are unitless. Both models are frozen and
reject unknown fields.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    JsonValue,
    StrictFloat,
    StrictInt,
    field_validator,
    model_validator,
)

from drovisio.layout.dictionaries import accepted_dictionary_names, check_dictionary_name
from drovisio.layout.errors import Located, LocatedIssues
from drovisio.layout.palette import DEFAULT_PALETTE
from drovisio.layout.square import square_corners, square_issues, unit

__all__ = [
    "MAX_COORD",
    "UP_MIN_ANGLE_DEG",
    "Coord",
    "Vec3",
    "PositiveFloat",
    "ArucoMarker",
    "DotMarker",
    "Marker",
]

#: no coordinate or size beyond a kilometre in millimetres: such numbers are not a brick (and
#: overflow the geometry checks)
MAX_COORD = 1e6
Coord = Annotated[StrictFloat, Field(ge=-MAX_COORD, le=MAX_COORD)]
Vec3 = tuple[Coord, Coord, Coord]
PositiveFloat = Annotated[StrictFloat, Field(gt=0, le=MAX_COORD)]

UP_MIN_ANGLE_DEG = 1.0  #: ``up`` must be at least 1 degree away from ``normal``.

#: The dictionary names the schema lists (canonical names and aliases).
_DICTIONARY_ENUM: list[JsonValue] = [*accepted_dictionary_names()]


class ArucoMarker(BaseModel):
    """A square ArUco code printed on the brick.

    Give either ``corners`` or ``center`` + ``normal`` + ``up`` (they mean the same square).
    Lengths are in the layout's ``units``.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    kind: Literal["aruco"] = Field(description="Marker kind.")
    dictionary: str = Field(
        description="cv2.aruco predefined dictionary name, e.g. DICT_4X4_50.",
        json_schema_extra={"enum": _DICTIONARY_ENUM},
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
        check_dictionary_name(v)  # raises with the list of valid names
        return v

    @model_validator(mode="after")
    def _check_geometry(self) -> ArucoMarker:
        frame = [self.center is not None, self.normal is not None, self.up is not None]
        if self.corners is not None:
            if any(frame):
                raise LocatedIssues([((), "give either 'corners' or 'center' + 'normal' + 'up', "
                                          "not both")])
            issues = square_issues(np.array(self.corners, np.float64), self.size)
        elif all(frame):
            issues = _frame_issues(np.array(self.normal, np.float64),
                                   np.array(self.up, np.float64))
        else:
            missing = [k for k, given in zip(("center", "normal", "up"), frame) if not given]
            issues = [((missing[0],) if any(frame) else (),
                       "give either 'corners' (4 x [x, y, z]) or 'center' + 'normal' + "
                       f"'up'; missing: {', '.join(missing)}")]
        if issues:
            raise LocatedIssues(issues)
        return self

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
            return unit(np.array(self.normal, np.float64))
        c = self.corners_array()
        right = c[1] - c[0] + c[2] - c[3]
        upv = c[0] - c[3] + c[1] - c[2]
        return unit(np.cross(right, upv))

    def up_array(self) -> np.ndarray:
        """Unit vector toward the printed image's top edge (in the code plane), (3,)."""
        c = self.corners_array()
        return unit(c[0] - c[3] + c[1] - c[2])

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
        return unit(np.array(self.normal, np.float64))

    def describe(self) -> str:
        """Short label used in messages, e.g. ``"dot red"``."""
        return f"dot {self.color}"


def _frame_issues(n: np.ndarray, up: np.ndarray) -> list[Located]:
    """The problem (if any) with a code given by ``normal`` and ``up`` (each (3,))."""
    if np.linalg.norm(n) < 1e-12:
        return [(("normal",), "normal is the zero vector; give the direction "
                              "the printed face looks toward, e.g. [0, 0, 1]")]
    if np.linalg.norm(up) < 1e-12:
        return [(("up",), "up is the zero vector; give the direction toward "
                          "the printed image's top edge, e.g. [0, 1, 0]")]
    sin = np.linalg.norm(np.cross(unit(n), unit(up)))
    if sin < math.sin(math.radians(UP_MIN_ANGLE_DEG)):
        return [(("up",), "up is parallel to normal; up must point along the "
                          "code's surface, toward the printed image's top edge")]
    return []


Marker = Annotated[ArucoMarker | DotMarker, Field(discriminator="kind")]
