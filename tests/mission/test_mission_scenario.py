"""The scenario file: the shipped one is valid, errors name the file and the field."""

from __future__ import annotations

import math

import pytest
import yaml

from drovisio.mission.scenario import ScenarioError, load_scenario, parse_scenario, shipped_scenario


def _data():
    return yaml.safe_load(shipped_scenario().read_text())


def test_shipped_scenario_is_a_two_course_running_bond(wall):
    assert wall.name == "wall-2-courses"
    courses = [wall.plan_by_id[b].course for b in wall.order]
    assert courses.count(1) == 5 and courses.count(2) == 4
    pitch = wall.wall.brick_pitch_m
    for b in wall.order:
        e = wall.plan_by_id[b]
        if e.course == 2:
            lo, hi = (wall.slot_pose(x) for x in e.rests_on)
            s = wall.slot_pose(b)
            assert math.dist((lo.x, lo.y), (hi.x, hi.y)) == pytest.approx(pitch)
            assert (s.x, s.y) == pytest.approx(((lo.x + hi.x) / 2, (lo.y + hi.y) / 2))
            assert s.z == pytest.approx(lo.z + wall.wall.course_height_m)
    assert wall.references("b1") == [] and wall.references("b2") == ["b1"]
    assert wall.references("b7") == ["b2", "b3"]
    assert wall.thresholds.retries == 3


def test_package_data_holds_the_scenario():
    assert shipped_scenario().is_file()


@pytest.mark.parametrize("mutate, where, words", [
    (lambda d: d["bricks"][2].update(instance=40), "bricks[2].instance", "out of range"),
    (lambda d: d["bricks"][1].update(instance=0), "bricks[1].instance", "same codes"),
    (lambda d: d["wall"]["plan"][6].update(rests_on=["b2", "b4"]), "wall.plan[6].rests_on",
     "not neighbours"),
    (lambda d: d["wall"]["plan"][5].update(rests_on=["b1"]), "wall.plan[5]", "exactly two"),
    (lambda d: d["wall"].update(order=["b6", "b1", "b2", "b3", "b4", "b5", "b7", "b8", "b9"]),
     "wall.order", "built before"),
    (lambda d: d["bricks"][0].update(layout="drick-nope"), "bricks[0].layout", "not in"),
    (lambda d: d["site"]["safe_zone"].update(center=[2.3, 0.8]), "site.safe_zone",
     "within 0.5 m of the wall"),
    (lambda d: d["thresholds"].update(align_yaw_tolerance_deg=5),
     "thresholds.align_yaw_tolerance_deg", "placement_tolerance"),
    (lambda d: d["altitudes"].update(cruise_m=0.8), "altitudes.cruise_m", "1 m"),
    (lambda d: d["thresholds"].update(retries=0), "thresholds.retries", "greater than"),
    (lambda d: d.pop("wall"), "wall", "Field required"),
    (lambda d: d["site"].update(home=[9.0, 0.0]), "site.home", "inside site.bounds"),
    (lambda d: d["wall"]["plan"][3].update(slot=1), "wall.plan[3].slot", "already holds"),
])
def test_errors_name_file_and_field(mutate, where, words):
    d = _data()
    mutate(d)
    with pytest.raises(ScenarioError) as e:
        parse_scenario(d, "site/wall.yaml")
    msg = str(e.value)
    assert f"site/wall.yaml: {where}" in msg, msg
    assert words in msg, msg


def test_bad_files(tmp_path):
    with pytest.raises(ScenarioError, match="scenario file not found"):
        load_scenario(tmp_path / "missing.yaml")
    p = tmp_path / "x.yaml"
    p.write_text("schema: [unclosed")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(p)
    p.write_text("schema: something-else\n")
    with pytest.raises(ScenarioError, match="schema: expected"):
        load_scenario(p)


def test_subset_is_validated(wall):
    small = wall.subset(["b1", "b2", "b6"])
    assert small.order == ["b1", "b2", "b6"]
    with pytest.raises(ScenarioError, match="not planned"):
        wall.subset(["b1", "b6"])


def test_yaml_on_is_explained():
    text = shipped_scenario().read_text().replace("rests_on: [b1, b2]", "on: [b1, b2]")
    with pytest.raises(ScenarioError, match=r"wall.plan\[5\]: .*'rests_on'"):
        parse_scenario(text, "w.yaml")
