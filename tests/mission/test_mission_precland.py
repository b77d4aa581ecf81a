"""The mission simulator's pick descents flown by the model of ArduPilot's precision landing
(:class:`drovisio.autopilot.precland.PrecLandEstimator` in the simulator's own tick loop),
against the trend measured on the real autopilot (ArduCopter SITL fed by Drovisio): a down
camera lands 1-3 cm off in 3 m/s wind, the 20° forward mount several cm off on its last
estimate, and below 2 Hz the filter never initialises."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from drovisio import cli
from drovisio.autopilot.blind import blind_height
from drovisio.autopilot.precland import INIT_TIME_S, PrecLandEstimator
from drovisio.mission.check import landing_lines
from drovisio.mission.scenario import ScenarioError, parse_scenario
from drovisio.mission.sim import SimParams, body_from_camera_for, camera_for, simulate
from drovisio.mount import Mount


def _variant(wall, *, n=2, tilt=0.0, **autopilot):
    d = wall.model_dump(by_alias=True, exclude_none=True)
    d["autopilot"] = {"precision_landing": True, **autopilot}
    d["drone"]["camera"]["mount"]["tilt_deg"] = tilt
    if tilt:
        # the tilted camera sees the brick below only higher up
        d["altitudes"].update(approach_m=2.2, cruise_m=2.6)
    scn = parse_scenario(json.dumps(d), "<test>")
    return scn.subset(scn.order[:n])


def _touchdowns(scn, seeds):
    """Every pick descent that reached the brick (the grab was tried), over ``seeds``."""
    out = []
    for s in seeds:
        tr = simulate(scn, (), SimParams(seed=s))
        out += [d for d in tr.landings if d["outcome"] == "GRAB"]
    return out


def test_down_camera_at_15_hz_lands_within_3_cm_in_3_mps_wind(wall):
    scn = _variant(wall, rate_hz=15.0, wind_mps=3.0)
    tr = simulate(scn, (), SimParams(seed=0))
    assert tr.final_state == "DONE"
    downs = [d for d in tr.landings if d["outcome"] == "GRAB"]
    downs += _touchdowns(scn, [1])
    assert len(downs) >= 4
    err = [d["error_m"] for d in downs]
    assert np.median(err) <= 0.03 and max(err) <= 0.04, err
    for d in downs:
        assert d["initialised"] and d["init_failures"] == 0
        # the brick stays in the picture down to ~20 cm: the landing is not blind for long
        assert d["last_seen_camera_height_m"] < 0.3
        assert d["estimate_error_m"] <= 0.03


def test_forward_mount_lands_several_cm_off_on_its_last_estimate(wall):
    down = _touchdowns(_variant(wall, rate_hz=15.0, wind_mps=3.0), [0, 1])
    scn = _variant(wall, tilt=20.0, rate_hz=15.0, wind_mps=3.0)
    tilted = _touchdowns(scn, [0, 1])
    err = np.array([d["error_m"] for d in tilted])
    # several cm off, more than twice the down camera's, some beyond the 5 cm tolerance (the
    # grab then fails and the phase is retried)
    assert 0.025 <= float(np.median(err)) <= 0.10, err
    assert np.median(err) > 2 * np.median([d["error_m"] for d in down])
    assert err.max() > 0.05 and err.max() < 0.15
    # the blind height reported is the lens-and-mount one, and the brick was indeed last seen
    # about there (lower or higher as the drone stands behind or ahead of it)
    want = blind_height(camera_for(scn), Mount(body_from_camera_for(scn)),
                        scn.layout(scn.layouts[0])).leaves_at_m
    assert want is not None and 0.4 < want < 0.8
    for d in tilted:
        assert d["initialised"] and d["blind_height_m"] == pytest.approx(want)
        assert d["last_seen_camera_height_m"] > 0.25    # the down camera sees it to ~0.18 m
    seen = np.median([d["last_seen_camera_height_m"] for d in tilted])
    assert abs(seen - want) < 0.15
    tr = simulate(scn, (), SimParams(seed=0))
    text = "\n".join(landing_lines(tr))
    assert f"leaves the picture {want:.2f} m above it" in text and "WARNING" not in text


def test_below_2_hz_the_filter_never_initialises_and_the_check_warns(wall, tmp_path, capsys):
    scn = _variant(wall, n=1, rate_hz=1.8, detect_prob=1.0)
    tr = simulate(scn, (), SimParams(seed=0))
    assert tr.landings
    for d in tr.landings:
        assert not d["initialised"] and d["init_failures"] >= 3 and d["measurements"] >= 3
        assert d["estimate_error_m"] is None
    lines = landing_lines(tr)
    assert "NEVER initialised" in lines[0]
    assert lines[-1].startswith("WARNING") and "1.8 detections a second" in lines[-1]
    path = tmp_path / "slow.yaml"
    path.write_text(yaml.safe_dump(scn.model_dump(by_alias=True, exclude_none=True)))
    rc = cli.main(["mission", "check", str(path), "--fault", "no fault", "--json",
                   str(tmp_path / "t.json")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "pick descent onto b1" in out and "NEVER initialised" in out
    assert "WARNING: ArduPilot's precision-landing filter never initialised on b1" in out
    rows = json.loads((tmp_path / "t.json").read_text())
    assert rows[0]["landings"][0]["initialised"] is False


def test_without_precision_landing_the_descent_is_recorded_without_the_filter(small):
    tr = simulate(small.subset(["b1"]), (), SimParams(seed=0))
    assert tr.final_state == "DONE"
    (d,) = [d for d in tr.landings if d["outcome"] == "GRAB"]
    assert d["error_m"] < 0.03 and "initialised" not in d
    assert landing_lines(tr)[0].startswith("pick descent onto b1")


@pytest.mark.parametrize("field, value", [("rate_hz", -1), ("detect_prob", 1.5),
                                          ("latency_ms", float("nan")), ("wind_mps", 1e9),
                                          ("precision_landing", "maybe")])
def test_bad_autopilot_options_are_named(wall, field, value):
    d = wall.model_dump(by_alias=True, exclude_none=True)
    d["autopilot"] = {field: value}
    with pytest.raises(ScenarioError, match=f"autopilot.{field}"):
        parse_scenario(json.dumps(d), "scn.yaml")


def _feed(period_s, dt, seconds=6.0, lag_s=0.05):
    est = PrecLandEstimator(lag_s, dt)
    t, next_msg = 0.0, 0.0
    R = np.eye(3)
    while t < seconds:
        est.record(np.zeros(2), R)
        if t + 1e-9 >= next_msg:
            est.send(t + lag_s, np.array([0.1, -0.2, 1.0]))
            next_msg += period_s
        est.update(t)
        t = round(t + dt, 9)
    return est


@pytest.mark.parametrize("dt", [0.01, 0.05])
def test_estimator_rules_hold_on_a_coarse_tick(dt):
    slow = _feed(0.55, dt)           # 1.8 Hz: every gap is over 0.5 s
    assert not slow.ever_acquired and slow.init_fail >= 5
    fast = _feed(0.45, dt)
    assert fast.ever_acquired
    assert fast.initialised_at == pytest.approx(0.05 + INIT_TIME_S, abs=2 * dt)
    assert fast.last_estimate == pytest.approx([0.1, -0.2], abs=1e-6)
    # the process noise per second does not depend on the tick (0.4 s of prediction)
    a, b = (PrecLandEstimator(0.0, d) for d in (0.01, 0.05))
    for est, d in ((a, 0.01), (b, 0.05)):
        est.record(np.zeros(2), np.eye(3))
        est.send(0.0, np.array([0.0, 0.0, 1.0]))
        est.update(0.0)
        for k in range(1, int(round(0.4 / d)) + 1):   # under the 0.5 s init gap
            est.record(np.zeros(2), np.eye(3))
            est.update(k * d)
    assert a.kf is not None and b.kf is not None
    assert math.isclose(a.kf[0].P[1, 1], b.kf[0].P[1, 1], rel_tol=1e-9)


def test_simulate_prints_and_records_each_pick_descent(wall, tmp_path, capsys):
    scn = _variant(wall, n=1, rate_hz=15.0, wind_mps=3.0)
    path = tmp_path / "one.yaml"
    path.write_text(yaml.safe_dump(scn.model_dump(by_alias=True, exclude_none=True)))
    assert cli.main(["mission", "simulate", str(path), "--record", str(tmp_path / "rec")]) == 0
    out = capsys.readouterr().out
    assert "pick descent onto b1" in out and "filter initialised" in out
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    (grab,) = [d for d in manifest["landings"] if d["outcome"] == "GRAB"]
    assert grab["initialised"] is True and grab["error_m"] <= 0.03


@pytest.mark.parametrize("tilt, approach, field, fix", [
    (20.0, 0.6, "altitudes.approach_m", "raise approach_m above 0.73 m"),   # leaves at 0.58 m
    (35.0, 1.2, "drone.camera.mount.tilt_deg", "tilt the camera less")])   # never below
def test_a_brick_the_descent_cannot_see_is_refused_by_name(wall, tmp_path, capsys, tilt,
                                                            approach, field, fix):
    d = wall.model_dump(by_alias=True, exclude_none=True)
    d["autopilot"] = {"precision_landing": True}
    d["drone"]["camera"]["mount"]["tilt_deg"] = tilt
    d["altitudes"].update(approach_m=approach, blind_below_m=0.3)
    path = tmp_path / "steep.yaml"
    path.write_text(yaml.safe_dump(d))
    assert cli.main(["mission", "check", str(path), "--fault", "no fault"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"drovisio mission: {path}: {field}:"), err
    assert fix in err[0] and "Traceback" not in err[0]
