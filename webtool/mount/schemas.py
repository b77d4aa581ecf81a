"""The camera mount API's request bodies and response models (``/api/mount``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from drovisio.mount import MountAngles
from webtool.schemas import Answer, Body, Json, SceneLink

__all__ = ["LiveBody", "MountMeasured", "MountScene", "MountState", "PreviewBody"]


class PreviewBody(Body):
    angles: MountAngles
    height_m: Annotated[float, Field(gt=0.05, le=100)] = 1.5   # metres above flat ground


class LiveBody(Body):
    aligned: bool = False


class MountState(Answer):
    """The mount (angles in degrees, offset in metres; FRD body frame), its matrix, the ground
    in view at the preview height, when each layout leaves the picture, the file."""

    angles: dict[str, Json]
    height_m: float
    body_from_camera: list[list[float]]
    footprint: Json
    blind: list[dict[str, Json]]
    file: str
    loaded_from: str | None
    saved: bool
    camera: dict[str, Json]


class MountMeasured(Answer):
    """The angles measured from pictures of a code lying flat (the drone level)."""

    proposed: dict[str, Json]
    pictures: int
    spread_deg: float
    pan_measured: bool
    pan_refused: Json
    lines: list[Json]


class MountScene(SceneLink):
    """Where the mount's 3D preview is (``/mount/3d/``)."""

    clients: int
    shown: Json
