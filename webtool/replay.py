"""Replay of a simulated mission recording (:mod:`drovisio.mission.record`) in the live page.

:class:`ReplayService` lists the recordings in ``Settings.replay_dir`` (each a folder with a
``manifest.json``), loads one and plays it on a server-side thread: the playback clock ``t``
advances ``speed`` times real time, at ~15 Hz, and every step updates the replay's own viser
scene (:class:`ReplayScene`, served through the app at ``/replay/3d/``).

The scene is in the site frame (x east, y north, z up, metres): a ground grid, the wall plan as
ghost outlines, the drone (FRD body axes, a flat box and the camera frustum at
``body_from_camera``) at its recorded pose, its setpoint (a small orange ball), and each brick
as its layout's mesh at its recorded top-face pose (placed bricks turn green).
"""

from __future__ import annotations

import bisect
import json
import logging
import math
import threading
import time
from pathlib import Path

import numpy as np

from drovisio.geometry import quat_wxyz, yaw_quat_wxyz
from drovisio.mission.record import SCHEMA_ID, load_recording
from drovisio.resources import layouts_dir

__all__ = ["Playback", "ReplayError", "ReplayScene", "ReplayService"]

log = logging.getLogger(__name__)
BRICK_RGB = (60, 130, 220)
PLACED_RGB = (40, 160, 70)
HELD_RGB = (250, 200, 20)
GHOST_RGB = (150, 150, 150)
SETPOINT_RGB = (240, 140, 20)
SPEEDS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


