"""The replay API (/api/replay/...): listing, loading, playing a short simulated recording."""

from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from drovisio.mission.record import write_recording
from drovisio.mission.scenario import load_scenario, shipped_scenario
from drovisio.mission.sim import SimParams, simulate
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"  # the Host a browser on this machine sends


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """A folder with one short recording (one brick, detector model) and one broken one."""
    d = tmp_path_factory.mktemp("replays")
    scn = load_scenario(shipped_scenario()).subset(["b1"])
    write_recording(simulate(scn, params=SimParams(seed=2)), d / "one-brick", every=2)
    (d / "broken").mkdir()
    (d / "broken" / "manifest.json").write_text('{"schema": "something/else"}')
    return d


@pytest.fixture
def client(recordings):
    with TestClient(create_app(Settings(replay_dir=recordings)), base_url=LOCAL) as c:
        yield c


def test_lists_and_refuses_bad_input(client, recordings, tmp_path):
    r = client.get("/api/replay/runs")
    assert r.status_code == 200
    runs = {x["name"]: x for x in r.json()["runs"]}
    assert runs["one-brick"]["ok"] and runs["one-brick"]["outcome"] == "DONE"
    assert runs["broken"]["ok"] is False
    assert client.get("/api/replay/state").json() == {"loaded": False}
    assert client.post("/api/replay/play").status_code == 409
    r = client.post("/api/replay/load", json={"name": "broken"})
    assert r.status_code == 422 and "schema" in r.json()["detail"]
    r = client.post("/api/replay/load", json={"name": "nope"})
    assert r.status_code == 404 and "no recording folder" in r.json()["detail"]
    # only recordings inside the recordings folder: any other folder is refused
    r = client.post("/api/replay/load", json={"path": str(tmp_path)})
    assert r.status_code == 403 and "not in the recordings folder" in r.json()["detail"]
    r = client.post("/api/replay/load", json={"path": "../.."})
    assert r.status_code == 403
    (recordings / "empty").mkdir(exist_ok=True)
    r = client.post("/api/replay/load", json={"path": "empty"})
    assert r.status_code == 422 and "manifest.json" in r.json()["detail"]
    assert client.post("/api/replay/load", json={}).status_code == 422


def test_no_folder_configured(tmp_path):
    with TestClient(create_app(Settings()), base_url=LOCAL) as c:
        r = c.get("/api/replay/runs")
        assert r.status_code == 404 and "replay_dir" in r.json()["detail"]
    with TestClient(create_app(Settings(replay_dir=tmp_path / "missing")), base_url=LOCAL) as c:
        r = c.get("/api/replay/runs")
        assert r.status_code == 404 and "does not exist" in r.json()["detail"]


def test_load_play_seek_speed(client):
    st = client.post("/api/replay/load", json={"name": "one-brick"}).json()
    assert st["loaded"] and st["t"] == 0.0 and st["state"] == "TAKE_OFF" and not st["playing"]
    assert st["duration"] > 20
    st = client.post("/api/replay/seek", json={"t": 30}).json()
    assert st["t"] == 30 and st["state"] not in ("TAKE_OFF", "IDLE")
    assert st["events"] > 5 and st["last_events"][-1]["text"]
    st = client.post("/api/replay/seek", json={"t": 1e9}).json()
    assert st["t"] == st["duration"] and st["state"] == "DONE" and st["placed"] == ["b1"]
    assert client.post("/api/replay/speed", json={"x": 0}).status_code == 422
    assert client.post("/api/replay/seek", json={"t": "x"}).status_code == 422
    client.post("/api/replay/seek", json={"t": 0})
    st = client.post("/api/replay/speed", json={"x": 16}).json()
    assert st["speed"] == 16
    p0 = st["drone"]["position"]
    assert client.post("/api/replay/play").json()["playing"]
    # playing moves on (the playback thread's pace is a loaded machine's; the bound is
    # for failures only)
    end = time.monotonic() + 60
    while (st := client.get("/api/replay/state").json())["t"] <= 3:
        assert time.monotonic() < end, st
        time.sleep(0.05)
    assert st["drone"]["position"] != p0
    st = client.post("/api/replay/pause").json()
    t = st["t"]
    time.sleep(0.3)
    assert client.get("/api/replay/state").json()["t"] == t


