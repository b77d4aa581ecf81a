"""The mount page's 3D preview (viser): the drone, its camera and what the camera sees of the
ground.

World frame = the drone's body frame, FRD (x forward, y right, z down), viewer up −z, as the
live view. Nodes: ``/drone`` (body axes, a flat box for the airframe and a red arrow to the
nose), ``/drone/camera`` (the frustum at ``body_from_camera``), ``/ground`` (a grid
``height_m`` below the body origin) and ``/footprint`` (the outline of the ground in view, with
a dot where the optical axis meets it). Reached through the app at ``/mount/3d/``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drovisio.geometry import quat_wxyz
from drovisio.mount import Mount
from webtool.viewer.scene import ViserScene

__all__ = ["MountScene"]

FOOTPRINT_RGB = (11, 79, 168)


class MountScene(ViserScene):
    """The preview; :meth:`show` redraws what depends on the mount and the height.

    Args:
        camera: The camera (its field of view draws the frustum).
    """

    label = "Drovisio camera mount"
    up = "-z"

    def __init__(self, camera) -> None:
        super().__init__()
        self.camera = camera
        self._frustum: Any = None
        self._ground: Any = None
        self._footprint: Any = None
        self._centre: Any = None
        self.shown: dict | None = None

    def setup(self) -> None:
        sc = self.server.scene
        sc.add_frame("/drone", axes_length=0.25, axes_radius=0.008)
        sc.add_box("/drone/body", color=(70, 70, 70), dimensions=(0.35, 0.35, 0.06),
                   opacity=0.6)
        # the nose: an arrow along +x, so "forward" is never a guess
        sc.add_line_segments("/drone/nose", points=np.array([[[0.18, 0, 0], [0.45, 0, 0]],
                                                             [[0.45, 0, 0], [0.38, -0.05, 0]],
                                                             [[0.45, 0, 0], [0.38, 0.05, 0]]],
                                                            np.float32),
                             colors=(220, 40, 40), thickness=5.0,
                             thickness_units="screen")
        sc.add_label("/drone/nose/label", "nose", position=(0.5, 0.0, 0.0))
        try:
            self.server.initial_camera.position = (-1.5, -1.3, -1.1)
            self.server.initial_camera.look_at = (0.7, 0.0, 0.8)
            self.server.initial_camera.up = (0.0, 0.0, -1.0)
        except Exception:  # noqa: BLE001 - cosmetic
            pass

    def show(self, mount: Mount, height_m: float, footprint: dict) -> None:
        """Draw the camera at ``mount`` and the ground ``height_m`` below the body origin with
        ``footprint`` (:func:`drovisio.mount.ground_footprint`)."""
        with self._lock:
            if self.server is None:
                return
            sc = self.server.scene
            T = mount.body_from_camera
            cam = self.camera
            fov = min(2 * math.atan2(cam.height / 2, cam.fy), math.radians(170))
            if self._frustum is None:
                self._frustum = sc.add_camera_frustum(
                    "/drone/camera", fov=fov, aspect=cam.width / cam.height, scale=0.2,
                    color=(20, 20, 20))
            self._frustum.wxyz = tuple(quat_wxyz(T[:3, :3]))
            self._frustum.position = tuple(float(v) for v in T[:3, 3])
            size = max(4.0, 2.2 * float(footprint["farthest_m"]))
            if self._ground is not None:
                self._ground.remove()
            self._ground = sc.add_grid("/ground", width=size, height=size, plane="xy",
                                       cell_size=0.25, section_size=1.0,
                                       position=(0.0, 0.0, float(height_m)))
            poly = np.asarray(footprint["polygon"], np.float32)
            pts = np.column_stack([poly, np.full(len(poly), height_m - 0.005, np.float32)])
            segs = np.stack([pts, np.roll(pts, -1, axis=0)], axis=1).astype(np.float32)
            if self._footprint is not None:
                self._footprint.remove()
            self._footprint = sc.add_line_segments("/footprint", points=segs,
                                                   colors=FOOTPRINT_RGB, thickness=3.0,
                                                   thickness_units="screen")
            if self._centre is not None:
                self._centre.remove()
                self._centre = None
            if footprint["centre"] is not None:
                f, r = footprint["centre"]
                self._centre = sc.add_icosphere("/footprint_centre", radius=0.04,
                                                color=FOOTPRINT_RGB,
                                                position=(f, r, height_m - 0.01))
            self.shown = {"body_from_camera": T.tolist(), "height_m": height_m}
