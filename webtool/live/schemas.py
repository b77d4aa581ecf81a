"""The live view API's request bodies and response models (``/api/live``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import ConfigDict, Field

from webtool.schemas import Answer, Body, Json, SceneLink

__all__ = ["Bricks", "LiveScene", "LiveStatus", "TargetBody", "TargetSet"]


class TargetBody(Body):
    model_config = ConfigDict(extra="forbid")

    spec: Annotated[str, Field(min_length=1, max_length=200)]
    """``nearest``, ``LAYOUT``, ``LAYOUT:INSTANCE``, ``track:N`` or ``none``"""


class LiveStatus(Answer):
    """The pipeline's figures (fps, detect time, latency, bricks, source state…), the
    viewers, the stream rate, the 3D scene, and this request's access (full or viewer)."""

    running: bool
    error: str | None
    viewers: int
    bandwidth_kbps: float
    sample: bool | None
    stream_kbps: float
    access: str


class Bricks(Answer):
    """The bricks of the newest frame (poses, body frame, yaw, uncertainty, target)."""

    seq: int
    bricks: list[dict[str, Json]]


class TargetSet(Answer):
    target: dict[str, Json]
    """mode, layout, instance, track, spec"""


class LiveScene(SceneLink):
    """Where the live 3D view is (``/live/3d/``)."""
