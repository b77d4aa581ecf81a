"""The colour-dot detector: stages, accuracy on rendered scenes, partial matches,
symmetry, gravity, and bad input. Heavy evaluation lives in ``drovisio bench dots``."""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.detect.dots import (
    DotDetector,
    DotsInputError,
    DotsState,
    LayoutNotSupported,
    detect_dots,
)
from drovisio.detect.dots.blobs import (
    BlobFilter,
    find_blobs,
    find_blobs_cc,
    find_blobs_multi,
    refine_centers,
)
from drovisio.detect.dots.color import (
    ClaheMap,
    ColorClassifier,
    clahe_value,
    clean_mask,
    threshold_color,
    to_hsv,
)
from drovisio.detect.dots.model import DotModel, occluded_dots
from drovisio.geometry import so3_exp
from drovisio.layout import (
    DEFAULT_PALETTE,
    load_layout,
    parse_layout,
    shipped_layouts_dir,
)
from drovisio.pose.batch import conic_center_offsets
from drovisio.scenes import SceneSpec, gravity_in_camera, random_scene
from drovisio.synth import (
    BrickInstance,
    Ground,
    Scene,
    camera_over,
    render,
    rot_z,
    transform,
)

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="module")
def drick():
    return load_layout(shipped_layouts_dir() / "drick-dots-2x3.json")


@pytest.fixture(scope="module")
def asym():
    return load_layout(DATA / "drick-dots-2x3-asym.json")


@pytest.fixture(scope="module")
def cam():
    return Camera.drone_webcam()


def _one_brick(cam, layout, yaw=0.3, xy=(0.0, 0.0), distance=0.9, tilt=20.0, heading=None,
               hidden=frozenset(), ground="gravel", ss=3):
    """One brick; by default seen from along its length (its pyramids hide no dot)."""
    if heading is None:
        heading = 90.0 + math.degrees(yaw)
    scene = Scene(camera=cam, camera_from_world=camera_over([xy[0], xy[1], 0.1], distance, tilt,
                                                            heading),
                  ground=Ground(ground, seed=1),
                  bricks=[BrickInstance(layout, transform(rot_z(yaw), [xy[0], xy[1], 0.1]),
                                        instance=None, hidden_markers=frozenset(hidden))])
    return render(scene, ss=ss)


def _errors(truth_T, pose, symmetric):
    R = cv2.Rodrigues(np.asarray(pose.rvec, float))[0]
    Rt, tt = truth_T[:3, :3], truth_T[:3, 3]
    E = Rt.T @ R
    yaw = math.degrees(math.atan2(E[1, 0] - E[0, 1], E[0, 0] + E[1, 1]))
    period = 180.0 if symmetric else 360.0
    yaw = (yaw + period / 2) % period - period / 2
    return (float(np.hypot(*(pose.tvec - tt)[:2])), float(abs(pose.tvec[2] - tt[2]) / tt[2]),
            abs(yaw))


# ================================================================================= stages
def test_hsv_threshold_wraps_red_hue():
    hsv = np.zeros((2, 4, 3), np.uint8)
    hsv[..., 1:] = 200
    hsv[0, :, 0] = [175, 5, 10, 11]      # red wraps: 170..179 and 0..10
    hsv[1, :, 0] = [169, 60, 80, 115]
    red = threshold_color(hsv, DEFAULT_PALETTE["red"])
    assert red[0].tolist() == [255, 255, 255, 0] and not red[1].any()
    blue = threshold_color(hsv, DEFAULT_PALETTE["blue"])
    assert blue[1].tolist() == [0, 0, 255, 255]


def test_classifier_equals_inrange_and_morphology_equals_open_close():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    img = cv2.resize(img, (320, 240), interpolation=cv2.INTER_NEAREST)
    hsv = to_hsv(img)
    specs = list(DEFAULT_PALETTE.values())
    for m, spec in zip(ColorClassifier(specs, v_floor=None).masks(hsv), specs):
        ref = threshold_color(hsv, spec)
        assert np.array_equal(m, ref)
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        want = cv2.morphologyEx(cv2.morphologyEx(ref, cv2.MORPH_OPEN, k), cv2.MORPH_CLOSE, k)
        assert np.array_equal(clean_mask(ref, 3), want)


def test_clahe_map_matches_opencv():
    rng = np.random.default_rng(1)
    v = cv2.GaussianBlur(rng.integers(0, 256, (97, 131), dtype=np.uint8), (0, 0), 3)
    ref = clahe_value(cv2.merge([v, v, v]))[..., 2]
    cm = ClaheMap(v, stride=1)
    ys, xs = np.mgrid[0:v.shape[0], 0:v.shape[1]]
    out = cm(xs.ravel(), ys.ravel(), v.ravel()).reshape(v.shape)
    assert np.abs(np.rint(out) - ref).max() <= 1


