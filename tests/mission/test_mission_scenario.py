"""The scenario file: the shipped one is valid, errors name the file and the field."""

from __future__ import annotations

import math

import pytest
import yaml

from drovisio.mission.scenario import ScenarioError, load_scenario, parse_scenario, shipped_scenario
from drovisio.mission.scenario_model import MAX_BRICKS, MAX_FILE_BYTES


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
    (lambda d: d["thresholds"].update(retries=0), "thresholds.retries", "from 1 to 10"),
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


# ------------------------------------------------------------------ hostile sizes and numbers
def _many_bricks(n: int, spacing: float) -> dict:
    """The shipped scenario with ``n`` dot bricks (no ids) on a grid ``spacing`` apart, all in
    course 1 of one long wall."""
    d = _data()
    side = math.ceil(math.sqrt(n))
    d["layouts"] = ["drick-dots-2x3"]
    d["bricks"] = [{"id": f"b{k}", "layout": "drick-dots-2x3",
                    "pick": {"position": [1.0 + (k % side) * spacing,
                                          3.7 + (k // side) * spacing]}} for k in range(n)]
    d["site"]["pick_area"] = {"center": [1.0 + side * spacing / 2, 3.7 + side * spacing / 2],
                              "size": [side * spacing + 1, side * spacing + 1]}
    d["site"]["bounds"]["max"] = [2.0 + n * 0.3 + 1, 3.7 + side * spacing + 2, 3.5]
    d["wall"]["plan"] = [{"brick": f"b{k}", "course": 1, "slot": k} for k in range(n)]
    d["wall"].pop("order", None)
    return d


def test_a_hundred_bricks_apart_is_a_valid_scenario():
    scn = parse_scenario(_many_bricks(100, 0.5), "site/wall.yaml")
    assert len(scn.order) == 100


def test_more_bricks_than_a_scenario_holds_is_one_line():
    with pytest.raises(ScenarioError) as e:
        parse_scenario(_many_bricks(MAX_BRICKS + 1, 0.5), "site/wall.yaml")
    # the plan has as many entries: the second problem
    assert str(e.value) == (f"site/wall.yaml: bricks: {MAX_BRICKS + 1} entries; a scenario "
                            f"holds at most {MAX_BRICKS} (and 1 more problem in this file)")


def test_bricks_lying_together_give_one_problem_each_said_in_one_line():
    # 100 bricks on one spot: one problem a brick (99), not one a pair (4,950)
    with pytest.raises(ScenarioError) as e:
        parse_scenario(_many_bricks(100, 0.0), "site/wall.yaml")
    assert str(e.value) == ("site/wall.yaml: bricks[1].pick.position: [1.0, 3.7] is within "
                            "0.45 m of brick 'b0': bricks to pick must lie apart (and 98 more "
                            "problems in this file)")


def test_a_scenario_file_over_its_size_is_refused_unread(tmp_path):
    p = tmp_path / "big.yaml"
    p.write_text(shipped_scenario().read_text() + "#" * MAX_FILE_BYTES)
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    assert str(e.value) == (f"{p}: the scenario file is larger than {MAX_FILE_BYTES // 1024} "
                            "KiB; is it the right file?")


@pytest.mark.parametrize("field, value, says", [
    ("altitudes.descent_speed_mps", math.inf,
     "inf is not a finite number; give a number from 0.01 to 5 m/s"),
    ("altitudes.descent_speed_mps", 1e-300,
     "1e-300 is out of range: give a number from 0.01 to 5 m/s"),
    ("altitudes.cruise_m", math.nan,
     "nan is not a finite number; give a number above 0 and at most 120 m"),
    ("thresholds.align_timeout_s", 1e12,
     "1e+12 is out of range: give a number above 0 and at most 600 s"),
    ("thresholds.filter_frames", 10 ** 9,
     "1000000000 is out of range: give a whole number from 1 to 1000"),
    ("thresholds.retries", 10 ** 25,
     f"{10 ** 25} is out of range: give a whole number from 1 to 10"),
    ("site.bounds.max[0]", 1e9, "1e+09 is out of range: give a number from -10000 to 10000 m"),
    ("drone.camera.mount.tilt_deg", 1e308,
     "1e+308 is out of range: give a number from -90 to 90 degrees"),
    ("autopilot.wind_mps", math.nan, "nan is not a finite number; give a number from 0 to 20 m/s"),
])
def test_every_number_has_its_range_named(field, value, says):
    d = _data()
    *path, last = field.replace("[", ".").replace("]", "").split(".")
    node = d
    for k in path:
        node = node.setdefault(k, {}) if not k.isdigit() else node[int(k)]
    if last.isdigit():
        node[int(last)] = value
    else:
        node[last] = value
    with pytest.raises(ScenarioError) as e:
        parse_scenario(d, "site/wall.yaml")
    assert str(e.value) == f"site/wall.yaml: {field}: {says}"


def test_a_brick_resting_twice_on_one_brick_is_said_once():
    d = _data()
    d["wall"]["plan"][5]["rests_on"] = ["b6", "b6"]
    with pytest.raises(ScenarioError) as e:
        parse_scenario(d, "site/wall.yaml")
    assert str(e.value) == ("site/wall.yaml: wall.plan[5].rests_on: names 'b6' twice: the two "
                            "bricks below must differ")


def test_a_layout_name_is_a_name_and_a_layout_path_is_read_where_it_says(tmp_path):
    import json
    import os

    from drovisio.layout import shipped_layouts_dir

    shipped = shipped_layouts_dir() / "drick-aruco-pyramids.json"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "drick-aruco-pyramids.json").write_text(shipped.read_text())
    # a shipped name that climbs out of the shipped folder is no name
    climb = os.path.relpath(elsewhere / "drick-aruco-pyramids", shipped_layouts_dir())
    d = _data()
    d["layouts"] = [climb]
    with pytest.raises(ScenarioError) as e:
        parse_scenario(d, str(tmp_path / "scn.yaml"))
    assert str(e.value).startswith(f"{tmp_path / 'scn.yaml'}: layouts[0]: no shipped layout "
                                   f"called {climb!r}")
    # a .json path: beside the scenario, up from it, or absolute (the command line's files)
    (tmp_path / "plans").mkdir()
    for name in ("../elsewhere/drick-aruco-pyramids.json",
                 str(elsewhere / "drick-aruco-pyramids.json")):
        d = _data()
        d["layouts"] = [name]
        for b in d["bricks"]:
            b["layout"] = name
        scn = parse_scenario(json.loads(json.dumps(d)), str(tmp_path / "plans" / "scn.yaml"))
        assert scn.layout(name).name == "drick-aruco-pyramids"
