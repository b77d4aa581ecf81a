"""Recording of a simulated mission, in a form a 3D page can replay.

``drovisio mission simulate SCENARIO --record DIR`` writes three files into ``DIR``:

``manifest.json``
    ``{"schema": "drovisio/mission-recording@1", "scenario": NAME, "scenario_file":
    "scenario.yaml", "ticks_file": "ticks.jsonl", "frame": "site: x east, y north, z up,
    metres", "quaternion_order": "wxyz", "dt": 0.05, "ticks": N, "duration_s": T,
    "outcome": "DONE" | "SHUTDOWN" | ..., "vision": "model" | "render", "detector": ...,
    "site": {"bounds", "home", "safe_zone", "pick_area"}, "layouts": {NAME: {"dimensions":
    [l, w, h], "mesh": "marker_layouts/meshes/drick.stl"}}, "bricks": [{"id", "layout",
    "instance", "plan": POSE, "pick": POSE}], "camera": {"width", "height", "K",
    "body_from_camera"}, "states": [...], "transitions": [{"source", "trigger", "target"}],
    "placements": {ID: {"error_m", "yaw_error_deg", ...}}, "faults": [...]}``

    where a POSE is ``{"position": [x, y, z], "yaw": rad, "quat_wxyz": [w, x, y, z]}`` — for a
    brick the centre of its top face, for the drone its body origin.

``ticks.jsonl``
    one JSON object per recorded tick (every ``every``-th simulator tick; events of the
    skipped ticks are carried into the next recorded one), in time order::

        {"t": 12.35, "state": "ALIGN_BRICK",
         "drone": {"position": [x, y, z], "yaw": rad, "quat_wxyz": [w, x, y, z]},
         "setpoint": {"position": [x, y, z], "yaw": rad} | null,
         "picker": "open" | "closed", "holding": "b3" | null,
         "ts": [x, y, z] | null, "vision": ["drick-aruco-pyramids#2", ...] | null,
         "events": [{"t": ..., "kind": "transition", "source": ..., "target": ...,
                     "trigger": ...}, ...],
         "bricks": {"b1": [x, y, z, yaw], ...}}

    The drone's quaternion is that of ``site_from_body`` for the FRD body (so a viewer that
    draws the body's +x as its nose needs no extra turn); a brick's pose is its top-face centre
    and yaw (level bricks; quaternion = rotation ``yaw`` about +z).

``scenario.yaml``
    a copy of the scenario that was flown.

:func:`load_recording` reads a recording back (manifest, list of ticks).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drovisio.errors import InputError
from drovisio.fileio import atomic_write_text
from drovisio.geometry import quat_wxyz
from drovisio.mission.frames import site_from_body
from drovisio.mission.machine import TRANSITIONS, State
from drovisio.mission.scenario import Scenario
from drovisio.mission.sim import Trace, body_from_camera_for, camera_for
from drovisio.textfile import parse_json, read_inside, read_text

__all__ = ["SCHEMA_ID", "write_recording", "load_recording"]

SCHEMA_ID = "drovisio/mission-recording@1"


def _r(v: Any, nd: int = 4) -> list[float]:
    return [round(float(x), nd) for x in v]


def _pose(position: Any, yaw: float, body: bool = False) -> dict[str, Any]:
    if body:
        R = site_from_body(position, yaw)[:3, :3]
    else:
        c, s = math.cos(yaw), math.sin(yaw)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return {"position": _r(position), "yaw": round(float(yaw), 5),
            "quat_wxyz": [round(q, 6) for q in quat_wxyz(R)]}


def _tick_lines(trace: Trace, every: int) -> list[str]:
    """One JSON line every ``every`` ticks, on every transition and at the end; a line
    carries the events since the line before."""
    lines = []
    pending: list[dict[str, Any]] = []
    n = len(trace.ticks)
    for i, tk in enumerate(trace.ticks):
        pending.extend(tk.events)
        if i % every and i != n - 1 and not any(e["kind"] == "transition" for e in tk.events):
            continue
        lines.append(json.dumps({
            "t": round(tk.t, 3), "state": tk.state,
            "drone": _pose(tk.position, tk.yaw, body=True),
            "setpoint": tk.setpoint, "picker": tk.picker, "holding": tk.holding,
            "ts": _r(tk.ts) if tk.ts is not None else None, "vision": tk.vision,
            "events": pending,
            "bricks": {b: _r(p[:3]) + [round(p[3], 5)] for b, p in tk.bricks.items()},
        }, separators=(",", ":")))
        pending = []
    return lines


def _scenario_text(scn: Scenario) -> str:
    """The scenario file as written, else the scenario dumped."""
    if scn.source is not None and Path(scn.source).is_file():
        return read_text(scn.source, "scenario")
    return yaml.safe_dump(scn.model_dump(by_alias=True), sort_keys=False)


def _layouts(scn: Scenario) -> dict[str, dict[str, Any]]:
    layouts = {}
    for name in scn.layouts:
        lay = scn.layout(name)
        mesh = lay.mesh_path()
        layouts[name] = {"dimensions": _r(lay.dimensions_m),
                         "mesh": (f"marker_layouts/{lay.mesh}" if lay.mesh else None),
                         "mesh_exists": bool(mesh and mesh.exists())}
    return layouts


def _manifest(trace: Trace, every: int, n_lines: int) -> dict[str, Any]:
    scn = trace.scenario
    cam = camera_for(scn)
    site = scn.site
    return {
        "schema": SCHEMA_ID,
        "scenario": scn.name,
        "scenario_file": "scenario.yaml",
        "ticks_file": "ticks.jsonl",
        "frame": "site: x east, y north, z up, metres; yaw from east, counter-clockwise",
        "body_frame": "FRD (x forward, y right, z down)",
        "quaternion_order": "wxyz",
        "dt": trace.params.dt,
        "record_every": every,
        "ticks": n_lines,
        "duration_s": round(trace.ticks[-1].t, 3) if trace.ticks else 0.0,
        "outcome": trace.final_state,
        "vision": trace.params.vision,
        "detector": trace.detector,
        "seed": trace.params.seed,
        "site": {"bounds": site.bounds.model_dump(), "home": site.home,
                 "safe_zone": site.safe_zone.model_dump(),
                 "pick_area": site.pick_area.model_dump()},
        "layouts": _layouts(scn),
        "bricks": [{"id": b.id, "layout": b.layout, "instance": b.instance,
                    "plan": _pose(scn.slot_pose(b.id).xyz, scn.slot_pose(b.id).yaw),
                    "pick": _pose(scn.pick_pose(b.id).xyz, scn.pick_pose(b.id).yaw)}
                   for b in scn.bricks],
        "camera": {"width": cam.width, "height": cam.height, "K": cam.K.tolist(),
                   "dist": cam.dist.tolist(),
                   "body_from_camera": body_from_camera_for(scn).tolist()},
        "states": [s.value for s in State],
        "transitions": [{"source": t.source.value, "trigger": t.trigger,
                         "target": t.target.value} for t in TRANSITIONS],
        "placements": trace.placements,
        "faults": [f.describe() for f in trace.faults],
    }


def write_recording(trace: Trace, out_dir: str | Path, every: int = 2,
                    extra: dict[str, Any] | None = None) -> Path:
    """Write ``manifest.json``, ``ticks.jsonl`` and ``scenario.yaml`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lines = _tick_lines(trace, every)
    # every file beside, checked, renamed: a full disk keeps an older run whole
    atomic_write_text(out / "ticks.jsonl", "\n".join(lines) + "\n")
    atomic_write_text(out / "scenario.yaml", _scenario_text(trace.scenario))
    manifest = {**_manifest(trace, every, len(lines)), **(extra or {})}
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=1))
    return out


MAX_TICKS_BYTES = 256 * 1024 * 1024
"""Largest ticks file read (a 20-minute mission recorded every tick is ~30 MB)."""


def load_manifest(path: str | Path) -> dict:
    """The manifest of a recording folder, read through the bounded reader and checked.

    Raises:
        InputError: one line naming the file and the field.
    """
    mf = Path(path) / "manifest.json"
    manifest = parse_json(read_text(mf, "recording manifest"), str(mf))
    if not isinstance(manifest, dict):
        raise InputError(f"{mf}: not a recording manifest (a JSON object)")
    if manifest.get("schema") != SCHEMA_ID:
        raise InputError(f"{mf}: schema: expected {SCHEMA_ID!r}")
    for key in ("duration_s",):
        v = manifest.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not math.isfinite(v) or v < 0):
            raise InputError(f"{mf}: {key}: give a finite number of seconds, 0 or more")
    return manifest


def load_recording(path: str | Path) -> tuple[dict, list[dict]]:
    """(manifest, ticks) of a recording folder. The ticks file the manifest names is read
    through :func:`drovisio.textfile.read_inside` (a regular file inside the folder, its size
    bounded: never ``/dev/zero``, a FIFO or ``../../etc/passwd``), every tick checked.

    Raises:
        InputError: one line naming the file and the field.
    """
    p = Path(path)
    manifest = load_manifest(p)
    where = f"{p / 'manifest.json'}: ticks_file"
    text = read_inside(p, manifest.get("ticks_file"), where, "ticks file", MAX_TICKS_BYTES)
    tf = p / str(manifest["ticks_file"])
    ticks = []
    last = -math.inf
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        tk = parse_json(line, f"{tf}: line {n}")
        t = tk.get("t") if isinstance(tk, dict) else None
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise InputError(f"{tf}: line {n}: t: give the tick's time, a finite number of "
                             "seconds")
        if t < last:
            raise InputError(f"{tf}: line {n}: t: {t} is before the previous tick's {last}; "
                             "ticks must be in time order")
        last = t
        events = tk.get("events", [])
        if not isinstance(events, list) or not all(isinstance(e, dict) for e in events) \
                or not isinstance(tk.get("bricks", {}), dict):
            raise InputError(f"{tf}: line {n}: events must be a list and bricks an object")
        if not isinstance(tk.get("state"), str) or not isinstance(tk.get("drone"), dict):
            raise InputError(f"{tf}: line {n}: give the tick's state (text) and drone (an "
                             "object)")
        ticks.append(tk)
    if not ticks:
        raise InputError(f"{tf}: the recording has no ticks")
    return manifest, ticks
