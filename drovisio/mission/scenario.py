"""The mission scenario file: the single source of truth of a pick-and-place mission.

The thesis (ch. 8.3) asks that "the scenario can be completely encoded before the flight in
order to know if the behaviour of the drone corresponds to the expectations". A scenario is a
YAML (or JSON) file with ``schema: drovisio/mission-scenario@1`` that says:

* ``site``: the geofence (``bounds``), the take-off pad (``home``), the ``safe_zone`` (where
  the drone lands and shuts down after three failures or a sensor disagreement) and the
  ``pick_area``;
* ``layouts`` and ``bricks``: the inventory — each brick's layout, instance (its code ids) and
  pick pose;
* ``wall``: the plan — course-1 bricks by slot along the wall, upper bricks ``rests_on`` the pair
  of bricks below them (running bond), built in ``order``;
* ``thresholds``, ``altitudes``, ``placement_tolerance``: alignment tolerances, the
  disagreement threshold, ``retries`` (failures of a phase before the safe zone), timings;
* ``drone`` (picker geometry, camera and mount) and ``sensors`` (what is in use);
* ``autopilot``: whether the pick descents are flown by ArduPilot's precision landing (off by
  default) and what feeds it: detection rate and chance, latency, ``PLND_LAG``, wind.

Frames: the site frame of :mod:`drovisio.mission.frames` (x east, y north, z up, metres);
angles in files are degrees. Every problem is reported as a :class:`ScenarioError` naming the
file and the field (``wall.plan[6].rests_on``), with what was expected.

Use::

    scn = load_scenario("drovisio/mission/scenarios/wall-2-courses.yaml")
    scn.order                    # build order, brick ids
    scn.slot_pose("b6")          # (x, y, z_top, yaw) planned in the site frame

The schema's fields and the poses they plan are in :mod:`drovisio.mission.scenario_model`, the
rules beyond the schema in :mod:`drovisio.mission.scenario_rules`; this module reads and
validates (and re-exports the schema's names).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from pydantic import PrivateAttr, ValidationError

from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.errors import InputError, one_line
from drovisio.layout import LayoutError, check_layout_set, load_layout, shipped_layout_file
from drovisio.mission.frames import wrap_half
from drovisio.mission.scenario_model import (
    MAX_FILE_BYTES,
    SCHEMA_ID,
    Altitudes,
    Area,
    Autopilot,
    Bounds,
    Brick,
    CameraSpec,
    Drone,
    Mount,
    PickPose,
    PlanEntry,
    Pose4,
    ScenarioError,
    ScenarioModel,
    Sensors,
    Site,
    Thresholds,
    Tolerance,
    Wall,
    Zone,
)
from drovisio.mission.scenario_rules import semantic_issues
from drovisio.resources import scenarios_dir
from drovisio.textfile import parse_yaml, read_text

__all__ = ["SCHEMA_ID", "Scenario", "ScenarioError", "Pose4", "load_scenario", "parse_scenario",
           "shipped_scenarios_dir", "shipped_scenario", "Altitudes", "Area", "Autopilot",
           "Bounds", "Brick", "CameraSpec", "Drone", "Mount", "PickPose", "PlanEntry", "Sensors",
           "Site", "Thresholds", "Tolerance", "Wall", "Zone"]


class Scenario(ScenarioModel):
    """A validated mission scenario (see the module docstring; fields and planned poses in
    :class:`~drovisio.mission.scenario_model.ScenarioModel`)."""

    _camera: Camera | None = PrivateAttr(None)

    @property
    def camera(self) -> Camera:
        """The drone's camera: the camera file ``drone.camera.file`` names (read once, when
        the scenario is), else the built-in drone webcam."""
        if self._camera is None and self.drone.camera.file:
            base = self._source.parent if self._source is not None else None
            self._camera = _load_camera(self.drone.camera.file, base,
                                        str(self._source or "<scenario>"))
        return self._camera if self._camera is not None else Camera.drone_webcam()

    def subset(self, keep: list[str]) -> Scenario:
        """The same scenario building only the bricks ``keep`` (validated again: the bricks a
        kept brick rests on must be kept too)."""
        data = self.model_dump(by_alias=True, exclude_none=True)
        w = data["wall"]
        w["plan"] = [e for e in w["plan"] if e["brick"] in keep]
        w["order"] = [b for b in self.order if b in keep]
        data["bricks"] = [b for b in data["bricks"] if b["id"] in keep]
        src = str(self._source) if self._source is not None else "<scenario>"
        return parse_scenario(data, src)

    # ------------------------------------------------------------------ semantic checks
    def _semantic_issues(self) -> list[tuple[str, str]]:
        """The rules beyond the schema (:mod:`drovisio.mission.scenario_rules`)."""
        return semantic_issues(self)


def _format_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def shipped_scenarios_dir() -> Path:
    """``drovisio/mission/scenarios/`` (package data)."""
    return scenarios_dir()


def shipped_scenario(name: str = "wall-2-courses") -> Path:
    return shipped_scenarios_dir() / f"{name}.yaml"


def _in_scenario(name: str, base: Path | None) -> Path:
    """A file a scenario names: relative to the scenario's folder, or absolute (scenarios are
    read by the local command line only, like any file given on it)."""
    p = Path(name)
    return p if p.is_absolute() or base is None else base / p


def _load_camera(name: str, base: Path | None, src: str) -> Camera:
    """The camera file ``drone.camera.file`` names, read by the camera file reader.

    Raises:
        ScenarioError: ``SCENARIO: drone.camera.file: the reader's one line``.
    """
    try:
        return load_camera(_in_scenario(name, base))
    except InputError as e:
        raise ScenarioError(f"{src}: drone.camera.file: {e}") from None


def _load_layouts(names: list[str], base: Path | None, src: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    problems = []
    for i, n in enumerate(names):
        if n.endswith(".json"):
            p = _in_scenario(n, base)
        else:
            try:   # a name, never a way out of the folder
                p = shipped_layout_file(n)
            except InputError as e:
                problems.append(f"{src}: layouts[{i}]: {e}")
                continue
        try:
            lay = load_layout(p)
        except LayoutError as e:
            problems.append(f"{src}: layouts[{i}]: {e}")
            continue
        if not n.endswith(".json") and lay.name != n:
            problems.append(f"{src}: layouts[{i}]: file {p} holds layout {lay.name!r}")
        out[n] = lay   # keyed as the scenario names it: bricks[].layout repeats that entry
    if problems:
        raise _problems(problems[0], len(problems) - 1)
    try:
        check_layout_set(list(out.values()))
    except LayoutError as e:
        raise ScenarioError(f"{src}: layouts: {e}") from None
    return out


def _parsed(data: dict[str, Any] | str | bytes, src: str) -> Any:
    """The scenario's data: YAML/JSON text parsed, a dict as it is."""
    if not isinstance(data, (str, bytes)):
        return data
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
        return parse_yaml(text, src)
    except UnicodeDecodeError as e:
        raise ScenarioError(f"{src}: not UTF-8 text (byte {e.start})") from None
    except InputError as e:
        raise ScenarioError(str(e)) from None


