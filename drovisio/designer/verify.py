"""Try a layout on a simulated photo: render the brick with :mod:`drovisio.synth` and find it
again with the detectors, to know before printing that the layout works.

:func:`verify_layout` renders one brick of the layout (its mesh file, its markers) seen by the
drone camera from above at a slant, runs the code detector (if the layout has codes) and the
dot detector (if it has dots), and compares each pose found with the true one. A symmetric
layout (``rot180_z``) counts a pose turned by a half-turn about z as right.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drovisio.camera import Camera
from drovisio.designer.model import DesignError
from drovisio.detect.result import BrickPose
from drovisio.layout import MarkerLayout
from drovisio.pose.measures import rotation_angle_deg, yaw_about_axis_deg
from drovisio.synth import (
    BrickInstance,
    Effects,
    Ground,
    Scene,
    camera_over,
    render,
    rot_z,
    transform,
)

__all__ = ["VerifyResult", "verify_layout"]


@dataclass
class VerifyResult:
    """One detector's result on the simulated photo.

    Attributes:
        method: ``"aruco"`` or ``"dots"``.
        found: the brick was found.
        position_error_m: distance between found and true brick origin (metres).
        angle_error_deg: rotation between found and true brick orientation (degrees).
        yaw_error_deg: the part of that rotation about the brick's z axis (its turn on the
            ground; what placing a brick needs most), signed, degrees.
        markers: ids (codes) or dot indices used.
        distance_m: camera-to-brick distance of the photo.
    """

    method: str
    found: bool
    position_error_m: float | None = None
    angle_error_deg: float | None = None
    yaw_error_deg: float | None = None
    markers: list[int] | None = None
    distance_m: float | None = None

    def to_json(self) -> dict:
        return {"method": self.method, "found": self.found,
                "position_error_mm": None if self.position_error_m is None
                else round(self.position_error_m * 1000, 2),
                "angle_error_deg": None if self.angle_error_deg is None
                else round(self.angle_error_deg, 3),
                "yaw_error_deg": None if self.yaw_error_deg is None
                else round(self.yaw_error_deg, 3),
                "markers": self.markers, "distance_m": self.distance_m}


def verify_layout(layout: MarkerLayout, camera: Camera | None = None,
                  distance_m: float | None = None, tilt_deg: float = 20.0,
                  yaw_deg: float = 25.0, instance: int = 0, ground: str = "concrete",
                  ss: int = 2) -> tuple[list[VerifyResult], np.ndarray]:
    """Render one brick of ``layout`` and detect it.

    Args:
        layout: a layout whose mesh file resolves (``layout.mesh_path()``).
        camera: the drone camera (default: the thesis's webcam).
        distance_m: camera-to-brick distance (default: 2.5 x the brick's largest size,
            at least 0.6 m).
        tilt_deg: camera tilt from straight down.
        yaw_deg: the brick's turn about the vertical.
        instance: brick instance (chooses the code ids).
        ground: ground texture of :class:`drovisio.synth.Ground`.
        ss: anti-aliasing samples per pixel side.

    Returns:
        The results (one per detector that applies) and the rendered BGR image.
    """
    camera = camera or Camera.drone_webcam()
    size = float(np.max(layout.dimensions_m))
    dist = distance_m if distance_m is not None else max(0.6, 2.5 * size)
    wfb = transform(rot_z(math.radians(yaw_deg)), [0.01, -0.015, 0.0])
    cfw = camera_over([0.0, 0.0, 0.0], dist, tilt_deg=tilt_deg, heading_deg=10.0)
    inst = instance if layout.has_codes else None
    res = render(Scene(camera, cfw, ground=Ground(ground),
                       bricks=[BrickInstance(layout, wfb, instance=inst)]), Effects(), ss=ss)
    truth = res.bricks[0].camera_from_brick
    half = np.diag([-1.0, -1.0, 1.0])
    out: list[VerifyResult] = []

    def score(method: str, poses: Sequence[BrickPose]) -> None:
        mine = [p for p in poses if p.layout == layout.name]
        if not mine:
            out.append(VerifyResult(method, False, distance_m=round(dist, 3)))
            return
        p = mine[0]
        T = p.camera_from_brick()
        err_t = float(np.linalg.norm(T[:3, 3] - truth[:3, 3]))
        Rt = truth[:3, :3]
        if layout.symmetry == "rot180_z" and method == "dots" and \
                rotation_angle_deg(T[:3, :3], Rt @ half) < rotation_angle_deg(T[:3, :3], Rt):
            Rt = Rt @ half
        out.append(VerifyResult(method, True, err_t, rotation_angle_deg(T[:3, :3], Rt),
                                yaw_about_axis_deg(Rt, T[:3, :3]), [int(m) for m in p.markers],
                                round(dist, 3)))

    if layout.has_codes:
        # deferred: the detectors load their compiled kernels, which only a check needs
        from drovisio.detect.aruco import detect_aruco

        score("aruco", detect_aruco(res.image, camera, [layout]))
    if layout.has_dots:
        # deferred: the detectors load their compiled kernels, which only a check needs
        from drovisio.detect.dots import LayoutNotSupported, detect_dots

        try:
            score("dots", detect_dots(res.image, camera, [layout]))
        except LayoutNotSupported as e:
            # a layout the dot detector refuses is the design's problem, said as such
            raise DesignError("the dot detector cannot use this layout: "
                              + str(e).split(": ", 1)[-1]) from None
    return out, res.image
