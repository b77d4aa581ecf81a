"""The study protocol: which bricks, which camera, which steps (one schema, YAML or JSON).

A protocol file (``schema: drovisio/study-protocol@1``)::

    schema: drovisio/study-protocol@1
    name: my brick
    camera: camera.yaml            # default: the drone webcam of the renderer
    layouts:
      - {name: code, layout: drick-aruco-centre}          # a shipped layout, or a path
      - {name: code36h11, layout: drick-aruco-centre, dictionary: DICT_APRILTAG_36h11}
    steps:
      - {figure: "6.3", layout: code, vary: distance, value: 1.0, frames: 10}
      - {figure: "6.3", layout: code, vary: distance, value: 1.5, frames: 10,
         source: recordings/code_150cm.mp4}              # recorded: the truth is the step

Steps vary one quantity from the thesis's set-up (the camera facing the markers, z through
the camera perpendicular to them, x/y in their plane): ``distance`` (m, camera to the brick's
top face), ``offset_x`` / ``offset_y`` (m, along the image's x / y, at ``distance``, default
1.9 m), ``rot_x`` / ``rot_y`` / ``rot_z`` (degrees about the camera-plane axes and the axis
through the camera, at ``distance``, default 1 m). A step with ``source`` (a video or a folder
of images) is *recorded*: its truth is what the step says, measured on the bench with a tape
and a protractor. Without ``source`` it is rendered with the image conditions drawn per frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from drovisio.errors import InputError
from drovisio.textfile import path_text_problem, read_structured

__all__ = ["PROTOCOL_SCHEMA", "FIGURES", "LayoutRef", "Protocol", "ProtocolError", "Step",
           "default_protocol", "load_protocol"]

PROTOCOL_SCHEMA = "drovisio/study-protocol@1"

Vary = Literal["distance", "offset_x", "offset_y", "rot_x", "rot_y", "rot_z"]

#: the thesis's figures: what each one plots (vary, error shown, layouts' kind)
FIGURES: dict[str, dict] = {
    "6.2": {"vary": ("offset_x", "offset_y"), "error": "xy_cm", "kind": "dots",
            "title": "x/y error against the offset, at 1.9 m (dots)"},
    "6.3": {"vary": ("distance",), "error": "z_pct", "kind": "dots",
            "title": "z error against the distance (dots)"},
    "6.4": {"vary": ("rot_x", "rot_y"), "error": "rot_xy_deg", "kind": "dots",
            "title": "rotation error about x and y, at 1 m (dots)"},
    "6.5": {"vary": ("rot_z",), "error": "rot_z_deg", "kind": "dots",
            "title": "rotation error about z, at 1 m (dots)"},
    "6.6": {"vary": ("offset_x", "offset_y"), "error": "xy_cm", "kind": "codes",
            "title": "x/y error against the offset, at 1.9 m (codes)"},
    "6.7": {"vary": ("distance",), "error": "z_pct", "kind": "codes",
            "title": "z error against the distance (codes)"},
    "6.8": {"vary": ("rot_x", "rot_y"), "error": "rot_xy_deg", "kind": "codes",
            "title": "rotation error about x and y, at 1 m (codes)"},
    "6.9": {"vary": ("rot_z",), "error": "rot_z_deg", "kind": "codes",
            "title": "rotation error about z, at 1 m (codes)"},
}


class ProtocolError(InputError):
    """A protocol that cannot be used; the message names the file and the field."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _plain_path(v: str | None) -> str | None:
    """A path written in the protocol must be one the OS can open (no NUL byte, no name over
    255 bytes): refused here, by field, not deep inside a reader."""
    problem = None if v is None else path_text_problem(v)
    if problem:
        raise ValueError(f"the path {problem}")
    return v


class LayoutRef(_Model):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.@-]+$",
                      description="Name the steps use.")
    layout: str = Field(min_length=1, max_length=4096,
                        description="A shipped layout's name or a layout file's path.")
    dictionary: str | None = Field(default=None, max_length=40, description=(
        "Give every code of the layout this dictionary (same ids), e.g. DICT_APRILTAG_36h11 "
        "(AprilTag 3's own tag36h11)."))

    _path = field_validator("layout")(_plain_path)


class Step(_Model):
    figure: str = Field(pattern=r"^6\.[2-9]$", description="The thesis figure, 6.2 to 6.9.")
    layout: str = Field(min_length=1, max_length=64)
    vary: Vary
    value: float | None = Field(default=None, ge=-180, le=180, description=(
        "The truth: metres (distance, offsets) or degrees, as measured on the bench. A "
        "recorded step without it is skipped, with its reason in the report."))
    distance: float | None = Field(default=None, gt=0.05, le=20, description=(
        "Camera distance for offsets and rotations (m); default 1.9 m for offsets, 1 m for "
        "rotations."))
    frames: int = Field(default=10, ge=1, le=10_000)
    source: str | None = Field(default=None, max_length=4096, description=(
        "Recorded step: a video file or a folder of images (relative to the protocol)."))

    _path = field_validator("source")(_plain_path)

    @model_validator(mode="after")
    def _sane(self) -> Step:
        if self.value is None:
            if self.source is None:
                raise ValueError("value: a rendered step needs its value (metres or degrees)")
            return self
        if self.vary == "distance" and not 0.05 < self.value <= 20:
            raise ValueError("a distance step needs 0.05 < value <= 20 (metres)")
        if self.vary.startswith("offset") and abs(self.value) > 10:
            raise ValueError("an offset must be within ±10 m")
        return self

    @property
    def at_distance(self) -> float:
        if self.vary == "distance":
            return float(self.value or 0.0)
        if self.distance is not None:
            return self.distance
        return 1.9 if self.vary.startswith("offset") else 1.0

    @property
    def label(self) -> str:
        unit = "°" if self.vary.startswith("rot") else " m"
        return f"{self.vary} {'?' if self.value is None else f'{self.value:g}'}{unit}"


