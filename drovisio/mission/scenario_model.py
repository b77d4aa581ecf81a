"""The mission scenario's schema: the fields of the file and the poses they plan.

Frames: the site frame of :mod:`drovisio.mission.frames` (x east, y north, z up, metres);
angles in files are degrees, radians in :class:`Pose4`. The rules beyond the schema are in
:mod:`drovisio.mission.scenario_rules`, reading and validating in :mod:`drovisio.mission.scenario`.

Every number of the file has its range here, one type per kind of quantity (a site
coordinate, a flight height, a speed, a timeout...): a number out of it, or not finite, is
refused naming the field and the range (:func:`drovisio.bounds.parse_number`); every list has
its longest length (:data:`MAX_BRICKS` bricks).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from drovisio.bounds import CAMERA_TILT_MAX_DEG, MOUNT_OFFSET_MAX_M, parse_number, parse_whole
from drovisio.errors import InputError
from drovisio.mission.frames import rot2

__all__ = ["SCHEMA_ID", "MAX_BRICKS", "MAX_FILE_BYTES", "MAX_LAYOUTS", "ScenarioError", "Pose4",
           "ScenarioModel", "Bounds", "Zone", "Area", "Site", "PickPose", "Brick", "PlanEntry",
           "Wall", "Thresholds", "Altitudes", "Tolerance", "Mount", "CameraSpec", "Drone",
           "Autopilot", "Sensors"]

SCHEMA_ID = "drovisio/mission-scenario@1"

MAX_BRICKS = 200
"""Most bricks a scenario holds (its inventory, its plan): far more than a drone builds in a
day of flights, and ``mission check`` simulates the whole mission once per fault case."""

MAX_FILE_BYTES = 1024 * 1024
"""Largest scenario file read: ten times a scenario of :data:`MAX_BRICKS` bricks written out
in full (reading YAML takes seconds a megabyte)."""

MAX_LAYOUTS = 16
"""Most layouts a scenario names (each is a file to read)."""


def _num(lo: float, hi: float, unit: str = "", above: bool = False) -> Callable[[float], float]:
    """A field's check: a finite number in ``[lo, hi]`` (``above``: ``lo`` excluded)."""
    def check(v: float) -> float:
        return parse_number(v, lo, hi, above=above, unit=unit)
    return check


def _whole(lo: int, hi: int) -> Callable[[int], int]:
    """A field's check: a whole number in ``lo..hi``."""
    def check(v: int) -> int:
        return parse_whole(v, lo, hi)
    return check


