"""The Fleet page's 3D scene (viser): every drone's camera and its bricks, side by side.

No site frame is known (the drones publish no position yet), so each drone's scene is its own
camera frame, OpenCV's (x right, y down, z forward, metres), placed along a row: drone ``k``
(in id order) at ``x = 1.5 k`` m. Nodes: ``/drones/<id>`` (camera axes, a frustum and the id
as a label) and ``/drones/<id>/bricks/<n>`` (each brick of its last frame as a small box at its
``camera_from_brick``; the target yellow, lost drones grey). Served through the app at
``/fleet/3d/``; updated at most ``max_hz`` times a second in its own thread.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from drovisio._threads import join_thread
from drovisio.geometry import from_rvec_tvec, quat_wxyz
from drovisio.station import Fleet
from webtool.viewer.scene import ViserScene

__all__ = ["FleetScene"]

SPACING_M = 1.5
BRICK_RGB = (60, 130, 220)
TARGET_RGB = (250, 200, 20)
LOST_RGB = (150, 150, 150)


class FleetScene(ViserScene):
    """Every drone of a :class:`Fleet` in one view (module doc).

    Args:
        fleet: The station's fleet state.
        max_hz: Most updates per second.
    """

    label = "Drovisio fleet"
    up = "-y"

    def __init__(self, fleet: Fleet, max_hz: float = 4.0):
        super().__init__()
        self.fleet = fleet
        self.period = 1.0 / max_hz
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._drawn: dict[str, int] = {}
        self.updates = 0

    def setup(self) -> None:
        self.server.scene.add_grid("/ground", width=12.0, height=12.0, plane="xz",
                                   position=(0.0, 1.5, 3.0))
        self._thread = threading.Thread(target=self._loop, name="fleet-scene", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the drawing thread, wait for a draw in progress, then the server."""
        self._stop.set()
        join_thread(self._thread, "drawing the fleet's 3D scene")
        super().stop()

    def _loop(self) -> None:
        while not self._stop.wait(self.period):
            try:
                self.update()
            except Exception:  # noqa: BLE001 - a scene error never stops the station
                pass

    def update(self) -> None:
        """Draw the fleet as it is now."""
        with self._lock:
            if self.server is None:
                return
            sc = self.server.scene
            for k, d in enumerate(self.fleet.status()):
                self._draw_drone(sc, k, d.drone_id, d.state == "live", d.to_json())
            self.updates += 1

    def _draw_drone(self, sc: Any, k: int, drone: str, live: bool, st: dict[str, Any]) -> None:
        root = f"/drones/{drone}"
        sc.add_frame(root, position=(SPACING_M * k, 0.0, 0.0), axes_length=0.15,
                     axes_radius=0.008)
        sc.add_label(f"{root}/name", f"{drone} ({st['state']})", position=(0.0, -0.2, 0.0))
        sc.add_camera_frustum(f"{root}/camera", fov=1.0, aspect=4 / 3, scale=0.15,
                              color=(40, 40, 40) if live else LOST_RGB)
        bricks = self.fleet.last_bricks(drone)
        target = st.get("target") or {}
        for n, b in enumerate(bricks):
            T = from_rvec_tvec(np.asarray(b["rvec"], float), np.asarray(b["tvec"], float))
            is_target = (b.get("track") == target.get("track")
                         and b.get("layout") == target.get("layout"))
            rgb = LOST_RGB if not live else TARGET_RGB if is_target else BRICK_RGB
            sc.add_box(f"{root}/bricks/{n}", color=rgb, dimensions=(0.1, 0.05, 0.03),
                       wxyz=quat_wxyz(T[:3, :3]), position=tuple(T[:3, 3]))
        for n in range(len(bricks), self._drawn.get(drone, 0)):
            sc.remove_by_name(f"{root}/bricks/{n}")
        self._drawn[drone] = len(bricks)
