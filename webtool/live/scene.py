"""The live view's 3D scene (viser): the drone, its tilted camera, the bricks, trails, target.

World frame of the scene = the drone's body frame, FRD (x forward, y right, z down); the
viewer's "up" is set to −z. Nodes:

* ``/drone`` — body axes and a flat box for the airframe;
* ``/drone/camera`` — the camera frustum at ``body_from_camera`` (mount tilt included;
  viser's frustum follows OpenCV's camera frame, like ours);
* ``/bricks/<track>`` — each tracked brick as its layout's mesh at ``body_from_brick``, with a
  label; the target brick is drawn in yellow, predicted (unmeasured) ones half transparent;
* ``/trails/<track>`` — the brick's last positions (body frame) as line segments.

The server is a :class:`webtool.viewer.scene.ViserScene` (127.0.0.1, own port, reached through
the app at ``/live/3d/``). :class:`LiveScene` is started lazily, updated at most ``max_hz``
times a second from the pipeline's outputs (in its own thread, so the pipeline never waits
for it) and stopped with the app. Quaternions are viser's (w, x, y, z).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from drovisio._threads import join_thread
from drovisio.geometry import quat_wxyz
from drovisio.mesh_file import load_layout_mesh
from drovisio.mount import Mount, down_camera_mount
from webtool.viewer.scene import ViserScene

__all__ = ["LiveScene"]

BRICK_RGB = (60, 130, 220)
DOTS_RGB = (200, 70, 60)
TARGET_RGB = (250, 200, 20)


class LiveScene(ViserScene):
    """The drone, its camera and the tracked bricks in the drone's body frame.

    Args:
        mount: The camera mount (a camera looking straight down without one).
        camera: The camera (its field of view draws the frustum).
        layouts: The layouts (their meshes draw the bricks).
        max_hz: Most scene updates per second.
        trail: Positions kept per brick for its trail.
    """

    label = "Drovisio live"
    up = "-z"

    def __init__(self, mount: Mount | None = None, camera=None, layouts=(),
                 max_hz: float = 10.0, trail: int = 40):
        super().__init__()
        self.mount = mount or down_camera_mount()
        self.camera = camera
        self.layouts = {lay.name: lay for lay in layouts}
        self.period = 1.0 / max_hz
        self.trail_len = trail
        self._latest = None
        self._event = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bricks: dict[int, dict] = {}
        self._trails: dict[int, deque] = {}
        self._meshes: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        self.updates = 0

    # ------------------------------------------------------------------ lifecycle
    def stop(self) -> None:
        """Stop the drawing thread, wait for a draw in progress, then the server."""
        self._stop.set()
        self._event.set()
        join_thread(self._thread, "drawing the live 3D scene")
        super().stop()

    # ------------------------------------------------------------------ content
    def setup(self) -> None:
        sc = self.server.scene
        self._ground = sc.add_grid("/ground", width=6.0, height=6.0, plane="xy", cell_size=0.25,
                                   section_size=1.0, position=(0.0, 0.0, 1.5))
        self._ground_z = 1.5
        sc.add_frame("/drone", axes_length=0.25, axes_radius=0.008)
        sc.add_box("/drone/body", color=(70, 70, 70), dimensions=(0.35, 0.35, 0.06),
                   opacity=0.6)
        T = self.mount.body_from_camera
        fov, aspect = 1.0, 4 / 3
        if self.camera is not None:
            fov = 2 * math.atan2(self.camera.height / 2, self.camera.fy)
            aspect = self.camera.width / self.camera.height
        sc.add_camera_frustum("/drone/camera", fov=fov, aspect=aspect, scale=0.15,
                              color=(20, 20, 20), wxyz=tuple(quat_wxyz(T[:3, :3])),
                              position=tuple(T[:3, 3]))
        try:
            self.server.initial_camera.position = (-0.9, -0.75, -0.7)
            self.server.initial_camera.look_at = (0.5, 0.0, 0.9)
            self.server.initial_camera.up = (0.0, 0.0, -1.0)
        except Exception:  # noqa: BLE001 - cosmetic
            pass
        self._thread = threading.Thread(target=self._run, daemon=True, name="live-scene")
        self._thread.start()

    def _mesh(self, layout: str) -> tuple[np.ndarray, np.ndarray] | None:
        if layout not in self._meshes:
            mesh = None
            lay = self.layouts.get(layout)
            if lay is not None:
                try:
                    m = load_layout_mesh(lay)
                    if m is not None:
                        mesh = (np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32))
                except Exception:  # noqa: BLE001 - fall back to a box
                    mesh = None
            self._meshes[layout] = mesh
        return self._meshes[layout]

    def _brick_nodes(self, key: int, layout: str, label: str) -> dict:
        sc = self.server.scene
        name = f"/bricks/{key}"
        mesh = self._mesh(layout)
        if mesh is not None:
            h = sc.add_mesh_simple(name, mesh[0], mesh[1], color=BRICK_RGB, flat_shading=True)
        else:
            lay = self.layouts.get(layout)
            dims = tuple(lay.dimensions_m) if lay is not None else (0.3, 0.15, 0.12)
            h = sc.add_box(name, color=BRICK_RGB, dimensions=dims)
        axes = sc.add_frame(f"{name}/axes", axes_length=0.1, axes_radius=0.004)
        lab = sc.add_label(f"{name}/label", label, position=(0.0, 0.0, 0.15))
        return {"mesh": h, "axes": axes, "label": lab, "color": None, "opacity": None}

    def update(self, output) -> None:
        """Give the latest output (cheap; the scene thread applies it at most max_hz)."""
        self._latest = output
        self._event.set()

    def _run(self) -> None:
        last = 0.0
        while not self._stop.is_set():
            self._event.wait(0.5)
            self._event.clear()
            if self._stop.is_set():
                break
            wait = self.period - (time.monotonic() - last)
            if wait > 0:
                self._stop.wait(wait)
            out = self._latest
            if out is None or self.server is None:
                continue
            last = time.monotonic()
            try:
                with self.server.atomic():
                    self._apply(out)
                self.updates += 1
            except Exception:  # noqa: BLE001 - a failed update is skipped, never fatal
                pass

    def _body_from_brick(self, b: Any) -> np.ndarray:
        """The brick's pose in the body frame (4×4): the pipeline's, else through the mount."""
        T = b.body_from_brick
        return T if T is not None else self.mount.body_from(b.camera_from_brick())

    def _apply(self, out: Any) -> None:
        """Bring the scene in line with one pipeline output (under the server's lock)."""
        seen = set()
        target_key = None if out.target is None else out.target.track
        for b in out.bricks:
            seen.add(b.track)
            self._show_brick(b, self._body_from_brick(b), b.track == target_key)
        self._move_ground(out)
        for key in [k for k in self._bricks if k not in seen]:
            self._remove_brick(key)

    def _show_brick(self, b: Any, T: np.ndarray, is_target: bool) -> None:
        """Place, colour and label one tracked brick (``T``: body_from_brick, 4×4)."""
        key = b.track
        name = b.layout + (f":{b.instance}" if b.instance is not None else f" #{b.track}")
        nodes = self._bricks.get(key)
        if nodes is None:
            nodes = self._bricks[key] = self._brick_nodes(key, b.layout, name)
        nodes["mesh"].position = tuple(float(x) for x in T[:3, 3])
        nodes["mesh"].wxyz = tuple(quat_wxyz(T[:3, :3]))
        color = TARGET_RGB if is_target else (DOTS_RGB if b.method == "dots" else BRICK_RGB)
        if nodes["color"] != color:
            nodes["mesh"].color = color
            nodes["color"] = color
        opacity = 1.0 if b.measured else 0.45
        if nodes["opacity"] != opacity and hasattr(nodes["mesh"], "opacity"):
            nodes["mesh"].opacity = opacity
            nodes["opacity"] = opacity
        text = f"{name}  {b.distance:.2f} m" + (" TARGET" if is_target else "")
        if nodes.get("text") != text:
            nodes["label"].text = text
            nodes["text"] = text
        self._extend_trail(key, nodes, T)

    def _extend_trail(self, key: int, nodes: dict[str, Any], T: np.ndarray) -> None:
        """Add the brick's position (body frame, metres) to its trail and redraw it."""
        tr = self._trails.setdefault(key, deque(maxlen=self.trail_len))
        tr.append(T[:3, 3].astype(np.float32))
        if len(tr) < 2:
            return
        pts = np.array(tr)
        segs = np.stack([pts[:-1], pts[1:]], axis=1)
        h = nodes.get("trail")
        if h is None:
            nodes["trail"] = self.server.scene.add_line_segments(
                f"/trails/{key}", segs, colors=(240, 140, 20), thickness=0.006)
        else:
            h.points = segs

    def _move_ground(self, out: Any) -> None:
        """The ground grid under the bricks (their lowest top face + a brick height; body z
        points down), smoothed."""
        downs = [float(self._body_from_brick(b)[2, 3]) for b in out.bricks if b.measured]
        if downs:
            z = max(downs) + 0.12
            self._ground_z += 0.2 * (z - self._ground_z)
            self._ground.position = (0.0, 0.0, round(self._ground_z, 3))

    def _remove_brick(self, key: int) -> None:
        nodes = self._bricks.pop(key)
        self._trails.pop(key, None)
        for n in ("label", "axes", "mesh", "trail"):
            if nodes.get(n) is not None:
                nodes[n].remove()

    # ------------------------------------------------------------------ inspection (tests)
    def brick_names(self) -> list[str]:
        return sorted(n["text"] for n in self._bricks.values() if n.get("text"))
