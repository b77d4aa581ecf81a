"""drovisio.pose.ambiguity: the one rule that decides a planar pose's flip for both detectors."""

from __future__ import annotations

import numpy as np

from drovisio.detect.aruco import ArucoParams
from drovisio.detect.dots import DotsConfig
from drovisio.geometry import rot_x, rot_z
from drovisio.pose import (
    HALF_TURN,
    AmbiguityRule,
    alternative_plausible,
    canonical_half_turn,
    decide_flips,
)

DOWN = np.array([0.0, 1.0, 0.0])          # gravity in a camera looking at the horizon


def _flat(yaw_deg: float = 0.0, tilt_deg: float = 0.0) -> np.ndarray:
    """camera_from_brick of a brick whose z (up) is −DOWN, tilted by tilt_deg about x."""
    return rot_x(np.radians(90.0 + tilt_deg)) @ rot_z(np.radians(yaw_deg))


def _pair(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a, b])[None]


def test_both_detectors_use_the_same_rule():
    assert DotsConfig().ambiguity == ArucoParams().ambiguity == AmbiguityRule()


def test_reprojection_decides_at_the_margin_only():
    R = _pair(_flat(), _flat(tilt_deg=40))
    dof = 10
    for other, decided in ((10.0 + 24.9, False), (10.0 + 25.1, True)):
        pick, why = decide_flips(R, np.array([[10.0, other]]), dof)
        assert (pick[0] == 0) == decided and (why[0] == "reprojection") == decided
    # a best fit inconsistent with the noise (χ² > 3·dof + 4) never decides by itself
    pick, _ = decide_flips(R, np.array([[40.0, 400.0]]), dof)
    assert pick[0] == -1
    assert alternative_plausible(np.array([[40.0, 400.0], [10.0, 36.0]]), dof).tolist() == \
        [True, False]


def test_close_candidates_are_one_pose():
    R = _pair(_flat(), _flat(tilt_deg=4.0))
    pick, why = decide_flips(R, np.array([[10.0, 11.0]]), 10)
    assert pick[0] == 0 and why[0] == "close"
    pick, why = decide_flips(_pair(_flat(), _flat(tilt_deg=6.0)), np.array([[10.0, 11.0]]), 10)
    assert pick[0] == -1 and why[0] == ""


def test_gravity_then_reference_then_previous():
    flat, tilted = _flat(yaw_deg=30), _flat(yaw_deg=30, tilt_deg=50)
    chi2 = np.array([[12.0, 10.0]])      # the image slightly prefers the tilted one
    R = _pair(flat, tilted)
    pick, why = decide_flips(R, chi2, 10, gravity=DOWN)
    assert pick[0] == 0 and why[0] == "gravity"
    pick, why = decide_flips(R, chi2, 10, reference_up=-DOWN)
    assert pick[0] == 0 and why[0] == "reference"
    pick, why = decide_flips(R, chi2, 10, previous=[tilted @ rot_x(np.radians(3))])
    assert pick[0] == 1 and why[0] == "previous"
    # gravity outranks a previous pose that disagrees with it
    pick, why = decide_flips(R, chi2, 10, gravity=DOWN, previous=[tilted])
    assert pick[0] == 0 and why[0] == "gravity"
    # neither candidate flat: gravity says nothing, the pose stays undecided
    R = _pair(_flat(tilt_deg=40), _flat(tilt_deg=-60))
    pick, why = decide_flips(R, chi2, 10, gravity=DOWN)
    assert pick[0] == -1


def test_evidence_never_picks_a_fit_far_worse():
    R = _pair(_flat(tilt_deg=20), _flat())
    # the flat one's χ² is 9 margins worse: it is out; the other one agrees with gravity
    pick, why = decide_flips(R, np.array([[10.0, 10.0 + 9 * 25 + 1]]), 10, gravity=DOWN)
    assert pick[0] == 0 and why[0] == "gravity"
    pick, why = decide_flips(R, np.array([[10.0, 10.0 + 9 * 25 - 1]]), 10, gravity=DOWN)
    assert pick[0] == 1 and why[0] == "gravity"


