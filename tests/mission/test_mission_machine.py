"""The state machine on its own: the table is consistent, step is pure, scripted inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drovisio.mission import machine as M
from drovisio.mission.frames import site_from_body, site_from_brick
from drovisio.mission.machine import (
    TRANSITIONS,
    Memory,
    MissionPlan,
    Readings,
    Sighting,
    State,
    step,
)

S = State


def test_every_state_is_reachable_and_every_live_state_can_leave():
    targets = {S.IDLE}
    frontier = [S.IDLE]
    while frontier:
        s = frontier.pop()
        for t in TRANSITIONS:
            if t.source is s and t.target not in targets:
                targets.add(t.target)
                frontier.append(t.target)
    assert targets == set(State)
    sources = {t.source for t in TRANSITIONS}
    assert sources == set(State) - {S.DONE, S.SHUTDOWN}
    # the safe path only leads to the shutdown
    for t in TRANSITIONS:
        if t.source in (S.GO_SAFE, S.LAND_SAFE):
            assert t.target in (S.LAND_SAFE, S.SHUTDOWN)


def test_every_phase_state_fails_to_retry_or_safe_zone():
    for s in M.PICK_STATES:
        assert M.next_state(s, "fail") is S.RETRY_PICK
        assert M.next_state(s, "fail_final") is S.GO_SAFE
    for s in M.DROP_STATES:
        assert M.next_state(s, "fail") is S.RETRY_DROP
        assert M.next_state(s, "fail_final") is S.GO_SAFE
    with pytest.raises(RuntimeError, match="no transition"):
        M.next_state(S.DONE, "start")


class Bench:
    """Feeds hand-made readings to :func:`step` (no simulator): the drone is where the
    setpoint says, the total station reads it exactly."""

    def __init__(self, scn):
        self.plan = MissionPlan.from_scenario(scn)
        self.mem = Memory()
        self.t = 0.0
        self.pos = np.array([*scn.site.home, scn.drone.gear_height_m])
        self.yaw = 0.0
        self.holding = False
        self.outputs = []
        self.yaw_step = math.radians(1.0)  # per tick: 20°/s

    def tick(self, ts=True, vision=None, dt=0.05):
        r = Readings(self.t, tuple(self.pos) if ts else None, tuple(self.pos), self.yaw,
                     vision, self.holding)
        self.mem, out = step(self.plan, self.mem, r)
        self.outputs.append(out)
        if out.setpoint is not None:
            sp = np.asarray(out.setpoint.position)
            d = sp - self.pos
            n = np.linalg.norm(d)
            self.pos = self.pos + (d if n < 0.05 else d / n * 0.05)
            dy = math.remainder(out.setpoint.yaw - self.yaw, 2 * math.pi)
            self.yaw += max(-self.yaw_step, min(self.yaw_step, dy))
        self.t = round(self.t + dt, 6)
        return out


def _see(bench, scn, bid, T_world):
    """A sighting of brick ``bid`` at ``T_world`` from the drone's current pose."""
    b = scn.brick_by_id[bid]
    bfb = np.linalg.inv(site_from_body(bench.pos, bench.yaw)) @ T_world
    return (Sighting(b.layout, b.instance, bfb),)


def test_step_is_pure(small):
    plan = MissionPlan.from_scenario(small)
    r = Readings(0.0, (0.0, 0.0, 0.2), (0.0, 0.0, 0.2), 0.0)
    m1, o1 = step(plan, Memory(), r)
    m2, o2 = step(plan, Memory(), r)
    assert m1 == m2 and o1 == o2
    assert o1.state is S.TAKE_OFF