# The ranges, one per kind of quantity: physically sane, far beyond any real site or drone.
Coord = Annotated[float, AfterValidator(_num(-10_000.0, 10_000.0, "m"))]
"""A site-frame coordinate, metres: within 10 km of the site benchmark."""
Extent = Annotated[float, AfterValidator(_num(0.0, 10_000.0, "m", above=True))]
"""A size or radius on the site, metres."""
Height = Annotated[float, AfterValidator(_num(0.0, 120.0, "m", above=True))]
"""A flight height, metres (120 m: the usual legal ceiling of small drones)."""
Length = Annotated[float, AfterValidator(_num(0.0, 10.0, "m", above=True))]
"""A length on the drone or the wall, or a distance it tolerates, metres."""
Tol = Annotated[float, AfterValidator(_num(0.0, 1.0, "m", above=True))]
"""A position tolerance, metres."""
TolDeg = Annotated[float, AfterValidator(_num(0.0, 90.0, "degrees", above=True))]
"""An angle tolerance, degrees."""
Angle = Annotated[float, AfterValidator(_num(-360.0, 360.0, "degrees"))]
"""A heading or a direction, degrees."""
Speed = Annotated[float, AfterValidator(_num(0.01, 5.0, "m/s"))]
"""A vertical speed, metres a second."""
Seconds = Annotated[float, AfterValidator(_num(0.0, 600.0, "s", above=True))]
"""A wait or timeout, seconds (ten minutes: longer than a battery lasts hovering)."""
Frames = Annotated[int, AfterValidator(_whole(1, 1000))]
"""A count of vision frames."""
Offset = Annotated[float, AfterValidator(_num(-MOUNT_OFFSET_MAX_M, MOUNT_OFFSET_MAX_M, "m"))]
"""One coordinate of the camera's offset from the body origin (the mount file's bound)."""
Tilt = Annotated[float, AfterValidator(_num(-CAMERA_TILT_MAX_DEG, CAMERA_TILT_MAX_DEG, "degrees"))]
"""The camera's tilt from straight down, degrees."""
Ms = Annotated[float, AfterValidator(_num(0.0, 1000.0, "ms"))]
"""A delay, milliseconds."""
Rate = Annotated[float, AfterValidator(_num(0.1, 120.0, "Hz"))]
"""Frames a second."""
Chance = Annotated[float, AfterValidator(_num(0.0, 1.0, above=True))]
"""A probability above 0."""
Wind = Annotated[float, AfterValidator(_num(0.0, 20.0, "m/s"))]
"""A wind speed, metres a second (20: no small drone flies in more)."""
Grace = Annotated[float, AfterValidator(_num(0.0, 60.0, "s"))]
"""A gap ridden through, seconds (0: none)."""
AttemptSeconds = Annotated[float, AfterValidator(_num(0.0, 3600.0, "s", above=True))]
"""The longest time of one attempt of a phase, seconds."""
Retries = Annotated[int, AfterValidator(_whole(1, 10))]
"""Failures of a phase before the safe zone."""
Instance = Annotated[int, AfterValidator(_whole(0, 100_000))]
"""A layout's instance number (its code ids)."""
Course = Annotated[int, AfterValidator(_whole(1, 100))]
"""A course of the wall, 1 at the bottom."""
Slot = Annotated[int, AfterValidator(_whole(0, 10_000))]
"""A slot along the wall, 0 at its origin."""

Vec2 = Annotated[list[Coord], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[Coord], Field(min_length=3, max_length=3)]
Size2 = Annotated[list[Extent], Field(min_length=2, max_length=2)]
Name = Annotated[str, Field(min_length=1, max_length=200)]


class ScenarioError(InputError):
    """A scenario that cannot be flown; the message names the file, the field and the fix."""


@dataclass(frozen=True)
class Pose4:
    """A level pose in the site frame: position of the brick's top-face centre (or the drone's
    body origin) and yaw (radians, from east, counter-clockwise)."""

    x: float
    y: float
    z: float
    yaw: float

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y])

    @property
    def xyz(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z])


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Bounds(_M):
    min: Vec3 = Field(description="lowest corner of the geofence (x, y, z), site frame, m")
    max: Vec3 = Field(description="highest corner of the geofence (x, y, z), site frame, m")

    @model_validator(mode="after")
    def _order(self) -> Bounds:
        for i, axis in enumerate("xyz"):
            if not self.min[i] < self.max[i]:
                raise ValueError(f"min.{axis} ({self.min[i]}) must be below max.{axis} "
                                 f"({self.max[i]})")
        return self

    def contains(self, p, margin: float = 0.0) -> bool:
        p = np.asarray(p, float)
        n = len(p)
        return bool(np.all(p >= np.asarray(self.min[:n]) + margin - 1e-9)
                    and np.all(p <= np.asarray(self.max[:n]) - margin + 1e-9))


class Zone(_M):
    center: Vec2 = Field(description="centre (x, y), site frame, m")
    radius: Extent = Field(description="radius, m")


class Area(_M):
    center: Vec2
    size: Size2 = Field(description="extent along x and y, m")


class Site(_M):
    frame: str = Field("x east, y north, z up, metres; origin at the site benchmark",
                       max_length=1000, description="free text: how the site frame was set out")
    bounds: Bounds
    home: Vec2 = Field(description="take-off and landing pad (x, y)")
    safe_zone: Zone
    pick_area: Area