def test_blob_filters_and_connected_components_agree():
    mask = np.zeros((200, 300), np.uint8)
    cv2.circle(mask, (40, 40), 8, 255, -1)                          # a dot
    cv2.ellipse(mask, (120, 50), (12, 5), 30, 0, 360, 255, -1)      # a dot seen obliquely
    cv2.rectangle(mask, (200, 20), (230, 50), 255, -1)              # a square: not a dot
    cv2.line(mask, (20, 150), (120, 170), 255, 3)                   # a line
    cv2.circle(mask, (220, 150), 15, 255, 4)                        # a ring
    cv2.ellipse(mask, (60, 110), (10, 10), 0, 0, 200, 255, -1)      # a half disc
    blobs, _ = find_blobs(mask, 0, BlobFilter())
    ref = find_blobs_cc(mask, 0, BlobFilter())
    got = sorted(map(tuple, np.round(blobs.xy, 1)))
    assert len(got) == 2
    assert np.allclose(got, sorted(map(tuple, np.round(ref.xy, 1))), atol=0.2)
    assert np.allclose(got[0], (40, 40), atol=0.3) and np.allclose(got[1], (120, 50), atol=0.3)
    multi, _ = find_blobs_multi([mask, np.zeros_like(mask)], BlobFilter())
    assert len(multi) == 2 and set(multi.color.tolist()) == {0}


def test_subpixel_centres_of_blurred_ellipses():
    rng = np.random.default_rng(2)
    img = np.full((120, 400, 3), 150, np.float32)
    centres = [(50.3, 60.7, 6, 4), (150.55, 58.2, 3.2, 2.6), (260.9, 61.4, 12, 7)]
    shift = 8
    for cx, cy, a, b in centres:
        # anti-aliased red ellipses placed at sub-pixel positions, on grey
        big = np.zeros((120 * shift, 400 * shift), np.uint8)
        centre = (round((cx + 0.5) * shift - 0.5), round((cy + 0.5) * shift - 0.5))
        cv2.ellipse(big, centre, (int(a * shift), int(b * shift)), 25, 0, 360, 255, -1)
        cov = cv2.resize(big.astype(np.float32) / 255, (400, 120), interpolation=cv2.INTER_AREA)
        img = img * (1 - cov[..., None]) + np.array([40, 40, 210], np.float32) * cov[..., None]
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + rng.normal(0, 2, img.shape)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    mask = clean_mask(threshold_color(to_hsv(img), DEFAULT_PALETTE["red"]))
    blobs, _ = find_blobs(mask, 0, BlobFilter(min_area=5))
    ref, contrast = refine_centers(img, blobs)
    for cx, cy, _, _ in centres:
        k = int(np.argmin(np.hypot(*(blobs.xy - (cx, cy)).T)))
        assert np.hypot(*(ref[k] - (cx, cy))) < 0.06, (cx, cy, ref[k])
        assert contrast[k] > 50


def test_conic_centre_offset_is_the_projected_disc_centroid():
    R = so3_exp(np.array([[2.7, 0.6, 0.3]]))
    t = np.array([[0.08, -0.12, 0.32]])
    X = np.array([[[0.1, 0.05, 0.0]]])
    off = conic_center_offsets(X, np.array([[[0, 0, 1.0]]]), np.array([[0.01]]), R, t)
    th = np.linspace(0, 2 * np.pi, 4001)[:-1]
    P = X[0, 0] + 0.01 * np.stack([np.cos(th), np.sin(th), 0 * th], 1)
    Y = P @ R[0].T + t[0]
    x, y = Y[:, 0] / Y[:, 2], Y[:, 1] / Y[:, 2]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cr = x * y1 - x1 * y
    A = cr.sum() / 2
    cen = np.array([((x + x1) * cr).sum() / (6 * A), ((y + y1) * cr).sum() / (6 * A)])
    Yc = X[0, 0] @ R[0].T + t[0]
    assert np.allclose(off[0, 0], cen - Yc[:2] / Yc[2], atol=1e-9)
    assert np.linalg.norm(off[0, 0]) * 554 > 0.05  # a visible effect at this range