def test_pick_sequence_with_scripted_vision(small):
    """Take off, fly to b1, see it (yaw 10°, 3 cm off), align, descend, go blind, grab."""
    bench = Bench(small)
    pp = small.pick_pose("b1")
    T = site_from_brick((pp.x + 0.03, pp.y - 0.02, pp.z), pp.yaw + math.radians(10))
    states = []
    for _ in range(3000):
        st = bench.mem.state
        vis = None
        if st in M.VISION_STATES and round(bench.t / 0.05) % 2 == 0:
            cam_h = bench.pos[2] - 0.05 - pp.z
            vis = _see(bench, small, "b1", T) if cam_h > 0.25 else ()
        if st is S.GRAB:
            bench.holding = True
        out = bench.tick(vision=vis)
        if not states or states[-1] is not out.state:
            states.append(out.state)
        if out.state is S.CLIMB_WITH_BRICK:
            break
    assert states[:9] == [S.TAKE_OFF, S.GO_TO_BRICK, S.ACQUIRE_BRICK, S.ALIGN_BRICK,
                          S.DESCEND_BRICK, S.BLIND_DESCENT_BRICK, S.GRAB, S.CLIMB_WITH_BRICK][:9]
    # aligned on the brick, not on its pick pose
    grabbed = [e for o in bench.outputs for e in o.events if e.kind == "grabbed"][0]
    assert abs(grabbed.detail["offset_m"][0]) < 0.02 and abs(grabbed.detail["offset_m"][1]) < 0.02
    assert abs(math.remainder(bench.yaw - (pp.yaw + math.radians(10)), math.pi)) < math.radians(1)


def test_total_station_loss_fails_the_phase_then_safe_zone(small):
    bench = Bench(small)
    for _ in range(400):
        if bench.tick().state is S.GO_TO_BRICK:
            break
    seen = []
    for _ in range(2000):
        out = bench.tick(ts=False)
        seen.extend(e for e in out.events if e.kind in ("phase_failed", "safe_zone"))
        if out.state is S.GO_SAFE:
            break
    kinds = [(e.kind, e.detail.get("failure")) for e in seen]
    # GO_TO_BRICK fails (1), RETRY_PICK waits ts_wait_s for the station, then gives up
    assert kinds[0] == ("phase_failed", 1)
    assert kinds[-1][0] == "safe_zone"
    assert bench.mem.state is S.GO_SAFE


def test_disagreement_goes_to_safe_zone(small):
    """Vision puts the pick brick 0.4 m from where the total station says: safe zone."""
    bench = Bench(small)
    pp = small.pick_pose("b1")
    T = site_from_brick((pp.x, pp.y, pp.z), pp.yaw)
    for _ in range(3000):
        vis = None
        if bench.mem.state in M.VISION_STATES:
            vis = _see(bench, small, "b1", T)
            # the station is wrong by 0.4 m: shift what vision sees the other way
            v = vis[0].body_from_brick.copy()
            v[:3, 3] += np.linalg.inv(site_from_body(bench.pos, bench.yaw))[:3, :3] @ [0.4, 0, 0]
            vis = (Sighting(vis[0].layout, vis[0].instance, v),)
        out = bench.tick(vision=vis)
        if out.state is S.GO_SAFE:
            break
    ev = [e for o in bench.outputs for e in o.events]
    assert any(e.kind == "disagreement" and e.detail["distance_m"] > 0.35 for e in ev)
    assert bench.mem.state is S.GO_SAFE


def test_never_descends_with_a_large_yaw_error(small):
    """The brick appears to turn by 6° mid-descent: stop, realign (never descend meanwhile)."""
    bench = Bench(small)
    bench.yaw_step = math.radians(0.2)  # a slow yaw: the error shows before it is corrected
    pp = small.pick_pose("b1")
    tol = math.radians(small.thresholds.align_yaw_tolerance_deg)
    turned = False
    prev_z = None
    for _ in range(4000):
        st = bench.mem.state
        yaw = pp.yaw + (math.radians(6) if turned else 0.0)
        vis = _see(bench, small, "b1", site_from_brick(pp.xyz, yaw)) \
            if st in M.VISION_STATES else None
        out = bench.tick(vision=vis)
        z = out.setpoint.position[2] if out.setpoint else None
        if out.state is S.DESCEND_BRICK and prev_z is not None and z < prev_z - 1e-9:
            assert abs(out.telemetry["yaw_error"]) <= tol
            if bench.pos[2] < 0.9:
                turned = True
        prev_z = z
        if out.state is S.BLIND_DESCENT_BRICK:
            break
    ev = [e.kind for o in bench.outputs for e in o.events]
    assert "misaligned" in ev and "blind" in ev