class ReplayError(Exception):
    """A request the replay cannot do; ``status`` is the HTTP status to answer with."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def _describe(e: dict) -> str:
    """An event of a tick in plain words."""
    k = e.get("kind")
    b = e.get("brick")
    if k == "transition":
        return f"{e.get('source')} → {e.get('target')} ({e.get('trigger')})"
    if k == "placed":
        return f"brick {b} placed ({float(e.get('error_m', 0)) * 100:.1f} cm off)"
    if k == "grabbed":
        return f"brick {b} grabbed"
    if k == "released":
        return f"brick {b} released"
    if k == "acquired":
        return f"brick {b} seen ({e.get('frames')} frames)"
    if k == "aligned":
        return f"aligned over {b}"
    if k == "contact":
        return f"contact with {b}"
    if k == "blind":
        return f"blind descent onto {b}"
    rest = ", ".join(f"{a}={v}" for a, v in e.items() if a not in ("t", "kind"))
    return f"{k}" + (f": {rest}" if rest else "")


# ------------------------------------------------------------------------------------------
# The 3D scene
# ------------------------------------------------------------------------------------------


class ReplayScene:
    """A viser server (127.0.0.1, own port) showing one recording at one instant."""

    def __init__(self, host: str = "127.0.0.1"):
        self.host = host
        self.server = None
        self._lock = threading.Lock()
        self._bricks: dict[str, dict] = {}
        self._meshes: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        self._drone = None
        self._setpoint = None
        self.updates = 0

    @property
    def port(self) -> int | None:
        return None if self.server is None else int(self.server.get_port())

    def start(self) -> ReplayScene:
        with self._lock:
            if self.server is None:
                import viser

                self.server = viser.ViserServer(host=self.host, port=0, verbose=False,
                                                label="Drovisio replay")
                self.server.scene.set_up_direction("+z")
        return self

    def stop(self) -> None:
        with self._lock:
            if self.server is not None:
                try:
                    self.server.stop()
                finally:
                    self.server = None

    def clients(self) -> int:
        return 0 if self.server is None else len(self.server.get_clients())

    def _mesh(self, layout: str) -> tuple[np.ndarray, np.ndarray] | None:
        if layout not in self._meshes:
            mesh = None
            try:
                from drovisio.layout import load_layout
                from drovisio.meshes import load_layout_mesh

                f = layouts_dir() / f"{layout}.json"
                if f.is_file():
                    m = load_layout_mesh(load_layout(f))
                    if m is not None:
                        mesh = (np.asarray(m.vertices, np.float32),
                                np.asarray(m.faces, np.int32))
            except Exception:  # noqa: BLE001 - fall back to a box
                mesh = None
            self._meshes[layout] = mesh
        return self._meshes[layout]

    def _brick_node(self, name: str, layout: str, dims, color, **kw):
        sc = self.server.scene
        mesh = self._mesh(layout)
        if mesh is not None:
            return sc.add_mesh_simple(name, mesh[0], mesh[1], color=color, flat_shading=True, **kw)
        l, w, h = dims
        # a box whose top face is at the pose (like the layout frame of a drick)
        node = sc.add_frame(name, show_axes=False, **kw)
        sc.add_box(f"{name}/box", color=color, dimensions=(l, w, h), position=(0, 0, -h / 2))
        return node

    def load(self, manifest: dict) -> None:
        """Draw the static part of a recording (site, wall plan, drone, bricks)."""
        if self.server is None:
            return
        sc = self.server.scene
        with self._lock, self.server.atomic():
            sc.reset()
            self._bricks.clear()
            site = manifest.get("site") or {}
            lo, hi = (site.get("bounds") or {}).get("min"), (site.get("bounds") or {}).get("max")
            if lo and hi:
                w, h = hi[0] - lo[0], hi[1] - lo[1]
                sc.add_grid("/ground", width=w, height=h, plane="xy", cell_size=0.25,
                            section_size=1.0,
                            position=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0))
            else:
                sc.add_grid("/ground", width=8.0, height=8.0, plane="xy", cell_size=0.25)
            layouts = manifest.get("layouts") or {}
            for b in manifest.get("bricks", []):
                dims = (layouts.get(b["layout"]) or {}).get("dimensions") or [0.3, 0.15, 0.12]
                plan = b["plan"]
                mesh = self._mesh(b["layout"])
                if mesh is not None:
                    sc.add_mesh_simple(f"/plan/{b['id']}", mesh[0], mesh[1], color=GHOST_RGB,
                                       wireframe=True, opacity=0.35,
                                       position=tuple(plan["position"]),
                                       wxyz=yaw_quat_wxyz(plan["yaw"]))
                else:
                    sc.add_box(f"/plan/{b['id']}", color=GHOST_RGB, dimensions=tuple(dims),
                               wireframe=True, wxyz=yaw_quat_wxyz(plan["yaw"]),
                               position=tuple(np.asarray(plan["position"]) -
                                              [0, 0, dims[2] / 2]))
                pick = b["pick"]
                node = self._brick_node(f"/bricks/{b['id']}", b["layout"], dims, BRICK_RGB,
                                        position=tuple(pick["position"]),
                                        wxyz=yaw_quat_wxyz(pick["yaw"]))
                self._bricks[b["id"]] = {"node": node, "color": BRICK_RGB}
            self._drone = sc.add_frame("/drone", axes_length=0.25, axes_radius=0.01)
            sc.add_box("/drone/body", color=(70, 70, 70), dimensions=(0.35, 0.35, 0.06),
                       opacity=0.7)
            cam = manifest.get("camera") or {}
            T = np.asarray(cam.get("body_from_camera") or np.eye(4), float)
            fov, aspect = 1.0, 4 / 3
            if cam.get("K") and cam.get("height"):
                fov = 2 * math.atan2(cam["height"] / 2, cam["K"][1][1])
                aspect = cam["width"] / cam["height"]

            sc.add_camera_frustum("/drone/camera", fov=fov, aspect=aspect, scale=0.15,
                                  color=(20, 20, 20), wxyz=tuple(quat_wxyz(T[:3, :3])),
                                  position=tuple(T[:3, 3]))
            self._setpoint = sc.add_icosphere("/setpoint", radius=0.05, color=SETPOINT_RGB, opacity=0.8)
            self.server.initial_camera.position = (
                ((lo[0] + hi[0]) / 2 if lo else 1.0), (lo[1] - 3.0 if lo else -4.0), 5.0)
            self.server.initial_camera.look_at = (
                ((lo[0] + hi[0]) / 2 if lo else 1.0), ((lo[1] + hi[1]) / 2 if lo else 1.0), 0.5)
            self.server.initial_camera.up = (0.0, 0.0, 1.0)

    def show(self, tick: dict, placed: set[str]) -> None:
        """Move the drone, setpoint and bricks to a tick's poses."""
        if self.server is None or tick is None:
            return
        with self._lock, self.server.atomic():
            d = tick["drone"]
            drone = self._drone
            if drone is None:
                return
            drone.position = tuple(d["position"])
            drone.wxyz = tuple(d["quat_wxyz"])
            sp = tick.get("setpoint")
            sph = self._setpoint
            if sph is not None:
                sph.visible = sp is not None
                if sp is not None:
                    sph.position = tuple(sp["position"])
            for bid, p in (tick.get("bricks") or {}).items():
                nodes = self._bricks.get(bid)
                if nodes is None:
                    continue
                nodes["node"].position = tuple(p[:3])
                nodes["node"].wxyz = yaw_quat_wxyz(p[3])
                color = (HELD_RGB if tick.get("holding") == bid else
                         PLACED_RGB if bid in placed else BRICK_RGB)
                if color != nodes["color"] and hasattr(nodes["node"], "color"):
                    nodes["node"].color = color
                    nodes["color"] = color
        self.updates += 1


