"""The mission replay API's request bodies and response models (``/api/replay``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from webtool.schemas import Answer, Body, Json, SceneLink

__all__ = ["LoadBody", "ReplayRuns", "ReplayScene", "ReplayState", "SeekBody", "SpeedBody"]


class LoadBody(Body):
    name: Annotated[str, Field(min_length=1, max_length=255)] | None = None
    path: Annotated[str, Field(min_length=1, max_length=4096)] | None = None


class SeekBody(Body):
    t: Annotated[float, Field(ge=0)]      # seconds; past the end means the end


class SpeedBody(Body):
    x: Annotated[float, Field(ge=0.05, le=64)]


class ReplayRuns(Answer):
    """The recordings of the replay folder (name, path, scenario, duration, outcome, bricks,
    or why one cannot be read)."""

    folder: str
    runs: list[dict[str, Json]]


class ReplayState(Answer):
    """The playback: ``loaded`` alone when nothing is; else the recording, the time (s), the
    drone, the setpoint, the events so far and the bricks placed."""

    loaded: bool


class ReplayScene(SceneLink):
    """Where the replay's 3D view is (``/replay/3d/``)."""

    clients: int
    updates: int
