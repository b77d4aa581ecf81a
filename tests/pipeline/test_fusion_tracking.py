"""SO(3) tools, code+dot fusion, and the per-brick tracker."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drovisio.detect.result import BrickPose
from drovisio.fusion import (
    fuse_frame,
    fuse_pair,
    right_jacobian,
    right_jacobian_inv,
    rvec_cov_to_tangent,
    so3_exp,
    so3_log,
    tangent_cov_to_rvec,
)
from drovisio.tracking import BrickTracker, TrackerConfig


def _pose(rvec, tvec, method="aruco", instance=1, layout="both", sig_r=0.01, sig_t=0.01,
          symmetric=False):
    cov = np.diag([sig_r ** 2] * 3 + [sig_t ** 2] * 3)
    return BrickPose(layout, instance if method == "aruco" else None, method,
                     np.asarray(rvec, float), np.asarray(tvec, float), 0.2,
                     markers=[1], covariance=cov, symmetric=symmetric)


@pytest.mark.parametrize("w", [[0.0, 0.0, 0.0], [1e-7, 0, 0], [0.3, -0.2, 0.1],
                               [0.0, 0.0, math.pi - 1e-6], [3.0, 0.5, 0.1]])
def test_so3_roundtrip_and_jacobians(w):
    w = np.array(w)
    assert np.allclose(so3_log(so3_exp(w)), w, atol=1e-6) or \
        np.allclose(so3_exp(so3_log(so3_exp(w))), so3_exp(w), atol=1e-9)
    if np.linalg.norm(w) < 3.0:
        assert np.allclose(right_jacobian(w) @ right_jacobian_inv(w), np.eye(3), atol=1e-9)
        d = np.array([1e-6, -2e-6, 1.5e-6])
        lhs = so3_exp(w + d)
        rhs = so3_exp(w) @ so3_exp(right_jacobian(w) @ d)
        assert np.abs(lhs - rhs).max() < 1e-10


def test_covariance_conversions_invert():
    rv = np.array([2.5, -0.4, 0.1])
    A = np.random.default_rng(0).normal(size=(6, 6))
    C = A @ A.T
    assert np.allclose(tangent_cov_to_rvec(rv, rvec_cov_to_tangent(rv, C)), C)


def test_fusion_is_covariance_weighted():
    code = _pose([0.0, 0.0, 0.3], [0.0, 0.0, 2.0], sig_t=0.01)
    dots = _pose([0.0, 0.0, 0.3], [0.03, 0.0, 2.0], method="dots", sig_t=0.02)
    fused, d2 = fuse_pair(code, dots)
    assert fused.method == "fused" and fused.instance == 1
    # weights 1/σ²: 0.03 · (1/4e-4) / (1/1e-4 + 1/4e-4) = 0.006
    assert fused.tvec[0] == pytest.approx(0.006, abs=1e-6)
    assert fused.covariance[3, 3] == pytest.approx(1 / (1 / 1e-4 + 1 / 4e-4), rel=1e-6)
    assert d2 == pytest.approx(0.03 ** 2 / 5e-4, rel=1e-3)


def test_fusion_picks_symmetric_half_turn_and_gates():
    code = _pose([0.0, 0.0, 0.3], [0.0, 0.0, 2.0])
    turned = so3_log(so3_exp([0.0, 0.0, 0.3]) @ np.diag([-1.0, -1.0, 1.0]))
    dots = _pose(turned + 0.005, [0.0, 0.0, 2.0], method="dots", symmetric=True)
    fused, d2 = fuse_pair(code, dots)
    assert np.allclose(fused.rvec, [0.0, 0.0, 0.3], atol=0.01) and d2 < 5
    far = _pose([0.0, 0.0, 0.3], [0.2, 0.0, 2.0], method="dots")
    same, d2 = fuse_pair(code, far)
    assert same is code and d2 > 100
    # frame level: pairs by layout and distance, leaves the others
    other = _pose([0.0, 0.0, 0.0], [1.0, 0.0, 2.0], layout="x", method="dots")
    out = fuse_frame([code, dots, other])
    assert sorted(p.method for p in out) == ["dots", "fused"]


def _feed(tr, poses, t):
    return tr.update(poses, t, 1000.0 + t)


def test_tracker_bridges_a_missed_frame_then_drops():
    tr = BrickTracker(TrackerConfig(max_age=0.5))
    for k in range(10):  # moving 0.3 m/s in x
        _feed(tr, [_pose([3.1, 0, 0], [0.3 * k / 30, 0, 1.5], sig_t=0.002)], k / 30)
    out = _feed(tr, [], 10 / 30)  # missed frame: predicted, not stale
    assert len(out) == 1 and not out[0].measured
    assert out[0].age == pytest.approx(1 / 30) and out[0].t == pytest.approx(1000 + 10 / 30)
    assert out[0].tvec[0] == pytest.approx(0.1, abs=0.01)  # extrapolated, not held
    assert _feed(tr, [], 9 / 30 + 0.49)
    assert _feed(tr, [], 9 / 30 + 0.51) == []  # dropped after max_age


def test_tracker_anonymous_bricks_keep_their_tracks():
    tr = BrickTracker()
    ids = None
    for k in range(5):
        a = _pose([3.1, 0, 0], [0.0 + 0.01 * k, 0, 1.5], method="dots", layout="d")
        b = _pose([3.1, 0, 0], [0.4 + 0.01 * k, 0, 1.5], method="dots", layout="d")
        out = _feed(tr, [b, a] if k % 2 else [a, b], k / 30)
        by_x = {round(o.tvec[0], 1): o.track for o in out}
        ids = ids or by_x
        assert by_x == ids
    assert len(set(ids.values())) == 2


def test_tracker_keeps_symmetric_yaw_and_restarts_on_jump():
    tr = BrickTracker()
    R0 = so3_exp([3.1, 0.0, 0.0])
    flip = so3_log(R0 @ np.diag([-1.0, -1.0, 1.0]))
    for k in range(6):
        rv = [3.1, 0.0, 0.0] if k % 2 == 0 else flip
        out = _feed(tr, [_pose(rv, [0, 0, 1.5], symmetric=True, method="dots", layout="d")],
                    k / 30)
        assert np.abs(so3_exp(out[0].rvec) - R0).max() < 0.05
    tr2 = BrickTracker(TrackerConfig(restart_after=2))
    for k in range(5):
        _feed(tr2, [_pose([3.1, 0, 0], [0, 0, 1.5], sig_t=0.002)], k / 30)
    track = tr2.tracks[0].track
    out = _feed(tr2, [_pose([3.1, 0, 0], [0.5, 0, 1.5], sig_t=0.002)], 5 / 30)
    assert out[0].tvec[0] < 0.1 and not out[0].measured  # one outlier: ignored
    out = _feed(tr2, [_pose([3.1, 0, 0], [0.5, 0, 1.5], sig_t=0.002)], 6 / 30)
    assert out[0].tvec[0] == pytest.approx(0.5) and out[0].track == track  # restarted
