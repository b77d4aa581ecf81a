"""Lens models in calibration: fisheye and rational solves against rendered truth, the model
chosen on held-out views (and why), outlier corners, a refused unknown model."""

from __future__ import annotations

import numpy as np
import pytest

from drovisio.bench.lens import FISHEYE_150 as FISHEYE
from drovisio.calibration.session import CalibrationSession, SessionConfig
from drovisio.calibration.solve import CalibrationError, SolveOptions, ViewInput, solve
from drovisio.calibration.synthetic import DEFAULT_BOARD, render_calibration_views
from drovisio.calibration.uncertainty import model_difference_px
from drovisio.camera import Camera


@pytest.fixture(scope="module")
def fisheye_views():
    return render_calibration_views(FISHEYE, 20, seed=1, ss=2)


def _session(views, model: str) -> CalibrationSession:
    s = CalibrationSession(DEFAULT_BOARD, config=SessionConfig(solve=SolveOptions(model=model)))
    for v in views:
        assert s.add_image(v.image, v.name).kept, v.name
    return s


def _rel_errors(cam: Camera, truth: Camera) -> np.ndarray:
    return np.abs(np.array([cam.fx - truth.fx, cam.fy - truth.fy, cam.cx - truth.cx,
                            cam.cy - truth.cy]) / np.array([truth.fx, truth.fy, truth.cx,
                                                            truth.cy]))


@pytest.mark.parametrize("model", ["fisheye", "auto"])
def test_150_degree_fisheye_is_recovered_within_its_uncertainty(fisheye_views, model):
    r = _session(fisheye_views, model).solve()
    assert r.camera.model == "fisheye"
    assert np.all(_rel_errors(r.camera, FISHEYE) < 0.003)
    np.testing.assert_allclose(r.camera.dist, FISHEYE.dist, atol=0.003)
    um = r.uncertainty
    d = model_difference_px(FISHEYE, r.camera, um.xs, um.ys)
    ok = np.isfinite(d) & np.isfinite(um.sigma)
    assert ok.mean() > 0.99
    assert np.mean(d[ok] <= 2 * um.sigma[ok]) >= 0.95
    assert set(r.std) == {"fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"}
    if model == "auto":
        choice = r.model_choice
        assert choice["chosen"] == "fisheye" and choice["held_out_rms_px"]["fisheye"] < 0.2
        assert choice["held_out_rms_px"]["plumb_bob"] is None or \
            choice["held_out_rms_px"]["plumb_bob"] > 0.2
        assert "chose fisheye" in choice["reason"]


def test_real_views_keep_the_five_coefficient_model(opencv_images, opencv_board):
    s = CalibrationSession(opencv_board, config=SessionConfig(solve=SolveOptions(model="auto")))
    for name, img in opencv_images.items():
        s.add_image(img, name)
    r = s.solve()
    assert r.camera.model == "plumb_bob" and r.model_choice["chosen"] == "plumb_bob"
    held = r.model_choice["held_out_rms_px"]
    assert 0.1 < held["plumb_bob"] < 0.3
    # measured: plumb_bob 0.182, rational 0.185, fisheye 0.195 px — no model does better
    assert held["plumb_bob"] < min(held["rational_polynomial"], held["fisheye"])
    assert r.model_choice["reason"].startswith("kept plumb_bob: held-out RMS plumb_bob 0.")


def test_a_strong_rational_lens_is_not_kept_as_plumb_bob():
    truth = Camera.from_fov(960, 720, 110.0,
                            dist=[0.6, 0.3, 0.0005, -0.0004, 0.02, 0.95, 0.45, 0.05])
    views = render_calibration_views(truth, 16, seed=2, ss=2)
    r = _session(views, "auto").solve()
    assert r.camera.model in ("rational_polynomial", "fisheye"), r.model_choice
    held = r.model_choice["held_out_rms_px"]
    best = held[r.camera.model]
    assert held["plumb_bob"] is None or held["plumb_bob"] > 1.1 * best
    assert r.rms_px < 0.15


# a 90° lens glued slightly off-centre (thin prism s1-s4), and the same on a tilted sensor
THIN_PRISM = [-0.25, 0.08, 0.0005, -0.0004, -0.01, 0, 0, 0, 0.004, -0.001, -0.003, 0.001]


@pytest.mark.parametrize("model, dist", [("thin_prism", THIN_PRISM),
                                         ("tilted", THIN_PRISM + [0.02, -0.015])])
def test_thin_prism_and_tilted_lenses_are_recovered(model, dist):
    truth = Camera.from_fov(960, 720, 90.0, dist=dist)
    views = render_calibration_views(truth, 16, seed=3, ss=2)
    r = _session(views, model).solve()
    # written as OpenCV writes them: rational_polynomial with 12 or 14 coefficients
    assert r.camera.model == "rational_polynomial" and r.camera.dist.size == len(dist)
    assert list(r.std)[-2:] == (["s3", "s4"] if model == "thin_prism" else ["tx", "ty"])
    # measured: thin prism fx..cy within 0.03/0.02/0.02/0.10 %, tilted 0.004/0.007/0.12/0.18 %
    assert np.all(_rel_errors(r.camera, truth) < 0.003), _rel_errors(r.camera, truth)
    np.testing.assert_allclose(r.camera.dist[8:], dist[8:], atol=0.0015)
    if model == "thin_prism":
        um = r.uncertainty
        d = model_difference_px(truth, r.camera, um.xs, um.ys)
        ok = np.isfinite(d) & np.isfinite(um.sigma)
        assert np.mean(d[ok] <= 2 * um.sigma[ok]) >= 0.95
    # the 5-coefficient model fits these views almost as well (RMS) but puts the image
    # centre 0.5-3 % off
    plain = _session(views, "plumb_bob").solve()
    assert plain.rms_px < 2.0 * r.rms_px
    assert _rel_errors(plain.camera, truth)[2:].max() > 0.005


def test_outlier_corners_are_dropped_and_named(rendered, true_camera):
    sess = CalibrationSession(DEFAULT_BOARD)
    for v in rendered:
        sess.add_image(v.image, v.name)
    clean = sess.view_inputs()
    bad = []
    for k in (2, 7, 11):
        v = clean[k]
        c = np.array(v.corners, float).reshape(-1, 2).copy()
        c[5 + k] += [2.5, -2.0]
        clean[k] = ViewInput(v.name, c, v.object_points)
        bad.append((v.name, 5 + k))
    r = solve(clean, true_camera.size)
    assert sorted((c["file"], c["corner"]) for c in r.rejected_corners) == sorted(bad)
    assert all(c["residual_px"] > 2.0 and "median corner residual" in c["reason"]
               for c in r.rejected_corners)
    assert not r.rejected                      # the views themselves stay
    assert np.all(_rel_errors(r.camera, true_camera) < 0.003)
    # without the corner rule, each of those views is lost whole
    off = solve(clean, true_camera.size, SolveOptions(reject_corners=False))
    assert sorted(v["file"] for v in off.rejected) == sorted(f for f, _ in bad)


def test_an_unknown_model_is_refused_by_name(rendered):
    views = [ViewInput(v.name, v.true_corners, DEFAULT_BOARD.object_points()) for v in rendered[:5]]
    with pytest.raises(CalibrationError, match="unknown lens model 'kannala'"):
        solve(views, (640, 480), SolveOptions(model="kannala"))