# ------------------------------------------------------------------------------------------
# Playback
# ------------------------------------------------------------------------------------------


class Playback:
    """One loaded recording and its clock (thread-safe; times in recording seconds)."""

    def __init__(self, path: Path, manifest: dict, ticks: list[dict]):
        if not ticks:
            raise ReplayError(f"{path}: the recording has no ticks", 422)
        self.path = path
        self.manifest = manifest
        self.ticks = ticks
        self.times = [float(tk["t"]) for tk in ticks]
        self.duration = float(manifest.get("duration_s") or self.times[-1])
        self.t = self.times[0]
        self.playing = False
        self.speed = 1.0

    def index(self, t: float | None = None) -> int:
        t = self.t if t is None else t
        return max(0, bisect.bisect_right(self.times, t + 1e-9) - 1)

    def tick(self) -> dict:
        return self.ticks[self.index()]

    def events_so_far(self, limit: int | None = None) -> list[dict]:
        i = self.index()
        out = [e for tk in self.ticks[: i + 1] for e in tk.get("events", [])]
        return out if limit is None else out[-limit:]

    def placed(self) -> list[str]:
        return sorted({e["brick"] for e in self.events_so_far() if e.get("kind") == "placed"})

    def advance(self, dt: float) -> None:
        if self.playing:
            self.t = min(self.duration, self.t + dt * self.speed)
            if self.t >= self.duration:
                self.playing = False


