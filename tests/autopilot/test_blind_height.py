"""Where a straight descent onto a brick loses it from the picture, for a mount and a lens."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from drovisio.autopilot.blind import blind_height, blind_heights_text
from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.layout import load_layout
from drovisio.mount import Mount, load_mount

REPO = Path(__file__).resolve().parents[2]
CENTRE = load_layout(REPO / "marker_layouts" / "drick-aruco-centre.json")


def test_sample_mount_goes_blind_near_1_7_m_and_straight_down_much_lower():
    cam = load_camera(REPO / "sample_sessions" / "camera.yaml")
    mount = load_mount(REPO / "sample_sessions" / "approach" / "mount.json")
    b = blind_height(cam, mount, CENTRE)
    # the measurement on ArduPilot SITL: ~1.75 m (body origin; the camera is 5 cm below)
    assert b.leaves_at_m is not None and 1.6 < b.leaves_at_m < 1.8
    assert b.leaves_at_m + b.body_offset_down_m == pytest.approx(1.75, abs=0.06)
    down = blind_height(cam, Mount.from_angles(0.0, offset_m=(0.08, 0.0, 0.05)), CENTRE)
    assert down.leaves_at_m is not None and down.leaves_at_m < 0.4
    text = blind_heights_text(cam, mount, CENTRE)
    assert f"{b.leaves_at_m:.2f} m above it" in text and f"{down.leaves_at_m:.2f} m" in text


@pytest.mark.parametrize("tilt_deg", [5.0, 12.0, 20.0])
def test_blind_height_agrees_with_the_pinhole_geometry(tilt_deg):
    """Distortion-free pinhole, camera at the body origin: the code's back edge (half a code
    behind the point below the camera, along the image's vertical) leaves the picture when
    tilt + atan(half / h) reaches the lower half field of view."""
    cam = Camera.from_fov(640, 480, 60.0)
    half_v = math.atan((cam.height - 1 - cam.cy) / cam.fy)
    corners = CENTRE.markers[0].corners_array()
    back = float(-corners[:, 0].min())   # the code's extent behind the brick origin (-x)
    want = back / math.tan(half_v - math.radians(tilt_deg))
    got = blind_height(cam, Mount.from_angles(tilt_deg), CENTRE, step_m=0.001,
                       margin_px=0.0).leaves_at_m
    assert got == pytest.approx(want, rel=0.01, abs=0.002)


def test_tilt_beyond_the_half_field_of_view_never_sees_the_brick_below():
    cam = Camera.from_fov(640, 480, 60.0)
    b = blind_height(cam, Mount.from_angles(40.0), CENTRE)
    assert b.highest_seen_m is None and "never in the picture" in blind_heights_text(
        cam, Mount.from_angles(40.0), CENTRE)
    assert np.isfinite(blind_height(cam, Mount.from_angles(0.0), CENTRE).leaves_at_m)
