"""drovisio.pose: PnP with IPPE's flip ambiguity resolved by evidence, refinement, covariance."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.pose import (
    PoseEvidence,
    PoseHistory,
    is_planar,
    rotation_angle_deg,
    solve_brick_pose,
    tilt_deg,
    yaw_about_axis_deg,
)


@pytest.fixture(scope="module")
def cam() -> Camera:
    return Camera.drone_webcam()


def _square(size: float = 0.065, z: float = 0.0, cx: float = 0.0) -> np.ndarray:
    h = size / 2
    return np.array([[cx - h, h, z], [cx + h, h, z], [cx + h, -h, z], [cx - h, -h, z]])


def _pose(rvec, tvec) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    T[:3, 3] = tvec
    return T


def _looking_down(yaw_deg: float, tilt_deg_: float, t) -> np.ndarray:
    """camera_from_brick of a brick lying flat, seen by a camera tilted by tilt_deg_."""
    Rz = cv2.Rodrigues(np.array([0, 0, math.radians(yaw_deg)]))[0]
    Rx = cv2.Rodrigues(np.array([math.pi + math.radians(tilt_deg_), 0, 0]))[0]  # z toward cam
    T = np.eye(4)
    T[:3, :3] = Rx @ Rz
    T[:3, 3] = t
    return T


def test_exact_points_give_the_pose_back(cam):
    T = _looking_down(30, 20, [0.1, -0.05, 1.2])
    for obj in (_square(), _square(z=0.02), np.concatenate([_square(cx=-0.075, z=0.02),
                                                            _square(cx=0.075, z=0.02)])):
        img = cam.project_from(obj, T)
        g = -T[:3, 2]  # the brick's up is -gravity
        res = solve_brick_pose(obj, img, cam, gravity=g)
        assert res is not None and not res.ambiguous
        assert rotation_angle_deg(res.camera_from_object()[:3, :3], T[:3, :3]) < 1e-4
        assert np.allclose(res.tvec, T[:3, 3], atol=1e-7)
        assert res.rmse_px < 1e-5


def test_non_planar_points(cam):
    obj = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1], [0.1, 0.1, 0.05],
                    [0.05, -0.05, 0.02]], float)
    assert not is_planar(obj)
    T = _pose([0.3, -0.2, 0.1], [0.05, 0.02, 0.9])
    res = solve_brick_pose(obj, cam.project_from(obj, T), cam)
    assert res is not None and res.decided_by == "unique"
    assert rotation_angle_deg(res.camera_from_object()[:3, :3], T[:3, :3]) < 1e-4


def _ambiguous_case(cam, seed: int):
    """A small square far away and nearly head-on: IPPE's two poses fit about equally."""
    T = _looking_down(40, 12, [0.15, 0.1, 2.2])
    obj = _square()
    rng = np.random.default_rng(seed)
    img = cam.project_from(obj, T) + rng.normal(0, 0.25, (4, 2))
    return T, obj, img


def test_flip_without_evidence_is_flagged_not_guessed(cam):
    flagged = 0
    for seed in range(12):
        T, obj, img = _ambiguous_case(cam, seed)
        res = solve_brick_pose(obj, img, cam, points_cov=0.25)
        err = rotation_angle_deg(res.camera_from_object()[:3, :3], T[:3, :3])
        if res.ambiguous:
            flagged += 1
            assert res.decided_by == "none" and len(res.alternatives) == 1
            alt = res.alternatives[0]
            alt_err = rotation_angle_deg(cv2.Rodrigues(alt.rvec.reshape(3, 1))[0], T[:3, :3])
            assert min(err, alt_err) < 15.0  # the truth is one of the two (noisy: 0.25 px)
        else:
            assert err < 20.0, f"seed {seed}: a flip decided by {res.decided_by}"
    assert flagged >= 6  # such views are mostly undecidable from the image alone


def test_gravity_resolves_the_flip(cam):
    for seed in range(12):
        T, obj, img = _ambiguous_case(cam, seed)
        g = -T[:3, 2]
        res = solve_brick_pose(obj, img, cam, points_cov=0.25, gravity=g, gravity_prior_deg=5)
        assert not res.ambiguous and res.decided_by == "gravity"
        assert rotation_angle_deg(res.camera_from_object()[:3, :3], T[:3, :3]) < 5.0
        assert tilt_deg(res.camera_from_object()[:3, :3], g) < 5.0


def test_reference_up_and_previous_pose_resolve_the_flip(cam):
    T, obj, img = _ambiguous_case(cam, 3)
    res = solve_brick_pose(obj, img, cam, points_cov=0.25,
                           evidence=PoseEvidence(reference_up=T[:3, 2]))
    assert res.decided_by == "reference"
    assert rotation_angle_deg(res.camera_from_object()[:3, :3], T[:3, :3]) < 10.0
    rvec = cv2.Rodrigues(T[:3, :3])[0].ravel()
    res = solve_brick_pose(obj, img, cam, points_cov=0.25,
                           evidence=PoseEvidence(previous=(rvec, T[:3, 3])))
    assert res.decided_by == "previous"
    assert rotation_angle_deg(res.camera_from_object()[:3, :3], T[:3, :3]) < 10.0


