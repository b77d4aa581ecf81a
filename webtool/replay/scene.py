"""The mission replay's 3D scene (viser): a simulated mission recording at one instant.

The scene is in the site frame (x east, y north, z up, metres): a ground grid, the wall plan as
ghost outlines, the drone (FRD body axes, a flat box and the camera frustum at
``body_from_camera``) at its recorded pose, its setpoint (a small orange ball), and each brick
as its layout's mesh at its recorded top-face pose (placed bricks turn green). Served through
the app at ``/replay/3d/`` (:mod:`webtool.viewer.scene`). Quaternions are viser's (w, x, y, z).
"""

from __future__ import annotations

import math

import numpy as np

from drovisio.geometry import quat_wxyz, yaw_quat_wxyz
from drovisio.layout import load_layout, shipped_layout_file
from drovisio.mesh_file import load_layout_mesh
from webtool.viewer.scene import ViserScene

__all__ = ["ReplayScene"]

BRICK_RGB = (60, 130, 220)
PLACED_RGB = (40, 160, 70)
HELD_RGB = (250, 200, 20)
GHOST_RGB = (150, 150, 150)
SETPOINT_RGB = (240, 140, 20)


class ReplayScene(ViserScene):
    """A recording at one instant, in the site frame (a :class:`ViserScene`)."""

    label = "Drovisio replay"
    up = "+z"

    def __init__(self) -> None:
        super().__init__()
        self._bricks: dict[str, dict] = {}
        self._meshes: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        self._drone = None
        self._setpoint = None
        self.updates = 0

    def _mesh(self, layout: str) -> tuple[np.ndarray, np.ndarray] | None:
        """The mesh of a shipped layout the recording names; None (a box) for any other name
        (the replay state says why: :func:`webtool.replay.service.layouts_note`)."""
        if layout not in self._meshes:
            mesh = None
            try:
                m = load_layout_mesh(load_layout(shipped_layout_file(layout)))
                if m is not None:
                    mesh = (np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32))
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
        with self._lock, self.server.atomic():
            self.server.scene.reset()
            self._bricks.clear()
            bounds = (manifest.get("site") or {}).get("bounds") or {}
            lo, hi = bounds.get("min"), bounds.get("max")
            self._draw_ground(lo, hi)
            layouts = manifest.get("layouts") or {}
            for b in manifest.get("bricks", []):
                self._draw_brick(b, layouts)
            self._draw_drone(manifest.get("camera") or {})
            cx, cy, y0 = ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[1]) if lo and hi \
                else (1.0, 1.0, -1.0)
            self.server.initial_camera.position = (cx, y0 - 3.0, 5.0)
            self.server.initial_camera.look_at = (cx, cy, 0.5)
            self.server.initial_camera.up = (0.0, 0.0, 1.0)

    def _draw_ground(self, lo: list[float] | None, hi: list[float] | None) -> None:
        """The ground grid over the site's bounds (world frame, metres), else 8 m square."""
        sc = self.server.scene
        if lo and hi:
            w, h = hi[0] - lo[0], hi[1] - lo[1]
            sc.add_grid("/ground", width=w, height=h, plane="xy", cell_size=0.25,
                        section_size=1.0,
                        position=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0))
        else:
            sc.add_grid("/ground", width=8.0, height=8.0, plane="xy", cell_size=0.25)

    def _draw_brick(self, b: dict, layouts: dict) -> None:
        """A brick's place in the wall plan (a ghost) and the brick itself at its pick-up
        place."""
        sc = self.server.scene
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
                       position=tuple(np.asarray(plan["position"]) - [0, 0, dims[2] / 2]))
        pick = b["pick"]
        node = self._brick_node(f"/bricks/{b['id']}", b["layout"], dims, BRICK_RGB,
                                position=tuple(pick["position"]),
                                wxyz=yaw_quat_wxyz(pick["yaw"]))
        self._bricks[b["id"]] = {"node": node, "color": BRICK_RGB}

    def _draw_drone(self, cam: dict) -> None:
        """The drone (axes and airframe), its camera's frustum at ``body_from_camera`` and the
        setpoint."""
        sc = self.server.scene
        self._drone = sc.add_frame("/drone", axes_length=0.25, axes_radius=0.01)
        sc.add_box("/drone/body", color=(70, 70, 70), dimensions=(0.35, 0.35, 0.06),
                   opacity=0.7)
        T = np.asarray(cam.get("body_from_camera") or np.eye(4), float)
        fov, aspect = 1.0, 4 / 3
        if cam.get("K") and cam.get("height"):
            fov = 2 * math.atan2(cam["height"] / 2, cam["K"][1][1])
            aspect = cam["width"] / cam["height"]
        sc.add_camera_frustum("/drone/camera", fov=fov, aspect=aspect, scale=0.15,
                              color=(20, 20, 20), wxyz=tuple(quat_wxyz(T[:3, :3])),
                              position=tuple(T[:3, 3]))
        self._setpoint = sc.add_icosphere("/setpoint", radius=0.05, color=SETPOINT_RGB,
                                          opacity=0.8)

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