class Protocol(_Model):
    schema_id: Literal["drovisio/study-protocol@1"] = Field(alias="schema")
    name: str = Field(min_length=1, max_length=200)
    camera: str | None = Field(default=None, max_length=4096,
                               description="Camera file (default: the renderer's webcam).")
    layouts: list[LayoutRef] = Field(min_length=1, max_length=20)
    steps: list[Step] = Field(min_length=1, max_length=2000)
    seed: int = Field(default=0, ge=0, le=2**31)
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, populate_by_name=True)

    _path = field_validator("camera")(_plain_path)

    @model_validator(mode="after")
    def _names(self) -> Protocol:
        names = [lay.name for lay in self.layouts]
        if len(set(names)) != len(names):
            raise ValueError("two layouts have the same name")
        for i, s in enumerate(self.steps):
            if s.layout not in names:
                raise ValueError(f"steps.{i}.layout: {s.layout!r} is not one of the "
                                 f"layouts ({', '.join(names)})")
        return self


def load_protocol(path: str | Path) -> Protocol:
    """Read and check a protocol file (YAML or JSON)."""
    p = Path(path)
    try:
        data = read_structured(p, "protocol file")
    except InputError as e:
        raise ProtocolError(str(e)) from None
    if not isinstance(data, dict):
        raise ProtocolError(f"{p}: expected a mapping with schema, name, layouts and steps")
    try:
        return Protocol.model_validate(data)
    except ValidationError as e:
        err = e.errors()[0]
        loc = ".".join(str(x) for x in err["loc"]) or "(file)"
        more = f" (and {len(e.errors()) - 1} more)" if len(e.errors()) > 1 else ""
        raise ProtocolError(f"{p}: {loc}: {err['msg']}{more}") from None


def default_protocol(quick: bool = False, frames: int | None = None) -> Protocol:
    """The thesis's protocol on renders: 2×3 dots 10 cm apart, one 6.5 cm 4×4 code, the
    two-code brick and the one-code brick with a tag36h11 code (AprilTag 3's own family; it
    reads the 4×4 codes too, given to it as a family)."""
    # quick: a first look in a few minutes (two frames, the ends and one middle per axis)
    n = frames or (2 if quick else 8)
    layouts = [LayoutRef(name="dots", layout="drick-dots-2x3"),
               LayoutRef(name="code", layout="drick-aruco-centre"),
               LayoutRef(name="two-codes", layout="drick-aruco-pyramids"),
               LayoutRef(name="code-36h11", layout="drick-aruco-centre",
                         dictionary="DICT_APRILTAG_36h11")]
    dist = [0.4, 1.2, 2.0] if quick else [0.3, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0]
    offs = [0.0, 0.5] if quick else [-0.6, -0.3, 0.0, 0.3, 0.6]
    rots = [0.0, 30.0] if quick else [0.0, 10.0, 20.0, 30.0, 40.0]
    rotz = [0.0, 90.0] if quick else [0.0, 45.0, 90.0, 135.0, 170.0]
    steps: list[Step] = []
    for lay in layouts:
        codes = lay.name != "dots"
        f = {k: v for k, v in (("offset", "6.6" if codes else "6.2"),
                               ("distance", "6.7" if codes else "6.3"),
                               ("rot", "6.8" if codes else "6.4"),
                               ("rot_z", "6.9" if codes else "6.5"))}
        steps += [Step(figure=f["distance"], layout=lay.name, vary="distance", value=d,
                       frames=n) for d in dist]
        for axis in ("offset_x", "offset_y"):
            steps += [Step(figure=f["offset"], layout=lay.name, vary=axis, value=o, frames=n)
                      for o in offs]
        for axis in ("rot_x", "rot_y"):
            steps += [Step(figure=f["rot"], layout=lay.name, vary=axis, value=a, frames=n)
                      for a in rots]
        steps += [Step(figure=f["rot_z"], layout=lay.name, vary="rot_z", value=a, frames=n)
                  for a in rotz]
    return Protocol.model_validate({"schema": PROTOCOL_SCHEMA, "name": "thesis chapter 6"
                                    + (" (quick)" if quick else ""),
                                    "layouts": [x.model_dump() for x in layouts],
                                    "steps": [s.model_dump() for s in steps]})
