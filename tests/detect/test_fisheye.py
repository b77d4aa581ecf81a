"""Both detectors through a 150° fisheye lens (Kannala–Brandt), against rendered truth: the
lens model is honoured in detection, undistortion, PnP and the renderer alike."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.detect.dots import DotDetector
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.pose import rotation_angle_deg, yaw_about_axis_deg
from drovisio.scenes import SceneSpec, gravity_in_camera, render_random

FISHEYE = Camera.from_fov(1280, 960, 150.0, dist=[0.03, -0.012, 0.004, -0.0008],
                          model="fisheye", name="fisheye-150")
HALF = np.array([-1.0, -1.0, 1.0])


def _eligible(kind: str, b) -> bool:
    """In the working range (≤ 2 m), markers inside the image (codes ≥ 15 px)."""
    if np.linalg.norm(b.camera_from_brick[:3, 3]) > 2.0:
        return False
    W, H = FISHEYE.size
    if kind == "aruco":
        sides = [np.sqrt(abs(cv2.contourArea(c.astype(np.float32))))
                 for c in b.code_corners_px.values()
                 if np.all(np.isfinite(c)) and np.all((c >= 0) & (c < [W, H]))]
        return bool(sides) and max(sides) >= 15
    c = b.dot_centers_px
    return bool(np.all(np.isfinite(c)) and np.all((c >= 5) & (c < [W - 5, H - 5])))


@pytest.mark.parametrize("kind", ["aruco", "dots"])
def test_bricks_through_a_150_degree_fisheye(kind):
    name = "drick-aruco-pyramids.json" if kind == "aruco" else "drick-dots-2x3.json"
    lay = load_layout(shipped_layouts_dir() / name)
    det = (ArucoBrickDetector(FISHEYE, [lay]) if kind == "aruco"
           else DotDetector(FISHEYE, [lay]))
    spec = SceneSpec(layouts=[lay], n_bricks=4, distance=(0.5, 2.0), spread=1.6, props=1)
    lat, depth, yaw, n, found = [], [], [], 0, 0
    for seed in range(10):
        r = render_random(seed, spec, FISHEYE, ss=2)
        poses = det.detect(r.image, gravity=gravity_in_camera(r.camera_from_world))
        for b in r.bricks:
            if not _eligible(kind, b):
                continue
            n += 1
            T = b.camera_from_brick
            near = [p for p in poses if np.linalg.norm(p.tvec - T[:3, 3]) < 0.08]
            if not near:
                continue
            p = near[0]
            found += 1
            R = cv2.Rodrigues(p.rvec)[0]
            if kind == "dots" and rotation_angle_deg(R * HALF, T[:3, :3]) < \
                    rotation_angle_deg(R, T[:3, :3]):
                R = R * HALF                  # a symmetric layout: either half-turn
            assert rotation_angle_deg(R, T[:3, :3]) < 20 or p.ambiguous, (seed, "flip")
            lat.append(np.linalg.norm((p.tvec - T[:3, 3])[:2]))
            depth.append(abs(p.tvec[2] - T[2, 3]) / T[2, 3])
            yaw.append(abs(yaw_about_axis_deg(T[:3, :3], R)))
    assert n >= 25
    # the 60° lens's targets: lateral ≤ 1 cm, depth ≤ 1.5 %, yaw ≤ 1° (p95 over few bricks)
    assert found >= 0.9 * n, (found, n)
    assert np.percentile(lat, 95) < 0.01
    assert np.percentile(depth, 95) < 0.015
    assert np.percentile(yaw, 95) < 1.0


@pytest.mark.parametrize("cam", [
    FISHEYE,
    Camera.from_fov(640, 480, 90.0, dist=[-0.3, 0.1, 0.001, -0.002, -0.01, 0.02, -0.01, 0.005]),
    Camera.drone_webcam()])
def test_projection_jacobian_for_every_lens_model(cam):
    rng = np.random.default_rng(3)
    obj = rng.normal(0, 0.2, (12, 3))
    rvec, tvec = np.array([0.2, -0.1, 0.3]), np.array([0.05, -0.02, 1.2])
    px, J = cam.project_points(obj, rvec, tvec)
    np.testing.assert_allclose(px, cam.project(obj @ cv2.Rodrigues(rvec)[0].T + tvec),
                               atol=1e-9)
    h = 1e-6
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        p1, _ = cam.project_points(obj, rvec + e[:3], tvec + e[3:])
        p0, _ = cam.project_points(obj, rvec - e[:3], tvec - e[3:])
        np.testing.assert_allclose((p1 - p0).ravel() / (2 * h), J[:, k], rtol=1e-4, atol=1e-3)