def test_serve_replays_the_shipped_demo_mission_by_default():
    from drovisio import cli
    from webtool.serve import settings_from

    settings = settings_from(cli.build_parser().parse_args(["serve"]))
    assert settings.replay_dir is not None and settings.replay_dir.name == "missions"
    with TestClient(create_app(settings), base_url=LOCAL) as c:
        runs = c.get("/api/replay/runs").json()["runs"]
        assert [(r["name"], r["ok"], r["bricks"]) for r in runs] == [
            ("wall-first-3-bricks", True, 3)]
        st = c.post("/api/replay/load", json={"name": "wall-first-3-bricks"}).json()
        assert st["loaded"] and st["bricks_total"] == 3 and st["duration"] > 30


def test_events_read_in_words_and_odd_fields_do_not_break_them():
    """Each kind of tick event in plain words; a recording's odd field (an error that is not
    a number, an unknown kind) is shown as it is, never a crash."""
    from webtool.replay.service import _describe

    assert _describe({"kind": "placed", "brick": "b3", "error_m": 0.0123}) == \
        "brick b3 placed (1.2 cm off)"
    assert _describe({"kind": "placed", "brick": "b3", "error_m": "n/a"}) == \
        "brick b3 placed (n/a off)"
    assert _describe({"kind": "transition", "source": "PICK", "target": "LIFT",
                      "trigger": "grabbed"}) == "PICK → LIFT (grabbed)"
    assert _describe({"kind": "acquired", "brick": "b1", "frames": 3}) == \
        "brick b1 seen (3 frames)"
    assert _describe({"t": 1.0, "kind": "gust", "speed": 4}) == "gust: speed=4"
    assert _describe({"kind": ["x"]}) == "['x']"


@pytest.mark.parametrize("name", ["../../../../../../../tmp/evil", "/etc/passwd", ".hidden",
                                  "drick-aruco-centre/..", "a\x00b", "nope", 12, None])
def test_a_layout_name_in_a_recording_is_a_shipped_name_or_a_box(recordings, tmp_path, name):
    import json
    import shutil

    from drovisio.layout import list_shipped_layouts

    rec = tmp_path / "replays" / "odd"
    shutil.copytree(recordings / "one-brick", rec)
    manifest = json.loads((rec / "manifest.json").read_text())
    manifest["bricks"][0]["layout"] = name
    (rec / "manifest.json").write_text(json.dumps(manifest))
    before = {p.name: p.read_bytes() for p in rec.iterdir()}
    with TestClient(create_app(Settings(replay_dir=rec.parent)), base_url=LOCAL) as c:
        r = c.post("/api/replay/load", json={"name": "odd"})
        assert r.status_code == 200, r.text
        assert c.get("/api/replay/state").json()["note"] == (
            f"{rec / 'manifest.json'}: bricks[0].layout: no shipped layout called {name!r}; "
            f"give one of {', '.join(p.stem for p in list_shipped_layouts())}; the 3D view "
            "draws these bricks as boxes")
    assert {p.name: p.read_bytes() for p in rec.iterdir()} == before


def test_the_replay_scene_reads_no_layout_a_name_climbs_to(tmp_path):
    import os

    from drovisio.layout import shipped_layouts_dir
    from webtool.replay.scene import ReplayScene

    # a layout (and its mesh) outside the shipped folder, named by climbing out of it
    shipped = shipped_layouts_dir()
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "drick.stl").write_bytes((shipped / "meshes/drick.stl").read_bytes())
    (tmp_path / "evil.json").write_text((shipped / "drick-aruco-centre.json").read_text())
    climb = os.path.relpath(tmp_path / "evil", shipped_layouts_dir())
    scene = ReplayScene()
    assert scene._mesh(climb) is None
    assert scene._mesh("drick-aruco-centre") is not None     # a shipped name: its mesh


def test_a_recording_of_shipped_layouts_has_no_note(client):
    assert client.post("/api/replay/load", json={"name": "one-brick"}).json()["note"] is None
