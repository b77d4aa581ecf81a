"""The renderer's geometry is exact: edges where the camera model puts them, and a calibration
from its own chessboard views gives the camera back."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from drovisio.bench import renderer
from drovisio.camera import Camera
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.synth import (
    Board,
    BrickInstance,
    Effects,
    Ground,
    Prop,
    Scene,
    apply_effects,
    camera_over,
    look_at,
    render,
    rot_z,
    transform,
)

CAM = Camera.drone_webcam()


def layout(name: str):
    return load_layout(shipped_layouts_dir() / f"{name}.json")


@pytest.fixture(scope="module")
def close_code():
    """One drick with a centre code, 0.25 m below the camera, slightly turned."""
    lay = layout("drick-aruco-centre")
    brick = BrickInstance(lay, transform(rot_z(math.radians(4)), [0.01, 0.005, 0.10]),
                          instance=3)
    scene = Scene(CAM, camera_over([0, 0, 0.10], 0.25, tilt_deg=8, heading_deg=30),
                  ground=Ground("plain"), bricks=[brick])
    return render(scene, ss=4), lay


def test_code_edge_lies_where_the_camera_model_projects_it():
    """Row by row, the area of white left of the code's outer left edge gives the edge's
    position to a few thousandths of a pixel; it must match the distorted projection.
    4×4 samples per pixel quantise each crossing to 1/4 px per sub-row: that averages out
    along the edge (mean) but not row by row (max)."""
    e = renderer.edge_check(CAM, ss=4)
    assert e["rows"] > 60
    assert abs(e["mean_px"]) < 0.01, e
    assert e["rms_px"] < 0.04, e
    assert e["max_px"] < 0.08, e


def test_truth_matches_what_opencv_finds(close_code):
    res, lay = close_code
    truth = res.bricks[0]
    assert truth.code_ids == [lay.marker_id(3, 0)] == [3]
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = det.detectMarkers(res.image)
    assert np.ravel(ids).tolist() == [3]
    err = np.linalg.norm(corners[0].reshape(4, 2) - truth.code_corners_px[3], axis=1)
    assert err.max() < 1.5  # OpenCV's own corner bias; the geometry itself is exact
    # pose of the truth is the composition of the world poses
    expected = res.camera_from_world @ transform(rot_z(math.radians(4)), [0.01, 0.005, 0.10])
    np.testing.assert_allclose(truth.camera_from_brick, expected, atol=1e-12)


def test_calibrating_from_rendered_chessboards_gives_the_camera_back():
    c = renderer.calibration_check(CAM)
    assert c["views"] == 27
    assert c["corner_max_px"] < 0.3
    assert c["rms_px"] < 0.1
    rel = np.abs(list(c["rel_err"].values()))
    assert rel.max() < 1e-3, f"fx fy cx cy relative errors {c['rel_err']}"


def test_board_object_points_are_opencv_order():
    b = Board(cols=9, rows=6, square=0.025)
    obj = b.object_points()
    assert obj.shape == (54, 3)
    np.testing.assert_allclose(obj[1], [0.025, 0, 0])
    np.testing.assert_allclose(obj[9], [0, 0.025, 0])


def test_stacked_brick_hides_dots_below_it_and_truth_centres_are_right():
    lay = layout("drick-dots-2x3")
    pose = transform(rot_z(0.2), [0.0, 0.0, 0.10])
    cam_pose = camera_over([0, 0, 0.1], 0.8, tilt_deg=10)
    free = render(Scene(CAM, cam_pose, Ground("concrete", 2), [BrickInstance(lay, pose, None)]))
    truth = free.bricks[0]
    hsv = cv2.cvtColor(free.image, cv2.COLOR_BGR2HSV)
    red = cv2.inRange(hsv, (0, 80, 70), (10, 255, 255)) | cv2.inRange(hsv, (170, 80, 70),
                                                                        (179, 255, 255))
    n, _, _, centroids = cv2.connectedComponentsWithStats(red)
    assert n - 1 == 4  # four red dots
    for c in centroids[1:]:
        d = np.linalg.norm(truth.dot_centers_px - c, axis=1).min()
        assert d < 0.3  # blob centroids sit on the true projected centres
    # a plain block laid over the +x end of the brick hides the dots at x = +0.10
    import trimesh

    block = trimesh.creation.box(extents=[0.12, 0.2, 0.05])
    block.apply_translation([0.10, 0, 0.03])
    hidden = render(Scene(CAM, cam_pose, Ground("concrete", 2), [BrickInstance(lay, pose, None)],
                          props=[Prop(block, pose, (150, 150, 150))]))
    hsv2 = cv2.cvtColor(hidden.image, cv2.COLOR_BGR2HSV)
    for k, center in enumerate(lay.dot_centers_m()):
        x, y = np.round(hidden.bricks[0].dot_centers_px[k]).astype(int)
        saturated = hsv2[y, x, 1] > 80
        assert saturated == (center[0] < 0.05), f"dot {k} at {center}"


def test_camera_over_points_the_optical_axis_at_the_target():
    T = camera_over([0.3, -0.2, 0.1], 1.5, tilt_deg=35, heading_deg=120, roll_deg=5)
    p = T[:3, :3] @ np.array([0.3, -0.2, 0.1]) + T[:3, 3]
    np.testing.assert_allclose(p, [0, 0, 1.5], atol=1e-12)
    # tilt: angle between the optical axis and straight down
    axis_world = T[:3, :3].T @ np.array([0, 0, 1.0])
    assert math.degrees(math.acos(-axis_world[2])) == pytest.approx(35, abs=1e-9)
    T2 = look_at([0, 0, 2], [0, 0, 0], up=[0, 1, 0])
    np.testing.assert_allclose(T2[:3, :3] @ [0, 1, 0], [0, -1, 0], atol=1e-12)  # +y is up


def test_effects_do_what_they_say():
    img = np.full((120, 160, 3), 100.0, np.float32)
    img[:, 80:] = 200.0
    assert apply_effects(img, Effects()).dtype == np.uint8
    noisy = apply_effects(img, Effects(noise_sigma=5.0, seed=1)).astype(float)
    assert np.std(noisy[:, :70] - 100) == pytest.approx(5.0, rel=0.05)
    bright = apply_effects(img, Effects(gain=1.2))
    assert bright[0, 0, 0] == 120 and bright[0, 100, 0] == 240
    dark = apply_effects(img, Effects(gamma=2.0))
    assert dark[0, 0, 0] == round(255 * (100 / 255) ** 2)
    streak = apply_effects(img, Effects(motion_px=12, motion_angle_deg=0)).astype(float)
    ramp = np.nonzero((streak[60, :, 0] > 101) & (streak[60, :, 0] < 199))[0]
    assert 10 <= ramp.size <= 13  # the edge is smeared over the streak's length
    jpg = apply_effects(img, Effects(jpeg_quality=60))
    assert jpg.shape == (120, 160, 3) and np.abs(jpg.astype(float) - img).mean() < 3
