"""Small codes: tag36h11 codes of 14–20 px at the far end of the working range, blurred,
found by the rescue (read with their blur, a few misread bits tolerated; the reader itself:
test_code_reading.py), the quads of contours OpenCV passes over, and the second look (twice
the size); never a brick that is not there."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drovisio.bench.aruco import Frame, _countable, _size_px, _visibility
from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector, ArucoParams
from drovisio.detect.code_reading import ring_quads
from drovisio.layout import (
    aruco_code_bits,
    aruco_dictionary_id,
    load_layouts,
    shipped_layouts_dir,
)
from drovisio.scenes import SceneSpec, gravity_in_camera, random_scene
from drovisio.synth import render

CAM = Camera.drone_webcam()
TAG36H11 = "DICT_APRILTAG_36h11"


@pytest.fixture(scope="module")
def far_frames(tag36h11_layouts) -> list[Frame]:
    # the far end of the range, blurred: most codes are 14-22 px across
    spec = SceneSpec(layouts=tag36h11_layouts, n_bricks=4, distance=(1.7, 2.2),
                     tilt_deg=(0.0, 30.0), blur_sigma_px=(0.5, 1.0))
    out = []
    for seed in range(24):
        scene, fx = random_scene(7000 + seed, spec, CAM)
        r = render(scene, fx, ss=3)
        out.append(Frame(r.image, r.bricks, gravity_in_camera(r.camera_from_world),
                         _visibility(scene), float(fx.blur_sigma_px)))
    return out


def _recall(frames, det) -> tuple[int, int, int, list[float]]:
    found = countable = false = 0
    sizes = []
    for fr in frames:
        seen = {(p.layout, p.instance) for p in det.detect(fr.image, gravity=fr.gravity)}
        truth = {(b.layout, b.instance): b for b in fr.bricks}
        false += len(seen - set(truth))
        for key, t in truth.items():
            size = _countable(t, fr, CAM.width, CAM.height)
            if size is not None:
                countable += 1
                found += key in seen
                sizes.append(size)
    return found, countable, false, sizes


def test_small_far_codes_are_found(far_frames, tag36h11_layouts):
    found, countable, false, sizes = _recall(far_frames,
                                             ArucoBrickDetector(CAM, tag36h11_layouts))
    # the set is what it claims: mostly codes under 20 px
    assert countable >= 60 and np.median(sizes) < 20.5, (countable, np.median(sizes))
    assert found / countable >= 0.95 and false == 0, (found, countable, false)
    # OpenCV's pass alone misses what the rescue, the ring quads and the second look add
    # (measured: 70 of 87 against 85)
    plain = ArucoBrickDetector(CAM, tag36h11_layouts,
                               ArucoParams(rescue=False, second_look_max=0))
    found0, _, false0, _ = _recall(far_frames, plain)
    assert found - found0 >= 10 and false0 == 0, (found, found0)


def test_bit_errors_tolerated_follow_the_codes_distances(tag36h11_layouts):
    det = ArucoBrickDetector(CAM, tag36h11_layouts)
    assert det._rescue_errors == {aruco_dictionary_id(TAG36H11): 3}
    # 4x4 codes are close to each other: a rescued reading must be exact
    four = ArucoBrickDetector(CAM, load_layouts([shipped_layouts_dir() /
                                                  "drick-aruco-centre.json"]))
    assert list(four._rescue_errors.values()) == [0]


def test_a_misread_quad_is_not_taken_for_another_code(tag36h11_layouts):
    # a code with 5 of its 36 bits flipped is too far from every code: not rescued
    det = ArucoBrickDetector(CAM, tag36h11_layouts)
    bits = aruco_code_bits(TAG36H11, 3).astype(np.uint8)
    rng = np.random.default_rng(1)
    inner = bits[1:-1, 1:-1].copy()
    flip = rng.choice(inner.size, 5, replace=False)
    inner.flat[flip] ^= 1
    bits[1:-1, 1:-1] = inner
    cell = 3
    img = np.full((120, 120), 200, np.uint8)
    code = np.kron(bits * 255, np.ones((cell, cell), np.uint8))
    img[40:40 + code.shape[0], 40:40 + code.shape[1]] = code
    e = 40 + code.shape[0] - 0.5
    quad = np.array([[[39.5, 39.5], [e, 39.5], [e, e], [39.5, e]]], np.float32)
    got, unread = det._rescue(img, quad, [], *[det._detectors[0][i] for i in (1, 2, 3)])
    assert got == [] and len(unread) == 1
    # with 2 flipped bits it is read as itself
    bits2 = aruco_code_bits(TAG36H11, 3).astype(np.uint8)
    bits2[2, 3] ^= 1
    bits2[5, 6] ^= 1
    img[40:40 + code.shape[0], 40:40 + code.shape[1]] = np.kron(bits2 * 255, np.ones(
        (cell, cell), np.uint8))
    got, _ = det._rescue(img, quad, [], *[det._detectors[0][i] for i in (1, 2, 3)])
    assert [c.marker_id for c in got] == [3] and _size_px(got[0].raw_corners) == 24


def test_a_code_whose_border_merges_with_a_pyramid_edge_is_found(tag36h11_layouts):
    # a rendered bench frame (drovisio bench aruco --dictionary DICT_APRILTAG_36h11 --bricks 4
    # --seed 5000): two sharp 22-px codes on a pyramid whose black border touches the shaded
    # side; OpenCV's thresholded contour is no quad there and nothing is even rejected
    spec = SceneSpec(layouts=tag36h11_layouts, n_bricks=4)
    scene, fx = random_scene(505017, spec, CAM)
    r = render(scene, fx, ss=3)
    gray = cv2.cvtColor(r.image, cv2.COLOR_BGR2GRAY)
    truth = {mid: c for b in r.bricks for mid, c in b.code_corners_px.items()}
    det = ArucoBrickDetector(CAM, tag36h11_layouts)
    cv_det = det._detectors[0][0]
    _, ids, rejected = cv_det.detectMarkers(gray)
    assert not {22, 23} & set(np.ravel(ids) if ids is not None else [])
    for mid in (22, 23):
        assert all(np.abs(np.asarray(q).reshape(4, 2).mean(axis=0)
                          - truth[mid].mean(axis=0)).max() > 3 for q in rejected)
    # a ring's hull is a quad near each (within 5 px: it takes in the pyramid's edge)
    rings = ring_quads(gray, 5, 12.0, 8.0, 40.0)
    for mid in (22, 23):
        assert min(np.abs(q.mean(axis=0) - truth[mid].mean(axis=0)).max() for q in rings) < 5
    poses = det.detect(r.image, gravity=gravity_in_camera(r.camera_from_world))
    pyramids = [p for p in poses if p.markers == [22, 23]]
    assert len(pyramids) == 1
    codes = {c.marker_id: c for c in det.last_codes}
    for mid in (22, 23):
        assert np.abs(codes[mid].refined.corners_px - truth[mid]).max() < 0.5
    # without the ring quads the brick is lost
    without = ArucoBrickDetector(CAM, tag36h11_layouts, ArucoParams(ring_quads_max=0))
    assert not [p for p in without.detect(r.image, gravity=gravity_in_camera(
        r.camera_from_world)) if 22 in p.markers]