# ================================================================================= layouts
def test_dot_models(drick, asym):
    m = DotModel.from_layout(drick, {"red": 0, "blue": 1})
    assert m.sym_perm is not None and sorted(m.sym_perm.tolist()) == list(range(6))
    assert m.occluders.shape[0] > 0                       # the pyramids
    assert DotModel.from_layout(asym, {"red": 0, "blue": 1}).sym_perm is None
    # the pyramids hide the far row's outer dots when looking across the brick (from -y)
    T = camera_over([0, 0, 0], 1.0, 25, 0)
    hid = occluded_dots(m, T[None, :3, :3], T[None, :3, 3])[0]
    assert hid.tolist() == [True, False, True, False, False, False]
    T = camera_over([0, 0, 0], 1.0, 0, 0)
    assert not occluded_dots(m, T[None, :3, :3], T[None, :3, 3]).any()


def test_unsupported_layouts_are_named(drick):
    data = drick.to_dict()
    data["markers"] = data["markers"][:3]
    data["name"] = "three-dots"
    data["symmetry"] = "none"
    with pytest.raises(LayoutNotSupported, match="three-dots.*at least 4 dots"):
        DotModel.from_layout(parse_layout(data), {"red": 0, "blue": 1})


def test_greedy_assignment_keeps_disjoint_bricks(drick):
    """Two bricks whose blob indices have equal sums must not be merged as duplicates."""
    from drovisio.detect.dots.match import Hypotheses, assign_greedy

    m = DotModel.from_layout(drick, {"red": 0, "blue": 1})
    rows = np.array([[0, 11, 1, 3, 12, -1], [0, 11, 1, 3, 12, -1], [6, 13, 4, -1, -1, 5],
                     [5, -1, -1, 4, 13, 6], [0, 13, 1, 3, -1, -1]])
    h = Hypotheses(m, rows, np.array([5.0, 4.9, 3.9, 3.8, 3.7]), np.ones(5),
                   np.zeros((5, 2, 2)), np.zeros((5, 2)))
    got = assign_greedy([h], 20, 4)
    assert [c.assign.tolist() for c in got] == [[0, 11, 1, 3, 12, -1], [6, 13, 4, -1, -1, 5]]


def test_any_planar_layout(cam):
    """An irregular five-dot layout (no lines), three colours, several bricks in a frame."""
    data = {
        "schema": "drovisio/marker-layout@1", "name": "test-five-dots", "units": "m",
        "dimensions": [0.3, 0.2, 0.05], "symmetry": "none",
        "markers": [{"kind": "dot", "color": c, "diameter": 0.025, "center": [x, y, 0.0]}
                    for c, x, y in [("red", -0.11, 0.06), ("green", 0.02, 0.07),
                                    ("blue", 0.12, -0.01), ("red", 0.05, -0.07),
                                    ("green", -0.08, -0.05)]]}
    lay = parse_layout(data)
    bricks = [BrickInstance(lay, transform(rot_z(a), [x, y, 0.05]), instance=None)
              for a, x, y in [(0.3, -0.25, 0.0), (2.5, 0.15, 0.12), (-1.2, 0.1, -0.2)]]
    scene = Scene(camera=cam, camera_from_world=camera_over([0, 0, 0.05], 1.1, 15, 40),
                  ground=Ground("concrete", 3), bricks=bricks)
    res = render(scene, ss=2)
    poses = detect_dots(res.image, cam, [lay], gravity=gravity_in_camera(res.camera_from_world))
    assert len(poses) == 3
    for truth in res.bricks:
        T = truth.camera_from_brick
        p = min(poses, key=lambda p: np.linalg.norm(p.tvec - T[:3, 3]))
        lat, depth, yaw = _errors(T, p, False)
        assert lat < 0.01 and depth < 0.015 and yaw < 1.0 and not p.symmetric


# ================================================================================= detection
@pytest.fixture(scope="module")
def rendered(drick, cam):
    """A few random scenes like the benchmark's (gravity known)."""
    out = []
    for seed in (3, 11, 19, 27):
        scene, fx = random_scene(seed, SceneSpec(layouts=[drick], n_bricks=3, props=1), cam)
        res = render(scene, fx, ss=3)
        out.append((scene, res))
    return out