def test_batched_decisions_are_independent():
    Rs = np.concatenate([_pair(_flat(), _flat(tilt_deg=40)),
                         _pair(_flat(tilt_deg=40), _flat()),
                         _pair(_flat(), _flat(tilt_deg=40))])
    chi2 = np.array([[10.0, 11.0], [10.0, 11.0], [10.0, 100.0]])
    pick, why = decide_flips(Rs, chi2, np.array([10, 10, 10]), gravity=DOWN)
    assert pick.tolist() == [0, 1, 0] and why == ["gravity", "gravity", "gravity"]
    pick, why = decide_flips(Rs, chi2, 10)
    assert pick.tolist() == [-1, -1, 0] and why == ["", "", "reprojection"]


def test_canonical_half_turn_points_x_to_image_right():
    for yaw in (10.0, 100.0, 190.0, 280.0):
        R = _flat(yaw_deg=yaw)
        Rc = R * HALF_TURN if canonical_half_turn(R) else R
        assert Rc[0, 0] > 0 and np.allclose(Rc[:, 2], R[:, 2])
        assert not canonical_half_turn(Rc)


def test_gravity_vetoes_a_pose_it_contradicts():
    R = _pair(_flat(tilt_deg=30), _flat(tilt_deg=-65))
    pick, why = decide_flips(R, np.array([[5.0, 80.0]]), 10)
    assert pick[0] == 0 and why[0] == "reprojection"
    pick, why = decide_flips(R, np.array([[5.0, 80.0]]), 10, gravity=DOWN)
    assert pick[0] == -1 and why[0] == ""
    # within the tolerance the image's choice stands
    R = _pair(_flat(tilt_deg=20), _flat(tilt_deg=-65))
    pick, _ = decide_flips(R, np.array([[5.0, 80.0]]), 10, gravity=DOWN)
    assert pick[0] == 0


def test_noise_scale_is_measured_robustly_from_the_residuals():
    """The factor on the assumed variance: 1 when the residuals match it, about the true
    factor (at its lower 99 % bound) when the points are noisier, hardly raised by a few
    gross residuals, and never measured from a single code's 2 degrees of freedom."""
    from drovisio.pose.ambiguity import noise_scale

    rng = np.random.default_rng(7)
    n, dof = 104, 98                      # 52 corners, 6 pose parameters
    e = rng.normal(0.0, 1.0, n) * np.sqrt(dof / n)
    assert noise_scale(e, dof) == 1.0
    s = noise_scale(2.0 * e, dof)         # variance 4x the assumed
    assert 2.0 < s < 4.0
    bad = 2.0 * e.copy()
    bad[:8] = 60.0                        # one code's four corners far off
    assert noise_scale(bad, dof) < 1.3 * s
    # with that scale the board's own χ² is consistent again, the outliers' is not
    assert float((2.0 * e) @ (2.0 * e)) / s <= 3 * dof + 4
    assert float(bad @ bad) / noise_scale(bad, dof) > 3 * dof + 4
    assert noise_scale(10.0 * rng.normal(size=8), 2) == 1.0


def test_decide_flips_uses_the_measured_scale():
    """χ² 417 for 52 corners (dof 98) with the mirror 20 px RMS worse: inconsistent at the
    assumed noise, decided at the measured one."""
    from drovisio.pose.ambiguity import decide_flips

    R = np.stack([np.eye(3), rot_x(0.6)])[None]
    chi2 = np.array([[417.0, 40000.0]])
    assert decide_flips(R, chi2, 98)[0][0] == -1
    pick, why = decide_flips(R, chi2, 98, scale=3.0)
    assert pick[0] == 0 and why[0] == "reprojection"
