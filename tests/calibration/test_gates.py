"""Per-view gates: sharpness (motion blur), size, stillness, novelty."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from drovisio.calibration.board import detect
from drovisio.calibration.gates import (
    corner_motion_px,
    gate_novel,
    gate_sharpness,
    gate_size,
    gate_still,
)
from drovisio.calibration.synthetic import DEFAULT_BOARD, calibration_poses


@pytest.fixture(scope="module")
def sharp_and_blurred(true_camera):
    from drovisio.synth import Effects, render_chessboard

    T = calibration_poses(true_camera, 1, seed=5)[0]
    out = {}
    for key, fx in {"sharp": Effects(noise_sigma=1.0, seed=1),
                    "motion13": Effects(motion_px=13, noise_sigma=1.0, seed=1),
                    "motion13_diag": Effects(motion_px=13, motion_angle_deg=60, noise_sigma=1.0,
                                             seed=1)}.items():
        img, truth, _ = render_chessboard(true_camera, T, DEFAULT_BOARD.cols, DEFAULT_BOARD.rows,
                                          DEFAULT_BOARD.square, effects=fx)
        out[key] = (img, truth)
    return out


def test_sharp_view_accepted(sharp_and_blurred):
    img, _ = sharp_and_blurred["sharp"]
    det = detect(img, DEFAULT_BOARD)
    g, es = gate_sharpness(img, det, DEFAULT_BOARD)
    assert g.ok and es.width_px < 2.0, es  # measured 1.3 px


@pytest.mark.parametrize("key", ["motion13", "motion13_diag"])
def test_motion_blur_13px_rejected_although_detected(sharp_and_blurred, key):
    img, _ = sharp_and_blurred[key]
    det = detect(img, DEFAULT_BOARD)
    assert det is not None  # it still detects...
    g, es = gate_sharpness(img, det, DEFAULT_BOARD)
    assert not g.ok and es.width_px > 8.0  # ...but edges are ~10 px wide
    assert "motion blur" in g.reason and "still" in g.reason


def test_opencv_sample_views_are_sharp(opencv_images, opencv_board):
    for name, img in opencv_images.items():
        g, es = gate_sharpness(img, detect(img, opencv_board), opencv_board)
        assert g.ok, (name, g.reason)  # measured 2.2–3.2 px


def _shifted(det, dx, dy=0.0):
    return replace(det, corners=det.corners + [dx, dy])


def test_size_gate(sharp_and_blurred):
    det = detect(sharp_and_blurred["sharp"][0], DEFAULT_BOARD)
    assert gate_size(det).ok
    assert not gate_size(replace(det, square_px=4.0)).ok


def test_stillness(sharp_and_blurred):
    det = detect(sharp_and_blurred["sharp"][0], DEFAULT_BOARD)
    assert not gate_still(None, det).ok
    assert gate_still(det, _shifted(det, 0.4, -0.3)).ok
    g = gate_still(det, _shifted(det, 3.0))
    assert not g.ok and "moving" in g.reason and math.isclose(g.value, 3.0, abs_tol=1e-6)
    # the same board labelled from the other end (a 180° turn of the labels) is the same board
    flipped = replace(det, corners=det.corners[::-1].copy())
    assert corner_motion_px(det, flipped) < 1e-9


def test_novelty(sharp_and_blurred):
    det = detect(sharp_and_blurred["sharp"][0], DEFAULT_BOARD)
    assert gate_novel(det, []).ok
    same = gate_novel(_shifted(det, 5.0), [det])
    assert not same.ok and "too similar" in same.reason
    assert gate_novel(_shifted(det, 60.0), [det]).ok
    # same place but turned 20° more: new information
    assert gate_novel(_shifted(det, 5.0), [det], tilt_deg=35.0, kept_tilts_deg=[15.0]).ok


def test_charuco_sharpness_is_measured_in_the_margin_around_the_markers():
    """On a ChArUco board the white squares hold markers, so a square side has only 1/8 of a
    square of white beside it: the edge is fitted as a blurred bar of that width. Sharp
    views (including one half outside the image) pass; defocus σ = 1.5 px and an 8 px motion
    streak are rejected."""
    from drovisio.calibration.board import parse_board
    from drovisio.camera import Camera
    from drovisio.synth import Effects, render_charuco, transform
    from drovisio.synth_samples import calibration_poses as sample_poses

    cam = Camera.drone_webcam()
    board = parse_board("charuco:9x6:DICT_4X4_50", 0.025)
    P = sample_poses(cam, 0.025)
    poses = [P[0], P[3], P[9] @ transform(None, [-0.15, 0.0, 0.0]), P[15]]

    def widths(fx):
        out = []
        for T in poses:
            img, _, _ = render_charuco(cam, T, board.charuco_board(), 0.025, fx, ss=2)
            det = detect(img, board)
            if det is not None:
                g, es = gate_sharpness(img, det, board)
                out.append((g.ok, es.width_px))
        return out

    sharp = widths(Effects(blur_sigma_px=0.6, noise_sigma=1.5, seed=2))
    assert len(sharp) == 4 and all(ok and w < 3.6 for ok, w in sharp), sharp
    for fx in (Effects(blur_sigma_px=1.5, noise_sigma=1.5, seed=3),
               Effects(blur_sigma_px=0.6, motion_px=8, motion_angle_deg=30, noise_sigma=1.5,
                       seed=4)):
        got = widths(fx)
        assert got and not any(ok for ok, _ in got), got