def test_accuracy_on_rendered_scenes(drick, cam, rendered):
    det = DotDetector(cam, [drick])
    n_truth = n_found = 0
    for _scene, res in rendered:
        poses = det.detect(res.image, gravity=gravity_in_camera(res.camera_from_world))
        for truth in res.bricks:
            T = truth.camera_from_brick
            if T[2, 3] > 2.0:
                continue
            n_truth += 1
            match = [p for p in poses if np.linalg.norm(p.tvec - T[:3, 3]) < 0.05]
            if not match:
                continue
            n_found += 1
            p = match[0]
            lat, depth, yaw = _errors(T, p, True)
            assert lat < 0.01 and depth < 0.015 and yaw < 1.0, (lat, depth, yaw)
            assert p.symmetric and p.method == "dots" and p.instance is None
            assert not p.ambiguous                       # gravity resolves it
            assert len(p.markers) >= 4 and p.image_points.shape == (len(p.markers), 2)
            js = p.to_json()
            assert js["symmetric"] is True and js["markers"] == sorted(js["markers"])
        assert len(poses) <= len(res.bricks)             # no false bricks
    assert n_truth >= 6 and n_found >= n_truth - 1


def test_centres_are_unbiased(drick, cam, rendered):
    """The reported image points estimate the projected circle centres (BrickTruth)."""
    det = DotDetector(cam, [drick])
    m = det.models[0]
    errs = []
    for _scene, res in rendered:
        for p in det.detect(res.image, gravity=gravity_in_camera(res.camera_from_world)):
            for truth in res.bricks:
                if np.linalg.norm(p.tvec - truth.camera_from_brick[:3, 3]) < 0.05:
                    mk = np.asarray(p.markers)
                    e1 = p.image_points - truth.dot_centers_px[mk]
                    e2 = p.image_points - truth.dot_centers_px[m.sym_perm[mk]]
                    errs.append(e1 if np.abs(e1).sum() < np.abs(e2).sum() else e2)
    e = np.concatenate(errs)
    assert len(e) >= 30
    assert np.linalg.norm(e.mean(axis=0)) < 0.1
    assert np.sqrt((e ** 2).sum(axis=1).mean()) < 0.35


def test_partial_matches_report_the_dots_used(asym, cam):
    for hidden in ({1}, {0, 5}, {3, 4}):      # {3, 4}: three in a line plus one
        res = _one_brick(cam, asym, hidden=hidden)
        T = res.bricks[0].camera_from_brick
        poses = detect_dots(res.image, cam, [asym], gravity=gravity_in_camera(
            res.camera_from_world))
        assert len(poses) == 1, hidden
        p = poses[0]
        assert set(p.markers) == set(range(6)) - hidden
        lat, depth, yaw = _errors(T, p, False)
        assert lat < 0.01 and depth < 0.015 and yaw < 1.0, (hidden, lat, depth, yaw)
        assert not p.symmetric


def test_asymmetric_layout_yaw_is_not_folded(asym, cam):
    for yaw in (0.4, 0.4 + math.pi):
        res = _one_brick(cam, asym, yaw=yaw)
        p = detect_dots(res.image, cam, [asym])[0]
        assert _errors(res.bricks[0].camera_from_brick, p, False)[2] < 1.0


def test_symmetric_yaw_is_canonical_and_stable(drick, cam):
    # the same brick turned by a half-turn gives the same report
    a = _one_brick(cam, drick, yaw=0.5)
    b = _one_brick(cam, drick, yaw=0.5 + math.pi)
    pa = detect_dots(a.image, cam, [drick])[0]
    pb = detect_dots(b.image, cam, [drick])[0]
    assert pa.symmetric and pb.symmetric
    Ra = cv2.Rodrigues(pa.rvec)[0]
    assert Ra[0, 0] >= 0                              # canonical: brick x toward image right
    assert np.allclose(pa.rvec, pb.rvec, atol=0.02) and np.allclose(pa.tvec, pb.tvec, atol=0.003)
    # in a stream, a yaw slowly crossing the canonical boundary does not flip
    state = DotsState()
    xs = []
    for yaw in np.radians([80, 86, 92, 98]):
        res = _one_brick(cam, drick, yaw=yaw, tilt=0.0, heading=0.0, ground="plain", ss=2)
        p = detect_dots(res.image, cam, [drick], state=state)[0]
        xs.append(cv2.Rodrigues(p.rvec)[0][:, 0])
    assert all(float(xs[k] @ xs[k + 1]) > 0.9 for k in range(len(xs) - 1))