class ReplayService:
    """The app's replay: a folder of recordings, the loaded one, its playback thread."""

    def __init__(self, settings, hz: float = 15.0):
        self.settings = settings
        self.period = 1.0 / hz
        self.pb: Playback | None = None
        self.scene: ReplayScene | None = None
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._shown = -1

    # --------------------------------------------------------------- recordings
    def folder(self) -> Path:
        d = getattr(self.settings, "replay_dir", None)
        if d is None:
            raise ReplayError("no recordings folder is configured (replay_dir; "
                              "`drovisio serve --replay-dir DIR`)", 404)
        d = Path(d)
        if not d.is_dir():
            raise ReplayError(f"the recordings folder {d} does not exist", 404)
        return d

    def runs(self) -> list[dict]:
        d = self.folder()
        out = []
        for m in sorted(d.glob("*/manifest.json")) + sorted(d.glob("manifest.json")):
            item = {"name": m.parent.name if m.parent != d else ".", "path": str(m.parent)}
            try:
                js = json.loads(m.read_text())
                if js.get("schema") != SCHEMA_ID:
                    raise ValueError(f"schema is not {SCHEMA_ID}")
                item.update(scenario=js.get("scenario"), duration_s=js.get("duration_s"),
                            outcome=js.get("outcome"), bricks=len(js.get("bricks", [])),
                            ok=True)
            except (OSError, ValueError) as e:
                item.update(ok=False, error=str(e))
            out.append(item)
        return out

    def _resolve(self, name: str | None, path: str | None) -> Path:
        if path:
            p = Path(path)
            if not p.is_absolute():
                p = self.folder() / p
        elif name:
            d = self.folder()
            if "/" in name or "\\" in name or name == "..":
                raise ReplayError(f"bad recording name {name!r}", 422)
            p = d if name == "." else d / name
        else:
            raise ReplayError('give "name" (a recording in the folder) or "path"', 422)
        if not p.is_dir():
            raise ReplayError(f"no recording folder {p}", 404)
        if not (p / "manifest.json").is_file():
            raise ReplayError(f"{p} has no manifest.json: not a mission recording", 422)
        return p

    def load(self, name: str | None = None, path: str | None = None) -> dict:
        p = self._resolve(name, path)
        try:
            manifest, ticks = load_recording(p)
        except (ValueError, KeyError, OSError) as e:
            raise ReplayError(f"bad recording {p}: {e}", 422) from None
        pb = Playback(p, manifest, ticks)
        with self._lock:
            self.pb = pb
            self._shown = -1
            if self.scene is not None and self.scene.server is not None:
                self.scene.load(manifest)
        self._ensure_thread()
        self._wake.set()
        return self.state()

    def _need(self) -> Playback:
        if self.pb is None:
            raise ReplayError("no recording loaded", 409)
        return self.pb

    # --------------------------------------------------------------- controls
    def play(self) -> dict:
        with self._lock:
            pb = self._need()
            if pb.t >= pb.duration:
                pb.t = pb.times[0]
            pb.playing = True
        self._wake.set()
        return self.state()

    def pause(self) -> dict:
        with self._lock:
            self._need().playing = False
        return self.state()

    def seek(self, t: float) -> dict:
        with self._lock:
            pb = self._need()
            if not math.isfinite(t):
                raise ReplayError("t must be a number of seconds", 422)
            pb.t = min(max(float(t), 0.0), pb.duration)
        self._wake.set()
        return self.state()

    def set_speed(self, x: float) -> dict:
        if not (math.isfinite(x) and 0.05 <= x <= 64):
            raise ReplayError("speed must be between 0.05 and 64", 422)
        with self._lock:
            self._need().speed = float(x)
        return self.state()

    def state(self) -> dict:
        with self._lock:
            pb = self.pb
            if pb is None:
                return {"loaded": False}
            tk = pb.tick()
            ev = pb.events_so_far()
            return {
                "loaded": True, "name": pb.path.name, "path": str(pb.path),
                "scenario": pb.manifest.get("scenario"), "outcome": pb.manifest.get("outcome"),
                "t": round(pb.t, 3), "duration": pb.duration, "playing": pb.playing,
                "speed": pb.speed, "state": tk["state"], "tick_t": tk["t"],
                "drone": tk["drone"], "setpoint": tk.get("setpoint"),
                "holding": tk.get("holding"), "picker": tk.get("picker"),
                "events": len(ev),
                "last_events": [{"t": e.get("t"), "kind": e.get("kind"), "text": _describe(e)}
                                for e in ev[-8:]],
                "placed": pb.placed(), "bricks_total": len(pb.manifest.get("bricks", [])),
                "scene_updates": self.scene.updates if self.scene is not None else 0,
            }

    # --------------------------------------------------------------- scene + thread
    def start_scene(self) -> ReplayScene | None:
        with self._lock:
            if self.scene is None:
                try:
                    self.scene = ReplayScene().start()
                except Exception:  # noqa: BLE001 - the panel works without the 3D view
                    self.scene = None
                    return None
                if self.pb is not None:
                    self.scene.load(self.pb.manifest)
                    self._shown = -1
        self._ensure_thread()
        self._wake.set()
        return self.scene

    def _ensure_thread(self) -> None:
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._stop.clear()
                self._thread = threading.Thread(target=self._run, daemon=True,
                                                name="replay-playback")
                self._thread.start()

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            playing = self.pb is not None and self.pb.playing
            if not playing:
                self._wake.wait(self.period if self._shown < 0 else 0.5)
                self._wake.clear()
            else:
                self._stop.wait(self.period)
            now = time.monotonic()
            dt, last = now - last, now
            if self._stop.is_set():
                break
            with self._lock:
                pb = self.pb
                if pb is None:
                    continue
                pb.advance(dt)
                i = pb.index()
                scene = self.scene
                tick = pb.ticks[i]
                placed = set(pb.placed())
            if scene is not None and i != self._shown:
                try:
                    scene.show(tick, placed)
                    self._shown = i
                except Exception:
                    log.debug("replay scene update failed", exc_info=True)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(3)
        if self.scene is not None:
            self.scene.stop()
            self.scene = None
