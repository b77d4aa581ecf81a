"""The drone's camera rig in a scenario: the camera, the mount, and where a brick leaves the
picture on the way down."""

from __future__ import annotations

import math

import cv2
import numpy as np

from drovisio.autopilot.blind import blind_height
from drovisio.camera import Camera
from drovisio.mission.scenario import Scenario, ScenarioError
from drovisio.mount import Mount

__all__ = ["camera_for", "body_from_camera_for", "landing_blind_heights"]


def camera_for(scn: Scenario) -> Camera:
    """The scenario's camera (:attr:`Scenario.camera`): its camera file, else the built-in
    drone webcam."""
    return scn.camera


def body_from_camera_for(scn: Scenario) -> np.ndarray:
    """The mount: camera looking down (image top toward the drone's front), tilted forward by
    ``tilt_deg``, at ``offset_m`` in the FRD body frame (as :mod:`drovisio.synth_samples`)."""
    m = scn.drone.camera.mount
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    tilt = cv2.Rodrigues(np.array([0.0, math.radians(m.tilt_deg), 0.0]))[0]
    T = np.eye(4)
    T[:3, :3] = tilt @ R
    T[:3, 3] = m.offset_m
    return T


def landing_blind_heights(scn: Scenario, camera: Camera | None = None,
                          body_from_camera: np.ndarray | None = None) -> dict[str, float | None]:
    """Per layout, the camera height above a brick at which it leaves the picture on the way
    down (None: seen all the way), with the scenario's lens and mount
    (:func:`drovisio.autopilot.blind.blind_height`).

    Raises:
        ScenarioError: with ``autopilot.precision_landing``, a brick the descent cannot see:
            never in the picture right below the drone, or gone above the approach height.
    """
    camera = camera if camera is not None else camera_for(scn)
    mount = Mount(body_from_camera if body_from_camera is not None else body_from_camera_for(scn))
    out: dict[str, float | None] = {}
    never = False
    for name in scn.layouts:
        bh = blind_height(camera, mount, scn.layout(name))
        out[name] = bh.leaves_at_m
        never |= bh.highest_seen_m is None
    if not scn.autopilot.precision_landing:
        return out
    where = f"{scn.source}: " if scn.source is not None else ""
    if never:
        raise ScenarioError(
            f"{where}drone.camera.mount.tilt_deg: with this lens and mount the brick right "
            "below the drone is never in the picture: with autopilot.precision_landing the "
            "drone would never see it to land on; tilt the camera less")
    highest = max((b for b in out.values() if b is not None), default=0.0)
    down = scn.drone.camera.mount.offset_m[2]
    approach_cam = scn.altitudes.approach_m - down
    if highest >= approach_cam - 0.05:
        raise ScenarioError(
            f"{where}altitudes.approach_m: with this lens and mount the brick below leaves the "
            f"picture {highest:.2f} m above it (camera height), above the approach "
            f"({approach_cam:.2f} m): with autopilot.precision_landing the drone would never "
            f"see it to land on; raise approach_m above {highest + down + 0.1:.2f} m (and "
            "cruise_m with it) or tilt the camera less")
    return out
