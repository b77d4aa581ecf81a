"""The verdict names the thesis's field failure: all views facing the camera at one distance."""

from __future__ import annotations

import numpy as np

from drovisio.calibration.board import Detection
from drovisio.calibration.geometry import place_board
from drovisio.calibration.session import CalibrationSession, FrameResult
from drovisio.calibration.synthetic import DEFAULT_BOARD


def _projected(camera, T, rng):
    px = camera.project_from(DEFAULT_BOARD.object_points(), T) + rng.normal(0, 0.05, (54, 2))
    return Detection(px, np.arange(54), (640, 480), 20.0, 6)


def test_same_distance_facing_views_are_not_ok(true_camera):
    rng = np.random.default_rng(0)
    s = CalibrationSession(DEFAULT_BOARD)
    for i, xy in enumerate([(320, 240), (300, 230), (340, 250), (250, 200), (400, 280),
                            (330, 200)]):
        T = place_board(true_camera, DEFAULT_BOARD, xy, 0.6)
        s.keep(FrameResult(f"f{i}", _projected(true_camera, T, rng), []))
    res = s.solve()
    assert res.uncertainty_stats()["p95"] > 2.0  # measured ~10 px: focal length undetermined
    v = s.verdict()
    text = " | ".join(v.reasons)
    assert not v.ok
    assert "nearly face the camera" in text and "same distance" in text
    assert "corners of the image not covered" in text
    hint = s.suggestion()
    assert hint.tilt_deg > 0 and hint.predicted_p95_px < 0.6 * hint.current_p95_px


def test_unknown_uncertainty_is_a_reason_not_a_crash(true_camera):
    """A solve whose uncertainty is finite nowhere (every grid point unprojectable) is not ok,
    and says so in words instead of formatting a missing number."""
    from drovisio.calibration.verdict import judge

    rng = np.random.default_rng(1)
    s = CalibrationSession(DEFAULT_BOARD)
    for i, (xy, d) in enumerate([((320, 240), 0.5), ((200, 150), 0.7), ((450, 330), 0.9),
                                 ((180, 340), 0.6), ((460, 140), 0.8), ((330, 250), 1.0)]):
        T = place_board(true_camera, DEFAULT_BOARD, xy, d)
        s.keep(FrameResult(f"f{i}", _projected(true_camera, T, rng), []))
    res = s.solve()
    res.uncertainty.sigma[:] = np.nan
    v = judge(res, s.coverage())
    assert not v.ok
    assert any("uncertainty unknown over the image" in r for r in v.reasons)