class PickPose(_M):
    position: Vec2 = Field(description="where the brick lies (x, y), site frame")
    yaw_deg: Angle = 0.0


class Brick(_M):
    id: Name
    layout: str = Field(max_length=1024)
    instance: Instance | None = Field(None, description="instance k (code ids); null for dots")
    pick: PickPose


class PlanEntry(_M):
    brick: Name
    course: Course
    slot: Slot | None = Field(None, description="course 1: slot index along the wall")
    rests_on: list[Name] | None = Field(None, description="upper courses: the two bricks below")

    @model_validator(mode="after")
    def _one_of(self) -> PlanEntry:
        if self.course == 1 and (self.slot is None or self.rests_on is not None):
            raise ValueError("a course-1 brick needs 'slot' (its index along the wall) and no "
                             "'rests_on'")
        if self.course > 1 and (self.rests_on is None or self.slot is not None):
            raise ValueError(f"a course-{self.course} brick needs 'rests_on: [A, B]' (the two "
                             "bricks it straddles) and no 'slot'")
        if self.rests_on is not None and len(self.rests_on) != 2:
            raise ValueError(f"'rests_on' must name exactly two bricks (running bond), got "
                             f"{len(self.rests_on)}")
        return self


class Wall(_M):
    origin: Vec2 = Field(description="(x, y) of course 1 slot 0's top-face centre")
    direction_deg: Angle = Field(0.0, description="direction of the wall (slot 0 → 1), degrees "
                                                  "from east, counter-clockwise")
    brick_pitch_m: Length = Field(0.30, description="slot spacing along the wall")
    course_height_m: Length = Field(0.10, description="height of one course (stacking pitch)")
    plan: list[PlanEntry] = Field(min_length=1, max_length=MAX_BRICKS)
    order: list[Name] | None = Field(None, max_length=MAX_BRICKS,
                                     description="build order (default: plan order)")


class Thresholds(_M):
    align_yaw_tolerance_deg: TolDeg = Field(
        2.0, description="never descend onto a target while |yaw error| exceeds this")
    align_position_tolerance_m: Tol = Field(
        0.02, description="aligned when the horizontal error is below this")
    contact_position_tolerance_m: Tol = Field(
        0.01, description="grab or release only when the total station puts the body within "
                          "this of the target")
    contact_yaw_tolerance_deg: TolDeg = Field(
        0.5, description="grab or release only when the heading is this close to its setpoint")
    filter_frames: Frames = Field(8, description="vision frames averaged into a target's "
                                                  "estimate")
    descent_position_tolerance_m: Tol = Field(
        0.05, description="stop descending and realign when the horizontal error exceeds this")
    disagreement_m: Length = Field(
        0.15, description="total station vs vision position: beyond this the drone goes to the "
                          "safe zone")
    disagreement_frames: Frames = Field(3, description="consecutive frames that must disagree")
    retries: Retries = Field(3, description="failures of a phase that send the drone to the "
                                            "safe zone (thesis: 3)")
    match_radius_m: Length = Field(0.25, description="a brick without id is the one seen within "
                                                     "this of where it is expected")
    settle_frames: Frames = Field(3, description="vision frames a condition must hold")
    ts_grace_s: Grace = Field(0.5, description="total-station gap ridden through")
    ts_wait_s: Seconds = Field(10.0, description="longest wait for the total station in a retry")
    vision_timeout_s: Seconds = Field(0.8, description="no sighting for this long = vision lost")
    acquire_timeout_s: Seconds = Field(5.0)
    align_timeout_s: Seconds = Field(20.0)
    verify_timeout_s: Seconds = Field(5.0)
    contact_timeout_s: Seconds = Field(15.0, description="blind descent: longest wait for a "
                                                         "steady contact on target")
    grab_time_s: Seconds = Field(0.6, description="picker close/open time before reading it")
    attempt_timeout_s: AttemptSeconds = Field(90.0, description="longest time for one attempt "
                                                                "of a phase")