def test_covariance_matches_the_scatter(cam):
    """The 6×6 covariance predicts the spread of poses under the stated corner noise."""
    T = _looking_down(10, 25, [0.05, 0.0, 0.8])
    obj = np.concatenate([_square(cx=-0.075, z=0.02), _square(cx=0.075, z=0.02)])
    clean = cam.project_from(obj, T)
    g = -T[:3, 2]
    rng = np.random.default_rng(1)
    sigma = 0.3
    poses, covs = [], []
    for _ in range(150):
        res = solve_brick_pose(obj, clean + rng.normal(0, sigma, clean.shape), cam,
                               points_cov=sigma, gravity=g)
        poses.append(np.concatenate([res.rvec, res.tvec]))
        covs.append(res.covariance)
    P = np.array(poses)
    emp = np.cov(P.T)
    pred = np.mean(covs, axis=0)
    ratio = np.diag(emp) / np.diag(pred)
    assert np.all(ratio > 0.4) and np.all(ratio < 2.5), ratio
    assert np.allclose(pred, pred.T)


def test_angles():
    R0 = np.eye(3)
    R1 = cv2.Rodrigues(np.array([0, 0, math.radians(7)]))[0]
    assert yaw_about_axis_deg(R0, R1) == pytest.approx(7.0, abs=1e-9)
    assert yaw_about_axis_deg(R1, R0) == pytest.approx(-7.0, abs=1e-9)
    R2 = cv2.Rodrigues(np.array([math.radians(30), 0, 0]))[0]
    assert yaw_about_axis_deg(R0, R2) == pytest.approx(0.0, abs=1e-9)
    assert rotation_angle_deg(R0, R2) == pytest.approx(30.0)
    assert tilt_deg(R2, np.array([0, 0, -1.0])) == pytest.approx(30.0)


def test_too_few_points_is_an_error(cam):
    with pytest.raises(ValueError, match="at least 4"):
        solve_brick_pose(np.zeros((3, 3)), np.zeros((3, 2)), cam)


def test_history_forgets_old_poses():
    h = PoseHistory(max_age=2)
    h.next_frame()
    h.update(("a", 1), np.zeros(3), np.ones(3))
    h.next_frame()
    assert h.previous(("a", 1)) is not None
    h.next_frame()
    h.next_frame()
    assert h.previous(("a", 1)) is None
    assert h.previous(("b", 0)) is None


@pytest.mark.parametrize("cam_name", ["webcam", "fisheye"])
def test_one_wrong_corner_does_not_carry_the_pose(cam, cam_name):
    # two 6.5-cm codes of a drick's pyramids at 1.3 m, corners with 0.2 px noise and one
    # corner 4 px off (a fit caught on the code's surroundings): the Huber weights keep the
    # pose close to the one the other seven corners give (measured, median lateral error:
    # 1.1 mm against 3.6 mm through the webcam, 23 against 63 mm 57° off-axis through the
    # fisheye)
    from drovisio.bench.lens import FISHEYE_150

    camera = cam if cam_name == "webcam" else FISHEYE_150
    T = _looking_down(25, 15, [0.15, -0.1, 1.3] if cam_name == "webcam" else [1.4, 0.9, 0.9])
    obj = np.concatenate([_square(cx=-0.075, z=0.02), _square(cx=0.075, z=0.02)])
    rng = np.random.default_rng(4)
    lat_robust, lat_plain = [], []
    for _ in range(20):
        img = camera.project_from(obj, T) + rng.normal(0, 0.2, (8, 2))
        img[5] += [2.8, -2.8]
        res = solve_brick_pose(obj, img, camera, gravity=-T[:3, 2], default_sigma_px=0.2)
        lat_robust.append(float(np.linalg.norm(res.tvec[:2] - T[:2, 3])))
        # the same without re-weighting: a plain least-squares fit of all eight corners
        from drovisio.pose import solve as solve_mod

        keep = solve_mod.ROBUST_MIN_POINTS
        solve_mod.ROBUST_MIN_POINTS = 10 ** 9
        try:
            res0 = solve_brick_pose(obj, img, camera, gravity=-T[:3, 2], default_sigma_px=0.2)
        finally:
            solve_mod.ROBUST_MIN_POINTS = keep
        lat_plain.append(float(np.linalg.norm(res0.tvec[:2] - T[:2, 3])))
    assert np.median(lat_robust) < 0.6 * np.median(lat_plain), (np.median(lat_robust),
                                                               np.median(lat_plain))
