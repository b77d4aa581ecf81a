"""Where a landing goes blind: the height above a brick at which its markers leave the picture.

A precision landing steers the body origin over the brick. With the camera tilted forward
(or mounted off the body origin), the brick right below drifts toward the image's edge as the
drone descends and leaves it at some height: from there the autopilot descends on its last
estimate. Computed from the camera's lens (field of view and distortion), the mount and the
layout's markers: the drone level, its body origin straight above the brick's origin, the
brick's x axis along the drone's nose (yaw aligned, as the mission aligns it before the
descent). The target counts as seen while one of its codes has all four corners in the
picture (a dots layout: all its dots).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drovisio.camera import Camera
from drovisio.layout import MarkerLayout
from drovisio.mount import BODY_FROM_ALIGNED_BRICK, Mount

__all__ = ["BlindHeight", "blind_height", "blind_heights_text"]


@dataclass(frozen=True)
class BlindHeight:
    """Heights are of the camera above the brick's top face (the layout's z = 0), metres."""

    leaves_at_m: float | None
    """Highest camera height at which the target leaves the picture on the way down (None:
    seen all the way to ``lowest_m``)."""
    highest_seen_m: float | None
    """Highest height (≤ ``search_top_m``) at which it is in the picture at all."""
    body_offset_down_m: float
    """The camera's offset below the body origin (add it for the body origin's height)."""


def _groups(layout: MarkerLayout) -> list[np.ndarray]:
    codes = [m.corners_array() for m in layout.markers if m.kind == "aruco"]
    if codes:
        return codes
    return [np.array([m.center_array() for m in layout.markers])]


def blind_height(camera: Camera, mount: Mount, layout: MarkerLayout, *, lowest_m: float = 0.05,
                 search_top_m: float = 10.0, step_m: float = 0.005, margin_px: float = 1.0
                 ) -> BlindHeight:
    """The height at which ``layout``'s brick leaves ``camera``'s picture on a straight
    descent onto it (see the module doc).

    Args:
        camera: The lens (its size must be known).
        mount: ``body_from_camera``.
        layout: The brick's markers (brick frame, metres).
        lowest_m, search_top_m, step_m: The camera heights searched.
        margin_px: A corner closer than this to the image border counts as out.
    """
    w, h = camera.size
    heights = np.arange(search_top_m, lowest_m - 1e-9, -step_m)
    cam_from_body = mount.camera_from_body
    down = float(mount.body_from_camera[2, 3])
    # the widest undistorted ray of the picture: beyond it a lens polynomial can fold back
    border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [0, h / 2], [w - 1, h / 2],
                       [w / 2, 0], [w / 2, h - 1]], np.float64)
    r_max = float(np.max(np.linalg.norm(camera.normalize(border), axis=1))) * 1.02
    seen = np.zeros(len(heights), bool)
    for group in _groups(layout):
        pts_b = BODY_FROM_ALIGNED_BRICK @ group.T                       # 3×K, brick at z = 0
        k = pts_b.shape[1]
        # every corner at every height at once: (3, K·N), corner-major
        p_body = np.repeat(pts_b, len(heights), axis=1)
        p_body[2] += np.tile(heights + down, k)                          # below the body origin
        p_cam = cam_from_body[:3, :3] @ p_body + cam_from_body[:3, 3:4]
        z = p_cam[2]
        front = z > 1e-6
        r = np.hypot(p_cam[0], p_cam[1]) / np.where(front, z, 1.0)
        px = camera.project(p_cam.T)
        inside = ((px[:, 0] >= margin_px) & (px[:, 0] <= w - 1 - margin_px)
                  & (px[:, 1] >= margin_px) & (px[:, 1] <= h - 1 - margin_px))
        ok = (front & (r <= r_max) & inside).reshape(k, len(heights)).all(axis=0)
        seen |= ok
    if not seen.any():
        return BlindHeight(None, None, down)
    first = int(np.argmax(seen))
    lost = np.nonzero(~seen[first:])[0]
    leaves = None if len(lost) == 0 else float(heights[first + lost[0] - 1])
    return BlindHeight(leaves, float(heights[first]), down)


def blind_heights_text(camera: Camera, mount: Mount, layout: MarkerLayout) -> str:
    """One sentence: the height with this mount, and with the camera straight down at the
    same place."""
    this = blind_height(camera, mount, layout)
    a = mount.angles()
    straight = Mount.from_angles(0.0, 0.0, a["roll_deg"], a["offset_m"])
    down = blind_height(camera, straight, layout)

    def say(b: BlindHeight) -> str:
        if b.highest_seen_m is None:
            return "never in the picture on the way down"
        if b.leaves_at_m is None:
            return "in the picture all the way down"
        return f"leaves the picture {b.leaves_at_m:.2f} m above it"

    return (f"landing on a {layout.name}: with this mount (tilt {a['tilt_deg']:.0f}°) the "
            f"brick {say(this)} (camera height; below that the autopilot lands on its last "
            f"estimate); looking straight down from the same place it {say(down)}")
