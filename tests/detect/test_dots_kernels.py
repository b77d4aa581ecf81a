"""The dot detector's compiled kernels (numba) against the numpy reference implementations
they replace, on rendered frames, and the whole detector with the kernels on and off."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.detect.dots import DotDetector
from drovisio.detect.dots import kernels as K
from drovisio.detect.dots.blobs import _measure, find_blobs_multi, refine_centers
from drovisio.detect.dots.color import ClaheMap, clean_mask
from drovisio.detect.dots.match import (
    BlobGeometry,
    assign_greedy,
    generate_hypotheses,
)
from drovisio.detect.dots.model import occluded_dots
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.pose import batch as dots_pose
from drovisio.scenes import SceneSpec, gravity_in_camera, random_scene
from drovisio.synth import render

pytestmark = pytest.mark.skipif(not K.AVAILABLE, reason="numba is not installed here (or DROVISIO_NUMBA=0)")


@pytest.fixture(autouse=True)
def _kernels_back_on():
    yield
    K.set_enabled(True)


@pytest.fixture(scope="module")
def drick():
    return load_layout(shipped_layouts_dir() / "drick-dots-2x3.json")


@pytest.fixture(scope="module")
def cam():
    return Camera.drone_webcam()


@pytest.fixture(scope="module")
def frames(drick, cam):
    """Rendered frames: bricks on gravel / grass / photo clutter, and clutter alone."""
    out = []
    for seed, n, grounds in ((2, 6, ("gravel",)), (7, 4, ("grass",)), (13, 5, ("clutter",)),
                             (21, 0, ("clutter",))):
        scene, fx = random_scene(seed, SceneSpec(layouts=[drick], n_bricks=n, props=3,
                                                 grounds=grounds), cam)
        res = render(scene, fx, ss=2)
        out.append((res.image, gravity_in_camera(res.camera_from_world)))
    return out


def _both(fn, *args, **kwargs):
    """fn(*args, **kwargs) with the kernels on, then off (numpy)."""
    K.set_enabled(True)
    a = fn(*args, **kwargs)
    K.set_enabled(False)
    b = fn(*args, **kwargs)
    K.set_enabled(True)
    return a, b


def _masks(det, img):
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    return hsv, [clean_mask(m, det.config.morph_kernel_px) for m in det.classifier.masks(hsv)]


def test_contour_measures_and_blobs(drick, cam, frames):
    det = DotDetector(cam, [drick])
    n_checked = 0
    for img, _ in frames:
        hsv, masks = _masks(det, img)
        for k, m in enumerate(masks):
            cs, _ = cv2.findContours(m, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
            if not cs:
                continue
            a, b = _both(_measure, list(cs), k, m.shape, flt=det.blob_filter)
            for name in ("x", "y", "area", "a", "b", "angle", "perimeter", "circularity",
                         "fill", "ellipse_err", "cov"):
                np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-9,
                                           atol=1e-9, err_msg=name)
            assert np.array_equal(a.bbox, b.bbox) and np.array_equal(a.border, b.border)
            # convexity, where measured, is cv2's contour area / hull area
            for j in np.flatnonzero(~np.isnan(a.convexity))[:40].tolist():
                c = cs[j]
                hull = cv2.contourArea(cv2.convexHull(c))
                want = cv2.contourArea(c) / hull if hull > 0 else 0.0
                assert a.convexity[j] == pytest.approx(want, rel=1e-9, abs=1e-12)
                n_checked += 1
        # the whole blob stage: the same blobs
        (a, _), (b, _) = _both(find_blobs_multi, masks, det.blob_filter, shape=m.shape)
        assert len(a) == len(b)
        np.testing.assert_allclose(a.x, b.x, atol=1e-9)
        np.testing.assert_allclose(a.holes, b.holes, atol=1e-12)
    assert n_checked > 20


def test_subpixel_centres(drick, cam, frames):
    det = DotDetector(cam, [drick])
    for img, _ in frames:
        blobs, _ = det.blobs(img)
        (ca, ka), (cb, kb) = _both(refine_centers, img, blobs)
        assert ca.shape == (len(blobs), 2)
        # the numpy version works in float32
        np.testing.assert_allclose(ca, cb, atol=2e-3)
        np.testing.assert_allclose(ka, kb, rtol=1e-4, atol=1e-3)


def test_clahe_at_blobs(drick, cam, frames):
    det = DotDetector(cam, [drick])
    for img, _ in frames:
        blobs, hsv = det.blobs(img)
        if not len(blobs):
            continue
        x = np.ascontiguousarray(blobs.x)
        y = np.ascontiguousarray(blobs.y)
        got = K.clahe_at(hsv, x, y, 8, 8, 4, 2.0)
        v = hsv[:, :, 2]
        xi = np.clip(np.rint(x).astype(int), 1, v.shape[1] - 2)
        yi = np.clip(np.rint(y).astype(int), 1, v.shape[0] - 2)
        raw = (v[yi, xi].astype(float) + v[yi - 1, xi] + v[yi + 1, xi] + v[yi, xi - 1]
               + v[yi, xi + 1]) / 5.0
        np.testing.assert_allclose(got, ClaheMap(v, 2.0, (8, 8), 4)(x, y, raw), atol=1e-9)


def test_hypotheses_and_assignment(drick, cam, frames):
    """The kernel tries fewer seed pairs (not those of a brick already matched completely),
    so it returns a subset of the numpy rows; the bricks assigned are the same."""
    det = DotDetector(cam, [drick])
    cfg = det.config
    m = det.models[0]
    for img, _ in frames:
        blobs, _ = det.blobs(img)
        q, cov = det._blob_geometry(blobs)
        geo = BlobGeometry.build(q, cov, blobs.color, ~blobs.border)
        ha, hb = _both(generate_hypotheses, m, geo, cfg.seeds_per_blob, cfg.ratio_tol,
                        cfg.match_tol, cfg.min_dots)
        rows_b: dict[tuple, list[float]] = {}
        for r, s in zip(hb.assign.tolist(), hb.score.tolist()):
            rows_b.setdefault(tuple(r), []).append(s)
        for r, s in zip(ha.assign.tolist(), ha.score.tolist()):
            assert any(abs(s - sb) < 1e-9 for sb in rows_b.get(tuple(r), [])), (r, s)
        ca, cb = _both(assign_greedy, [ha], len(blobs), cfg.min_dots)
        assert sorted(frozenset(c.assign[c.assign >= 0].tolist()) for c in ca) == \
            sorted(frozenset(c.assign[c.assign >= 0].tolist()) for c in cb)
        # the greedy kernel equals the numpy rounds on the same rows
        ga, gb = _both(assign_greedy, [hb], len(blobs), cfg.min_dots)
        assert [c.assign.tolist() for c in ga] == [c.assign.tolist() for c in gb]


def _random_poses(rng, B):
    R = dots_pose.so3_exp(rng.normal(0, 0.5, (B, 3)))
    t = np.c_[rng.uniform(-0.3, 0.3, (B, 2)), rng.uniform(0.6, 2.0, B)]
    return R, t


def test_pose_kernels(drick, cam):
    det = DotDetector(cam, [drick])
    m = det.models[0]
    rng = np.random.default_rng(4)
    B, N = 12, m.n
    R, t = _random_poses(rng, B)
    X = np.repeat(m.X[None], B, axis=0)
    Y = X @ R.transpose(0, 2, 1) + t[:, None, :]
    q = Y[..., :2] / Y[..., 2:] + rng.normal(0, 3e-4, (B, N, 2))
    w = (rng.random((B, N)) > 0.2).astype(float)
    w[:, :4] = 1.0
    R0 = dots_pose.so3_exp(rng.normal(0, 0.05, (B, 3))) @ R
    t0 = t + rng.normal(0, 0.01, (B, 3))
    (Ra, ta, ca), (Rb, tb, cb) = _both(lambda: dots_pose.refine_poses(X, q, w, R0, t0, 6))
    # each pose stops on its own in the kernel (numpy iterates until all have): ≤ 1e-7
    np.testing.assert_allclose(Ra, Rb, atol=1e-7)
    np.testing.assert_allclose(ta, tb, atol=1e-7)
    np.testing.assert_allclose(ca, cb, rtol=1e-3, atol=1e-12)
    ga, gb = _both(lambda: dots_pose.gn_step(X, q, w, Ra, ta, return_normal=True))
    for u, v in zip(ga, gb):
        np.testing.assert_allclose(u, v, rtol=1e-7, atol=1e-12)
    # perspective shift of the ellipse centres
    nrm = np.repeat(m.normals[None], B, axis=0)
    rad = np.repeat(m.radii[None], B, axis=0)
    oa, ob = _both(lambda: dots_pose.conic_center_offsets(X, nrm, rad, R, t))
    np.testing.assert_allclose(oa, ob, rtol=1e-9, atol=1e-15)
    assert np.abs(oa).max() > 1e-6
    # occlusion by the drick's pyramids
    oa, ob = _both(lambda: occluded_dots(m, R, t, clearance=True))
    np.testing.assert_allclose(oa, ob, atol=1e-9)
    # rotation vectors and covariances
    np.testing.assert_allclose(K.so3_log(R), dots_pose.so3_log(R), atol=1e-12)
    Rpi = dots_pose.so3_exp(np.array([[0.0, np.pi - 1e-6, 0.0], [np.pi, 0, 0]]))
    np.testing.assert_allclose(dots_pose.so3_exp(K.so3_log(Rpi)), Rpi, atol=1e-9)
    A = ga[3]
    rv = dots_pose.so3_log(ga[0])
    sig = np.full(B, 2e-4)
    ca, cb = _both(lambda: dots_pose.pose_covariance_from_normal(A, ga[0], ga[1], rv, sig))
    np.testing.assert_allclose(ca, cb, rtol=1e-6, atol=1e-18)
    np.testing.assert_allclose(ca, K.pose_covariance(A, rv, sig), rtol=1e-12, atol=1e-24)
    assert np.all(np.linalg.eigvalsh(cb) > 0)


def test_ippe_gives_opencvs_two_solutions(drick, cam):
    """The batched IPPE (compiled kernel, and OpenCV when numba is absent) gives OpenCV's
    two solutions and their costs (sum of squared normalised residuals)."""
    det = DotDetector(cam, [drick])
    m = det.models[0]
    rng = np.random.default_rng(9)
    B = 10
    R, t = _random_poses(rng, B)
    Y = m.X[None] @ R.transpose(0, 2, 1) + t[:, None, :]
    q = Y[..., :2] / Y[..., 2:] + rng.normal(0, 2e-4, (B, m.n, 2))
    P = np.repeat(m.P[None], B, axis=0)
    for Rk, tk, ck, ok in _both(lambda: dots_pose.ippe_batch(P, q, np.ones((B, m.n)),
                                                             m.plane_from_brick)):
        assert ok.all()
        for b in range(B):
            n, rvs, tvs, err = cv2.solvePnPGeneric(m.X, q[b], np.eye(3), None,
                                                   flags=cv2.SOLVEPNP_IPPE)
            for s in range(n):
                Ro = cv2.Rodrigues(rvs[s])[0]
                ang = np.degrees(np.arccos(np.clip((np.trace(Rk[b, s].T @ Ro) - 1) / 2,
                                                   -1, 1)))
                assert ang < 0.05 and np.linalg.norm(tk[b, s] - tvs[s].ravel()) < 1e-3, \
                    (b, s, ang)
                # OpenCV's error is the RMS over the 2n coordinates
                assert ck[b, s] == pytest.approx(2 * err[s, 0] ** 2 * m.n, rel=0.05,
                                                 abs=1e-12)


def test_undistort_and_project():
    rng = np.random.default_rng(1)
    for dist in ([-0.12, 0.08, 0.0006, -0.0004, -0.02],
                 [-0.3, 0.1, 0.001, -0.002, -0.01, 0.02, -0.01, 0.005, 0.001, -0.0005,
                  0.0008, 0.0002]):
        cam = Camera.from_fov(640, 480, 70.0, dist=dist)
        d12 = np.zeros(12)
        d12[:len(dist)] = dist
        args = (cam.fx, cam.fy, cam.K[0, 2], cam.K[1, 2], d12)
        px = rng.uniform([20, 20], [620, 460], (300, 2))
        q, J = K.undistort(px, *args)
        np.testing.assert_allclose(q, cam.normalize(px), atol=1e-12)
        h = 1e-2       # central differences
        qx1, _ = K.undistort(px + [h, 0], *args)
        qx0, _ = K.undistort(px - [h, 0], *args)
        qy1, _ = K.undistort(px + [0, h], *args)
        qy0, _ = K.undistort(px - [0, h], *args)
        Jn = np.stack([(qx1 - qx0) / (2 * h), (qy1 - qy0) / (2 * h)], axis=2)
        assert np.abs(Jn - J).max() < 1e-6 * np.abs(J).max()
        Yc = np.c_[q, np.ones(len(q))] * rng.uniform(0.5, 3, (len(q), 1))
        ref, _ = cv2.projectPoints(Yc, np.zeros(3), np.zeros(3), cam.K, cam.dist)
        np.testing.assert_allclose(K.project(Yc, *args), ref.reshape(-1, 2), atol=1e-9)


def test_detector_with_and_without_kernels(drick, cam, frames):
    """The whole detector gives the same bricks and poses either way (numpy is the
    reference and the fallback on machines without numba)."""
    n = 0
    for img, g in frames:
        for grav in (g, None):
            K.set_enabled(True)
            a = DotDetector(cam, [drick]).detect(img, gravity=grav)
            K.set_enabled(False)
            b = DotDetector(cam, [drick]).detect(img, gravity=grav)
            K.set_enabled(True)
            assert len(a) == len(b)
            for pa, pb in zip(sorted(a, key=lambda p: tuple(p.tvec)),
                              sorted(b, key=lambda p: tuple(p.tvec))):
                assert np.linalg.norm(pa.tvec - pb.tvec) < 2e-4
                Ra, Rb = cv2.Rodrigues(pa.rvec)[0], cv2.Rodrigues(pb.rvec)[0]
                assert np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))) \
                    < 0.05
                assert pa.markers == pb.markers and pa.ambiguous == pb.ambiguous
                assert pa.symmetric == pb.symmetric
                np.testing.assert_allclose(pa.image_points, pb.image_points, atol=5e-3)
                np.testing.assert_allclose(pa.covariance, pb.covariance, rtol=0.05,
                                           atol=1e-10)
                n += 1
    assert n >= 20


def test_environment_switch():
    """``DROVISIO_NUMBA=0`` turns the kernels off (the numpy path, as on 32-bit ARM)."""
    code = "from drovisio.detect.dots import kernels as K; print(K.AVAILABLE, K.enabled())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "DROVISIO_NUMBA": "0"}, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_warm_up_runs_every_kernel_on_a_drawn_frame():
    """The warm-up frame (drawn, not rendered) holds a dot brick and a code brick that the
    detectors find, so every kernel is compiled with the argument types of real frames."""
    from drovisio.detect.warmup import warm_up

    r = warm_up()
    assert r["compiled"] and r["dots"] == 1 and r["codes"] == 1
    assert not K.missing_cache(vars(K))
