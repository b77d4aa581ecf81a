"""The pose error measures: the two yaw errors agree where both apply, and each keeps the
arithmetic its benchmark was measured with."""

from __future__ import annotations

import math

import numpy as np

from drovisio.geometry import rot_z, rotation_about, so3_exp
from drovisio.pose import rotation_angle_deg, rotation_angles_deg, yaw_about_axis_deg, yaw_error_deg


def _random_rotations(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [so3_exp(rng.normal(size=3) * rng.uniform(0.0, 1.5)) for _ in range(n)]


def _dot_benchmark_yaw(Rt: np.ndarray, Re: np.ndarray, symmetric: bool) -> float:
    """The dot benchmark's yaw error, as it was measured (``drovisio bench dots``)."""
    E = Rt.T @ Re
    yaw = math.degrees(math.atan2(E[1, 0] - E[0, 1], E[0, 0] + E[1, 1]))
    period = 180.0 if symmetric else 360.0
    yaw = (yaw + period / 2) % period - period / 2
    return abs(yaw)


def test_the_dot_yaw_is_the_dot_benchmarks_bit_for_bit():
    for k, (Rt, Re) in enumerate(zip(_random_rotations(50, 1), _random_rotations(50, 2))):
        for symmetric in (False, True):
            assert abs(yaw_error_deg(Rt, Re, symmetric)) == _dot_benchmark_yaw(Rt, Re,
                                                                                symmetric), k


def test_both_yaws_measure_the_twist_about_z():
    for Rt in _random_rotations(20, 3):
        for yaw in (-170.0, -45.0, 0.0, 10.0, 120.0):
            swing = rotation_about(np.array([1.0, 0.0, 0.0]), 0.2)
            Re = Rt @ swing @ rot_z(math.radians(yaw))
            a, b = yaw_about_axis_deg(Rt, Re), yaw_error_deg(Rt, Re)
            assert abs(a - b) < 1e-9
            # a half turn is no error for a symmetric layout
            assert abs(yaw_error_deg(Rt, Re @ rot_z(math.pi), symmetric=True)
                       - yaw_error_deg(Rt, Re, symmetric=True)) < 1e-9


def test_rotation_about_an_axis_and_the_angles_between_rotations():
    axis = np.array([0.0, 0.6, 0.8])
    R = rotation_about(axis, 0.3)
    np.testing.assert_allclose(R, so3_exp(axis * 0.3), atol=1e-12)
    np.testing.assert_allclose(R @ axis, axis, atol=1e-12)
    Ra, Rb = _random_rotations(5, 4), _random_rotations(5, 5)
    batch = rotation_angles_deg(np.stack(Ra), np.stack(Rb))
    for a, b, d in zip(Ra, Rb, batch):
        assert abs(rotation_angle_deg(a, b) - d) < 1e-6
