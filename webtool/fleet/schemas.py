"""The Fleet API's response models (``/api/fleet``)."""

from __future__ import annotations

from webtool.schemas import Answer, Json

__all__ = ["DroneRow", "FleetStatus"]


class DroneRow(Answer):
    """One drone as the page lists it (:class:`drovisio.station.DroneStatus`)."""

    drone_id: str
    state: str
    fps: float
    latency_ms_p50: float | None
    latency_ms_p90: float | None
    frames: int
    bricks: int
    target: dict[str, Json] | None
    age_s: float | None
    has_image: bool
    info: dict[str, Json]


class FleetStatus(Answer):
    """Every drone heard, where the station listens, and when a drone counts as lost."""

    drones: list[DroneRow]
    listen: list[str]
    connect: list[str]
    lost_after_s: float
    error: str | None