def test_gravity_resolves_the_planar_ambiguity(drick, cam):
    # small and far, viewed off-axis: the mirrored tilt reprojects almost as well
    res = _one_brick(cam, drick, yaw=1.0, xy=(0.45, 0.3), distance=2.2, tilt=10.0, heading=200,
                     ground="grass")
    T = res.bricks[0].camera_from_brick
    free = detect_dots(res.image, cam, [drick])
    grav = detect_dots(res.image, cam, [drick], gravity=gravity_in_camera(res.camera_from_world))
    assert len(free) == 1 and len(grav) == 1
    R = cv2.Rodrigues(grav[0].rvec)[0]
    assert not grav[0].ambiguous
    assert math.degrees(math.acos(np.clip(R[:, 2] @ T[:3, 2], -1, 1))) < 5
    p = free[0]
    Rf = cv2.Rodrigues(p.rvec)[0]
    wrong = math.degrees(math.acos(np.clip(Rf[:, 2] @ T[:3, 2], -1, 1))) > 10
    assert p.ambiguous or not wrong                   # never an unflagged flip
    if p.ambiguous:
        assert len(p.alternatives) == 1 and "alternatives" in p.to_json()


def test_several_bricks_and_clutter(drick, cam):
    scene, fx = random_scene(5, SceneSpec(layouts=[drick], n_bricks=6, props=3), cam)
    res = render(scene, fx, ss=3)
    poses = detect_dots(res.image, cam, [drick], gravity=gravity_in_camera(res.camera_from_world))
    near = [b for b in res.bricks if b.camera_from_brick[2, 3] < 1.6]
    assert len(poses) >= len(near) - 1 and len(poses) <= len(res.bricks)
    scene, fx = random_scene(8, SceneSpec(layouts=[drick], n_bricks=0, props=8,
                                          grounds=("clutter",)), cam)
    res = render(scene, fx, ss=2)
    assert detect_dots(res.image, cam, [drick]) == []


# ================================================================================= bad input
def test_bad_input_gives_a_clear_result_or_message(drick, cam, caplog):
    with pytest.raises(DotsInputError, match="None"):
        detect_dots(None, cam, [drick])
    with pytest.raises(DotsInputError, match="uint8"):
        detect_dots(np.zeros((480, 640, 3), np.float32), cam, [drick])
    with pytest.raises(DotsInputError, match="shape"):
        detect_dots(np.zeros((480, 640, 5), np.uint8), cam, [drick])
    state = DotsState()
    with caplog.at_level(logging.WARNING, logger="drovisio.detect.dots"):
        assert detect_dots(np.full((480, 640), 128, np.uint8), cam, [drick], state=state) == []
    assert "greyscale" in state.note and "greyscale" in caplog.text
    assert detect_dots(np.zeros((8, 8, 3), np.uint8), cam, [drick]) == []        # tiny
    assert detect_dots(np.zeros((2, 3, 3), np.uint8), cam, [drick]) == []
    assert detect_dots(np.full((480, 640, 3), 255, np.uint8), cam, [drick]) == []  # saturated
    assert detect_dots(np.zeros((480, 640, 3), np.uint8), cam, [drick]) == []     # black


def test_no_dots_and_one_colour_missing(drick, cam):
    res = _one_brick(cam, drick, hidden={1, 4}, ss=2)    # both blue dots unpainted: 4 reds
    poses = detect_dots(res.image, cam, [drick])
    assert len(poses) == 1 and sorted(poses[0].markers) in ([0, 2, 3, 5],)
    img = res.image.copy()
    hsv = to_hsv(img)
    red = threshold_color(hsv, DEFAULT_PALETTE["red"]) > 0
    img[red] = (150, 150, 150)                            # now no dots at all
    assert detect_dots(img, cam, [drick]) == []
    res = _one_brick(cam, drick, hidden={0, 2, 3, 5}, ss=2)   # the blue pair only
    assert detect_dots(res.image, cam, [drick]) == []
    bgra = cv2.cvtColor(_one_brick(cam, drick, ss=2).image, cv2.COLOR_BGR2BGRA)
    assert len(detect_dots(bgra, cam, [drick])) == 1


def test_bench_help():
    from drovisio.bench.dots import main

    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0


def test_the_cached_detector_is_one_per_lens_model():
    """Two cameras that differ only by their lens model (same K, same four coefficients) get
    their own detectors: one that projects through the other's model would be wrong."""
    from drovisio.detect.dots.detector import _detector_for

    lay = load_layout(shipped_layouts_dir() / "drick-dots-2x3.json")
    d = [0.03, -0.012, 0.004, -0.0008]
    fish = Camera.from_fov(640, 480, 90.0, dist=d, model="fisheye")
    pin = dataclasses.replace(fish, model="plumb_bob")
    assert np.array_equal(pin.K, fish.K) and np.array_equal(pin.dist, fish.dist)
    a, b = _detector_for(pin, [lay], None), _detector_for(fish, [lay], None)
    assert a is not b and a.camera.model == "plumb_bob" and b.camera.model == "fisheye"
    assert _detector_for(pin, [lay], None) is a
