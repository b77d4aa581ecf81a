"""End to end for one brick: images rendered by drovisio.synth through the real ArUco detector
(drovisio.detect.aruco) drive the machine; the brick lands within tolerance.

The whole wall through renders takes minutes: ``drovisio mission simulate wall-2-courses
--vision render --record DIR`` (figures in the issue's closing note)."""

from __future__ import annotations

import pytest

from drovisio.mission.check import check_rules
from drovisio.mission.sim import SimParams, simulate


def test_one_brick_through_renders_and_the_real_detector(wall):
    pytest.importorskip("drovisio.detect.aruco")
    scn = wall.subset(["b1"])
    tr = simulate(scn, params=SimParams(seed=0, vision="render", render_ss=2,
                                        render_rate_hz=3.0))
    assert "drovisio.detect.aruco" in tr.detector
    assert tr.render_frames >= 20
    assert tr.final_state == "DONE", [e for e in tr.events() if e["kind"] != "transition"]
    p = tr.placements["b1"]
    assert p["error_m"] <= scn.placement_tolerance.position_m
    assert p["yaw_error_deg"] <= scn.placement_tolerance.yaw_deg
    assert all(r.held for r in check_rules(tr))
