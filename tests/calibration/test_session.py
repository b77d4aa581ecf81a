"""Session-style use: live frames, background solve, persistence, report."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from drovisio.calibration.session import CalibrationSession
from drovisio.calibration.synthetic import DEFAULT_BOARD


def test_live_frames_need_stillness_and_novelty(rendered):
    s = CalibrationSession(DEFAULT_BOARD)
    a, b = rendered[0].image, rendered[1].image
    r = s.offer_frame(a)
    assert not r.kept and any("second frame" in x for x in r.reasons)
    r = s.offer_frame(a)  # same frame again: still, novel → kept
    assert r.kept and r.view_id == 0 and len(s.views) == 1
    r = s.offer_frame(a)
    assert not r.kept and any("too similar" in x for x in r.reasons)
    r = s.offer_frame(b)  # the board jumped: moving
    assert not r.kept and any("moving" in x for x in r.reasons)
    assert s.offer_frame(b).kept and len(s.views) == 2


def test_manual_capture_and_size_check(rendered):
    s = CalibrationSession(DEFAULT_BOARD)
    assert s.add_image(rendered[0].image).kept
    assert s.add_image(rendered[0].image).kept  # a manual capture skips novelty
    small = rendered[1].image[:240, :320]
    r = s.add_image(small, "small.png")
    assert not r.kept and "differs from the session's 640x480" in r.reasons[0]
    assert s.rejected[-1]["file"] == "small.png"
    r = s.add_image(np.full((480, 640, 3), 128, np.uint8), "grey.png")
    assert not r.kept and "no chessboard:9x6 board found" in r.reasons[0]


def test_before_a_solve(rendered):
    s = CalibrationSession(DEFAULT_BOARD)
    assert s.suggestion().region == "centre"
    v = s.verdict()
    assert not v.ok and "not solved yet" in v.reasons[0]
    s.add_image(rendered[0].image, "a")
    assert s.coverage().n_views == 1 and s.suggestion().region != "centre"


def test_background_solve_and_staleness(rendered):
    s = CalibrationSession(DEFAULT_BOARD)
    try:
        for v in rendered[:8]:
            s.add_image(v.image, v.name)
        fut = s.solve_async()
        res = fut.result(timeout=60)
        assert s.result is res and s.result_is_current and not s.solving
        assert len(res.per_view) == 8
        assert s.remove_view(s.views[0].id) and not s.result_is_current
        assert not s.remove_view(12345)
        res2 = s.solve_async().result(timeout=60)
        assert len(res2.per_view) == 7 and s.result_is_current
    finally:
        s.close()


def test_failed_solve_is_reported_not_raised_in_the_caller(rendered):
    from drovisio.calibration.solve import CalibrationError

    s = CalibrationSession(DEFAULT_BOARD)
    s.add_image(rendered[0].image, "only-one")
    fut = s.solve_async()
    assert isinstance(fut.exception(timeout=30), CalibrationError)
    assert "at least 3" in s.last_error
    rep = s.report()
    assert rep["rms_px"] is None and rep["verdict"]["ok"] is False
    s.close()


def test_state_round_trip(rendered):
    s = CalibrationSession(DEFAULT_BOARD)
    for v in rendered[:5]:
        s.add_image(v.image, v.name)
    s.add_rejected("broken.jpg", "cannot be read")
    state = json.loads(json.dumps(s.state()))
    t = CalibrationSession.from_state(state)
    assert [v.name for v in t.views] == [v.name for v in s.views]
    assert t.rejected == s.rejected and t.image_size == (640, 480)
    assert np.allclose(t.views[2].detection.corners, s.views[2].detection.corners, atol=1e-5)
    assert np.allclose(t.solve().camera.K, s.solve().camera.K, rtol=1e-5)
    assert t.add_image(rendered[6].image).view_id == 5


def test_report_is_json_with_the_contract_fields(rendered_session):
    rep = rendered_session.report()
    text = json.dumps(rep, allow_nan=False)
    for key in ("rms_px", "rms_definition", "per_view", "rejected", "std", "uncertainty_px",
                "cross_validation_px", "coverage", "verdict", "suggestion"):
        assert key in rep, key
    assert set(rep["std"]) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}
    assert set(rep["uncertainty_px"]) >= {"p50", "p95", "max"}
    assert rep["verdict"]["ok"] is True and len(text) < 400_000


def test_roi_restricts_the_judgement(rendered):
    """The verdict is taken where the detector looks: a central region is judged alone."""
    from drovisio.calibration.session import SessionConfig

    s = CalibrationSession(DEFAULT_BOARD, config=SessionConfig(roi=(160, 120, 480, 360)))
    for v in rendered[:7]:
        s.add_image(v.image, v.name)
    res = s.solve()
    whole = res.uncertainty.stats()
    inner = res.uncertainty.stats(s.config.roi)
    assert inner["max"] < whole["max"]
    assert s.report()["uncertainty_px"]["max"] == replace(res, roi=s.config.roi
                                                          ).uncertainty_stats()["max"]