class Altitudes(_M):
    cruise_m: Height = Field(1.6, description="transit height (thesis: above 1 m)")
    approach_m: Height = Field(1.2, description="body above the target's top face while "
                                                "acquiring and aligning (thesis: 1–2 m)")
    blind_below_m: Length = Field(0.30, description="camera height above the target's top at "
                                                    "which the last part of the descent is blind")
    descent_speed_mps: Speed = Field(0.25)
    blind_speed_mps: Speed = Field(0.12)


class Tolerance(_M):
    position_m: Tol = 0.05
    yaw_deg: TolDeg = 3.0


class Mount(_M):
    offset_m: Annotated[list[Offset], Field(min_length=3, max_length=3)] = Field(
        [0.08, 0.0, 0.05], description="camera centre in the FRD body frame")
    tilt_deg: Tilt = Field(0.0, description="forward tilt from straight down")


class CameraSpec(_M):
    model: Literal["drone-webcam"] | None = "drone-webcam"
    file: str | None = Field(None, max_length=1024,
                             description="camera file instead of the built-in model "
                                         "(relative to the scenario, or absolute)")
    mount: Mount = Mount()


class Drone(_M):
    picker_depth_m: Length = Field(0.15, description="body origin to the held brick's top face")
    gear_height_m: Length = Field(0.20, description="body origin above the ground, landed")
    camera: CameraSpec = CameraSpec()


class Autopilot(_M):
    """What feeds the autopilot's precision landing, and whether the simulator models it."""

    precision_landing: bool = Field(
        False, description="the pick descents are flown by ArduPilot's precision landing fed by "
                           "the vision (lag buffer, 2 s initialisation, 2 s timeout, last "
                           "estimate once the brick leaves the picture); off: the autopilot "
                           "flies the mission's setpoints")
    rate_hz: Rate | None = Field(None, description="frames the pipeline processes a second "
                                                   "(default: 10)")
    detect_prob: Chance | None = Field(None, description="chance a frame showing the brick "
                                                         "detects it (default: 0.97)")
    latency_ms: Ms = Field(50.0, description="capture to LANDING_TARGET at the autopilot")
    plnd_lag_ms: Ms | None = Field(None, description="PLND_LAG (default: the latency)")
    wind_mps: Wind = Field(0.0, description="steady wind (its gusts move the drone; the steady "
                                            "part is held by the autopilot)")


class Sensors(_M):
    total_station: bool = True
    vision: bool = True
    picker: bool = True
    slot_selection: Literal["auto", "by_id", "by_position"] = Field(
        "auto", description="how the bricks below are recognised: by code id, or by position "
                            "(dots have no ids; the thesis counted bricks along the wall)")


