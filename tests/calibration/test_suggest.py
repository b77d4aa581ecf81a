"""Next-pose suggestion: data, direction, and the predicted gain checked by rendering it."""

from __future__ import annotations

import numpy as np

from drovisio.calibration.coverage import compute_coverage
from drovisio.calibration.session import CalibrationSession
from drovisio.calibration.suggest import suggest_next_pose
from drovisio.calibration.synthetic import DEFAULT_BOARD


def test_first_hint_is_the_centre_facing_the_camera(true_camera):
    s = suggest_next_pose(true_camera, DEFAULT_BOARD, compute_coverage([], (640, 480)))
    assert s.region == "centre" and s.tilt_deg == 0.0 and s.far_edge is None
    x0, y0, x1, y1 = s.box_px
    assert 0 <= x0 < 320 < x1 <= 639 and 0 <= y0 < 240 < y1 <= 479
    assert "centre" in s.sentence and "facing the camera" in s.sentence
    j = s.to_json()
    assert set(j) >= {"region", "box_px", "distance_m", "tilt_deg", "sentence", "outline_px"}


def test_opencv_hint_goes_to_the_empty_left_side(opencv_session):
    s = opencv_session.suggestion()
    assert s.region in ("top-left", "left", "bottom-left"), s.sentence
    assert s.predicted_p95_px < s.current_p95_px
    assert 0.2 < s.distance_m < 1.5 and f"{s.distance_m:.2f} m" in s.sentence
    x0, y0, x1, y1 = s.box_px
    assert x0 >= 0 and y0 >= 0 and x1 <= 639 and y1 <= 479 and x0 < 100  # left side


def test_rendering_the_hint_gives_the_predicted_gain(rendered, true_camera):
    """6 views, then the suggested view rendered with the true camera: the uncertainty drops,
    and by what was predicted once the change of the noise estimate is accounted for
    (measured: p95 0.667 → 0.622 px, predicted 0.543 at the old noise; 0.544 rescaled)."""
    from drovisio.synth import Effects, render_chessboard

    s = CalibrationSession(DEFAULT_BOARD)
    for v in rendered[:6]:
        s.add_image(v.image, v.name)
    before = s.solve()
    hint = s.suggestion()
    assert hint.predicted_p95_px < hint.current_p95_px
    assert np.isclose(hint.current_p95_px, before.uncertainty_stats()["p95"], rtol=1e-6)
    img, _, _ = render_chessboard(true_camera, hint.camera_from_board, DEFAULT_BOARD.cols,
                                  DEFAULT_BOARD.rows, DEFAULT_BOARD.square,
                                  effects=Effects(noise_sigma=1.0, seed=99))
    assert s.add_image(img, "suggested").kept
    after = s.solve()
    p_after = after.uncertainty_stats()["p95"]
    assert p_after < before.uncertainty_stats()["p95"]
    rescaled = p_after * np.sqrt(before.model.sigma2 / after.model.sigma2)
    assert np.isclose(rescaled, hint.predicted_p95_px, rtol=0.05)
