"""Property tests over random fault sequences (hypothesis): the safety rules always hold.

* never more than ``retries`` (3) failures / attempts of a phase;
* after the third failure of a phase, or a total-station/vision disagreement, only the safe
  path (GO_SAFE → LAND_SAFE → SHUTDOWN), ending on the ground inside the safe zone;
* never a descent onto a brick while the yaw error exceeds the tolerance;
* never a setpoint outside the site;
and every run ends (DONE or SHUTDOWN), never stuck.
"""

from __future__ import annotations

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drovisio.mission.check import check_rules
from drovisio.mission.faults import Fault
from drovisio.mission.machine import State
from drovisio.mission.sim import SimParams, simulate

STATES = [s.value for s in State if s not in (State.IDLE, State.DONE, State.SHUTDOWN,
                                               State.GO_SAFE, State.LAND_SAFE)]
BRICKS = ["b1", "b2", "b6", None]


@st.composite
def faults(draw):
    kind = draw(st.sampled_from(["grab_fail", "release_fail", "vision_loss", "vision_offset",
                                 "ts_dropout", "ts_offset", "gust", "ts_blocked"]))
    brick = draw(st.sampled_from(BRICKS))
    if kind in ("grab_fail", "release_fail"):
        return Fault(kind, brick=brick, count=draw(st.integers(1, 4)))
    magnitude = {"vision_offset": st.floats(0.02, 0.5), "ts_offset": st.floats(0.02, 0.5),
                 "gust": st.floats(0.1, 0.8), "ts_blocked": st.floats(0.5, 3.0)}.get(
        kind, st.just(0.3))
    box = None
    if kind == "ts_blocked":  # a container between the station and the wall or the pick area
        x = draw(st.floats(-0.5, 2.5))
        box = (x, -0.8, x + 1.0, draw(st.floats(-0.5, 2.5)))
        box = (box[0], min(box[1], box[3]), box[2], max(box[1], box[3]) + 0.1)
    return Fault(kind, state=draw(st.sampled_from(STATES)), brick=brick,
                 occurrence=draw(st.integers(1, 2)), delay_s=draw(st.floats(0.0, 3.0)),
                 duration_s=draw(st.floats(0.2, 15.0)), magnitude=draw(magnitude), box=box)


@settings(max_examples=12, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(fs=st.lists(faults(), min_size=1, max_size=4), seed=st.integers(0, 10_000))
def test_safety_rules_hold_under_random_faults(small, fs, seed):
    tr = simulate(small, tuple(fs), SimParams(seed=seed, max_time_s=900))
    assert tr.final_state in ("DONE", "SHUTDOWN"), (tr.final_state, fs)
    rules = {r.rule: r for r in check_rules(tr)}
    for name in ("retries", "safe_zone", "yaw_descent", "geofence"):
        assert rules[name].held, (name, rules[name].detail, fs, seed)
    n = small.thresholds.retries
    fails = [e for e in tr.events("phase_failed")]
    assert all(e["failure"] <= n for e in fails)
    if any(e["failure"] == n for e in fails) or tr.events("disagreement"):
        assert tr.final_state == "SHUTDOWN"
        sz = small.site.safe_zone
        assert math.dist(tr.ticks[-1].position[:2], sz.center) <= sz.radius


@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(fs=st.lists(faults(), min_size=0, max_size=3), seed=st.integers(0, 10_000),
       rate=st.sampled_from([1.8, 4.0, 15.0]), wind=st.floats(0.0, 6.0),
       latency_ms=st.floats(0.0, 200.0))
def test_safety_rules_hold_with_the_autopilots_precision_landing(small, fs, seed, rate, wind,
                                                                  latency_ms):
    """The autopilot flying the pick descents on its own estimate (ArduPilot's model) does not
    break a rule: it only moves the touchdown, and the picker sensor decides."""
    scn = small.model_copy(update={"autopilot": small.autopilot.model_copy(update={
        "precision_landing": True, "rate_hz": rate, "wind_mps": wind,
        "latency_ms": latency_ms})})
    tr = simulate(scn, tuple(fs), SimParams(seed=seed, max_time_s=900))
    assert tr.final_state in ("DONE", "SHUTDOWN"), (tr.final_state, fs)
    rules = {r.rule: r for r in check_rules(tr)}
    for name in ("retries", "safe_zone", "yaw_descent", "geofence"):
        assert rules[name].held, (name, rules[name].detail, fs, seed)
    for d in tr.landings:
        assert 0.0 <= d["error_m"] < 1.0 and isinstance(d["initialised"], bool)
        if rate < 2.0:
            assert not d["initialised"]