class ScenarioModel(_M):
    """A scenario's fields and what follows from them (the planned poses, the references);
    :class:`drovisio.mission.scenario.Scenario` is the scenario, validated."""

    schema_: Literal["drovisio/mission-scenario@1"] = Field(alias="schema")
    name: Name
    description: str = Field("", max_length=10_000)
    site: Site
    layouts: list[Annotated[str, Field(max_length=1024)]] = Field(
        min_length=1, max_length=MAX_LAYOUTS, description="shipped layout names or .json paths")
    bricks: list[Brick] = Field(min_length=1, max_length=MAX_BRICKS)
    wall: Wall
    thresholds: Thresholds = Thresholds()
    altitudes: Altitudes = Altitudes()
    placement_tolerance: Tolerance = Tolerance()
    drone: Drone = Drone()
    sensors: Sensors = Sensors()
    autopilot: Autopilot = Autopilot()

    _source: Path | None = PrivateAttr(None)
    _layouts: dict[str, Any] = PrivateAttr(default_factory=dict)

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    # ------------------------------------------------------------------ derived quantities
    @property
    def source(self) -> Path | None:
        return self._source

    @cached_property
    def brick_by_id(self) -> dict[str, Brick]:
        return {b.id: b for b in self.bricks}

    @cached_property
    def plan_by_id(self) -> dict[str, PlanEntry]:
        return {e.brick: e for e in self.wall.plan}

    @property
    def order(self) -> list[str]:
        return list(self.wall.order) if self.wall.order else [e.brick for e in self.wall.plan]

    @property
    def wall_yaw(self) -> float:
        return math.radians(self.wall.direction_deg)

    def layout(self, name: str):
        """The loaded :class:`~drovisio.layout.MarkerLayout` called ``name``."""
        return self._layouts[name]

    def layout_of(self, brick_id: str):
        return self._layouts[self.brick_by_id[brick_id].layout]

    def has_ids(self, brick_id: str) -> bool:
        lay = self.layout_of(brick_id)
        mode = self.sensors.slot_selection
        if mode == "by_position":
            return False
        return bool(lay.has_codes) and self.brick_by_id[brick_id].instance is not None

    def pick_pose(self, brick_id: str) -> Pose4:
        b = self.brick_by_id[brick_id]
        return Pose4(b.pick.position[0], b.pick.position[1], self.wall.course_height_m,
                     math.radians(b.pick.yaw_deg))

    def slot_pose(self, brick_id: str) -> Pose4:
        """Planned pose of a brick in the wall (top-face centre, yaw), site frame."""
        return self._slot_poses[brick_id]

    @cached_property
    def _slot_poses(self) -> dict[str, Pose4]:
        out: dict[str, Pose4] = {}
        w = self.wall
        d = np.array([math.cos(self.wall_yaw), math.sin(self.wall_yaw)])
        # PlanEntry's validator: course 1 has a slot, the upper courses rest on two bricks
        for e in sorted(w.plan, key=lambda e: e.course):
            if e.course == 1:
                assert e.slot is not None
                xy = np.asarray(w.origin) + e.slot * w.brick_pitch_m * d
                out[e.brick] = Pose4(float(xy[0]), float(xy[1]), w.course_height_m,
                                     self.wall_yaw)
            else:
                assert e.rests_on is not None
                a, b = out[e.rests_on[0]], out[e.rests_on[1]]
                out[e.brick] = Pose4((a.x + b.x) / 2, (a.y + b.y) / 2,
                                     e.course * w.course_height_m, self.wall_yaw)
        return out

    def supports(self, brick_id: str) -> list[str]:
        """Bricks the brick rests on (none for course 1)."""
        e = self.plan_by_id[brick_id]
        return list(e.rests_on or [])

    def references(self, brick_id: str) -> list[str]:
        """Placed bricks vision uses to find the slot: the two below, or course 1's neighbours
        placed before it."""
        e = self.plan_by_id[brick_id]
        if e.rests_on:
            return list(e.rests_on)
        order = self.order
        before = set(order[:order.index(brick_id)])
        slot = e.slot
        assert slot is not None  # PlanEntry's validator: a brick without rests_on has a slot
        return [o.brick for o in self.wall.plan
                if o.course == 1 and o.brick in before and o.slot is not None
                and abs(o.slot - slot) == 1]

    def wall_top_m(self) -> float:
        return max(e.course for e in self.wall.plan) * self.wall.course_height_m

    def brick_height_m(self, brick_id: str) -> float:
        return float(self.layout_of(brick_id).dimensions_m[2])

    def ref_from_slot(self, ref_id: str, brick_id: str) -> Pose4:
        """Planned pose of ``brick_id``'s slot in the frame of ``ref_id`` (planned)."""
        r, s = self.slot_pose(ref_id), self.slot_pose(brick_id)
        dxy = rot2(-r.yaw) @ (s.xy - r.xy)
        return Pose4(float(dxy[0]), float(dxy[1]), s.z - r.z, s.yaw - r.yaw)
