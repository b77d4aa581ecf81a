"""Simulated missions with the detector model: the shipped wall, the fault table, records."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drovisio.mission.check import check_rules, format_table, run_case
from drovisio.mission.faults import CHECK_FAULTS, Fault, FaultCase, preset
from drovisio.mission.record import load_recording, write_recording
from drovisio.mission.sim import SimParams, simulate


def test_shipped_wall_completes_within_tolerance(wall):
    """Done-when #1 (detector model): 9 bricks, each within 5 cm and 3° of its plan."""
    tr = simulate(wall, params=SimParams(seed=0))
    assert tr.final_state == "DONE"
    assert sorted(tr.placements) == sorted(wall.order)
    pos, yaw = tr.placement_errors()
    assert pos.max() <= wall.placement_tolerance.position_m
    assert yaw.max() <= wall.placement_tolerance.yaw_deg
    assert all(p["verified"] for p in tr.placements.values())
    assert all(r.held for r in check_rules(tr)), check_rules(tr)


@pytest.mark.parametrize("case", CHECK_FAULTS, ids=[c.name for c in CHECK_FAULTS])
def test_fault_table_on_three_bricks(small, case):
    r = run_case(small, case, SimParams(seed=3))
    assert r.all_held, [x for x in r.rules if not x.held]
    assert r.as_expected, (r.outcome, r.narrative)


def test_fault_narratives(small):
    res = [run_case(small, preset(n), SimParams(seed=3))
           for n in ("three failed drops", "missed grab")]
    assert "failed 3/3" in res[0].narrative and "safe zone" in res[0].narrative
    assert "failed 1/3" in res[1].narrative and "retried" in res[1].narrative
    table = format_table(res)
    assert "three failed drops" in table and "all held" in table


def test_long_total_station_outage_ends_in_the_safe_zone(small):
    case = FaultCase("outage", (Fault("ts_dropout", state="ALIGN_SLOT", brick="b2",
                                      duration_s=60.0),), "safe_zone")
    r = run_case(small, case, SimParams(seed=1))
    assert r.outcome == "safe_zone" and r.all_held, r.narrative


def test_recording_round_trip(small, tmp_path):
    tr = simulate(small.subset(["b1"]), params=SimParams(seed=2))
    out = write_recording(tr, tmp_path / "rec")
    manifest, ticks = load_recording(out)
    assert manifest["schema"] == "drovisio/mission-recording@1"
    assert manifest["quaternion_order"] == "wxyz" and manifest["outcome"] == "DONE"
    assert manifest["ticks"] == len(ticks) > 100
    assert {t["state"] for t in ticks} >= {"TAKE_OFF", "GRAB", "RELEASE", "DONE"}
    t = [x["t"] for x in ticks]
    assert t == sorted(t)
    first = ticks[0]
    assert set(first) >= {"t", "state", "drone", "setpoint", "picker", "holding", "events",
                          "bricks"}
    q = np.array(first["drone"]["quat_wxyz"])
    assert abs(np.linalg.norm(q) - 1) < 1e-5
    # every transition event of the run is in the record (none lost by decimation)
    n_trans = sum(1 for tk in tr.ticks for e in tk.events if e["kind"] == "transition")
    assert sum(1 for x in ticks for e in x["events"] if e["kind"] == "transition") == n_trans
    assert (out / "scenario.yaml").exists()
    json.dumps(manifest)


def test_a_layout_named_by_its_file_flies_like_the_shipped_one(tmp_path):
    """``layouts: [my.json]`` (a layout file beside the scenario) is checked and flown: the
    detector names what it sees by the layout's own name, the scenario by the file."""
    from drovisio.layout import shipped_layouts_dir
    from drovisio.mission.scenario import load_scenario, shipped_scenario

    (tmp_path / "my.json").write_bytes(
        (shipped_layouts_dir() / "drick-aruco-pyramids.json").read_bytes())
    text = shipped_scenario().read_text(encoding="utf-8").replace(
        "drick-aruco-pyramids", "my.json")
    (tmp_path / "s.yaml").write_text(text, encoding="utf-8")
    scn = load_scenario(tmp_path / "s.yaml")
    assert scn.layouts == ["my.json"] and scn.layout_of("b1").name == "drick-aruco-pyramids"
    tr = simulate(scn.subset(["b1", "b2", "b6"]), params=SimParams(seed=3))
    assert tr.final_state == "DONE" and sorted(tr.placements) == ["b1", "b2", "b6"]