def _check_shape(data: Any, src: str) -> None:
    """One mapping of this schema, and no YAML ``on`` read as a boolean key in the plan."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{src}: a scenario file must hold one mapping, not "
                            f"{type(data).__name__}")
    if data.get("schema") != SCHEMA_ID:
        raise ScenarioError(f"{src}: schema: expected {SCHEMA_ID!r}, got {data.get('schema')!r}")
    plan = data.get("wall", {}).get("plan") if isinstance(data.get("wall"), dict) else None
    for i, entry in enumerate(plan if isinstance(plan, list) else []):
        if isinstance(entry, dict) and True in entry:
            raise ScenarioError(f"{src}: wall.plan[{i}]: a key reads as true: YAML takes a bare "
                                "'on' for a boolean; the field is 'rests_on'")


def _problems(first: str, more: int) -> ScenarioError:
    """A file's first problem in one line, and how many more there are (a file of thousands of
    problems is one short line)."""
    return ScenarioError(first + (f" (and {more} more problem{'s' if more > 1 else ''} in "
                                  "this file)" if more else ""))


def _schema_message(err: Any) -> str:
    """What is wrong with a field, as pydantic found it: a field's own check (a number out of
    its range) says it with the value; a list too long says its length and the most."""
    if err["type"] == "value_error":
        return str(err["msg"]).removeprefix("Value error, ")
    if err["type"] == "too_long" and isinstance(err.get("input"), list):
        ctx = err.get("ctx", {})
        return (f"{ctx.get('actual_length', len(err['input']))} entries; a scenario holds at "
                f"most {ctx.get('max_length')}")
    return str(err["msg"]) + (f" (got {one_line(repr(err['input']), 60)})"
                              if err["type"] != "missing"
                              and not isinstance(err.get("input"), (dict, list)) else "")


def _schema_error(e: ValidationError, src: str) -> ScenarioError:
    """The schema's first problem in one line (and how many more there are)."""
    errors = e.errors(include_url=False)
    first = errors[0]
    return _problems(f"{src}: {_format_loc(first['loc'])}: {_schema_message(first)}",
                     len(errors) - 1)


def parse_scenario(data: dict[str, Any] | str | bytes,
                   source: str | os.PathLike[str] = "<scenario>") -> Scenario:
    """Validate a scenario given as a dict or YAML/JSON text.

    Raises:
        ScenarioError: the first problem as ``FILE: FIELD: message``, and how many more.
    """
    src = os.fspath(source)
    data = _parsed(data, src)
    _check_shape(data, src)
    try:
        scn = Scenario.model_validate(data)
    except ValidationError as e:
        raise _schema_error(e, src) from None
    base = Path(src).parent if not src.startswith("<") else None
    scn._source = Path(src) if base is not None else None
    scn._layouts = _load_layouts(scn.layouts, base, src)
    if scn.drone.camera.file:
        scn._camera = _load_camera(scn.drone.camera.file, base, src)
    issues = scn._semantic_issues()
    if issues:
        loc, msg = issues[0]
        raise _problems(f"{src}: {loc}: {msg}", len(issues) - 1)
    return scn


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Read and validate a scenario file (YAML or JSON).

    Raises:
        ScenarioError: missing file, a file over :data:`MAX_FILE_BYTES`, bad syntax or an
            invalid field (the first, and how many more).
    """
    src = os.fspath(path)
    try:
        raw = read_text(path, "scenario file", MAX_FILE_BYTES)
    except InputError as e:
        raise ScenarioError(str(e)) from None
    return parse_scenario(raw, src)


def yaw_error(a: float, b: float) -> float:
    """Yaw difference of two half-turn-symmetric bricks, radians in [−π/2, π/2)."""
    return wrap_half(a - b)
