"""Class: paths found inside files, and folders the web tool lists entry by entry.

* A recording's manifest names its ticks file: ``/dev/zero``, a FIFO, ``../../etc/passwd``,
  an absolute path, a NUL byte, a name of 300 bytes, a folder, a file over the cap — each is
  refused by the one path reader (:func:`drovisio.textfile.read_inside`) with one line naming
  the manifest and ``ticks_file``; the server never blocks, grows or leaves the folder.
* ``GET /api/replay/runs`` and ``GET /api/study/reports`` over folders of generated entries
  (valid, malformed JSON, the wrong type, NaN, huge numbers, a FIFO or a folder where a file
  should be): always 200, every bad entry skipped and named, the good ones listed; a bad
  load never replaces the loaded recording and ``/api/replay/state`` stays 200.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st

from drovisio.errors import InputError
from drovisio.mission.record import load_recording
from drovisio.resources import sample_sessions_dir

LOCAL = "http://127.0.0.1:8080"
SAMPLE_RUN = sample_sessions_dir() / "missions"


def _settings(n: int):
    from hypothesis import HealthCheck, settings

    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


def _sample_run() -> Path:
    return next(p.parent for p in SAMPLE_RUN.rglob("manifest.json"))


def _copy_run(dst: Path, ticks_file=None, ticks_text: str | None = None) -> Path:
    src = _sample_run()
    dst.mkdir(parents=True, exist_ok=True)
    manifest = json.loads((src / "manifest.json").read_text())
    shutil.copy(src / "ticks.jsonl", dst / "ticks.jsonl")
    if ticks_text is not None:
        (dst / "ticks.jsonl").write_text(ticks_text)
    if ticks_file is not None:
        manifest["ticks_file"] = ticks_file
    (dst / "manifest.json").write_text(json.dumps(manifest))
    return dst


def _bad_ticks_file(kind: str, d: Path) -> str:
    if kind == "fifo":
        os.mkfifo(d / "ticks.fifo")
        return "ticks.fifo"
    if kind == "folder":
        (d / "ticks.d").mkdir()
        return "ticks.d"
    return {"zero": "/dev/zero", "passwd": "../../../../../../../../etc/passwd",
            "absolute": "/etc/hostname", "nul": "ticks\x00.jsonl", "long": "t" * 300,
            "missing": "nope.jsonl", "number": 7, "empty": "", "urandom": "/dev/urandom",
            "proc": "/proc/self/mem", "link": "link.jsonl"}[kind]


KINDS = ["fifo", "folder", "zero", "passwd", "absolute", "nul", "long", "missing", "number",
         "empty", "urandom", "proc", "link"]


@pytest.mark.parametrize("kind", KINDS)
def test_a_ticks_file_named_in_a_manifest_is_read_only_inside_its_folder(tmp_path, ledger,
                                                                        kind):
    d = tmp_path / "run"
    d.mkdir()
    if kind == "link":
        (d / "link.jsonl").symlink_to("/etc/passwd")
    name = _bad_ticks_file(kind, d)
    _copy_run(d, ticks_file=name)
    ledger.tried_one("files inside files: recording manifest")
    with pytest.raises(InputError) as e:
        load_recording(d)
    msg = str(e.value)
    assert "ticks_file" in msg and "manifest.json" in msg, msg
    assert "\n" not in msg and len(msg) < 600


@_settings(60)
@given(lines=st.lists(st.one_of(
    st.just('{"t": NaN, "state": "X", "drone": {}}'),
    st.just('{"t": 1e400, "state": "X", "drone": {}}'),
    st.just('{"t": "1", "state": "X", "drone": {}}'),
    st.just('{"t": ' + "9" * 5000 + ', "state": "X", "drone": {}}'),
    st.just('{"t": 1, "state": 3, "drone": {}}'),
    st.just('{"t": 1, "state": "X", "drone": {}, "events": [1, 2]}'),
    st.just('{"t": 1, "state": "X", "drone": {}, "events": {}}'),
    st.just("[1, 2, 3]"), st.just("{"), st.just('"t"'),
    st.just('{"t": 0.5, "state": "X", "drone": {"position": [0, 0, 1]}}'),
    st.text(max_size=30)), min_size=1, max_size=6))
def test_every_tick_is_checked_or_the_recording_refused(tmp_path_factory, ledger, lines):
    d = _copy_run(tmp_path_factory.mktemp("run"), ticks_text="\n".join(lines) + "\n")
    ledger.tried_one("files inside files: ticks")
    try:
        _, ticks = load_recording(d)
    except InputError as e:
        assert "\n" not in str(e) and "ticks.jsonl" in str(e)
        return
    times = [t["t"] for t in ticks]
    assert times == sorted(times) and all(isinstance(t, (int, float)) for t in times)


# ------------------------------------------------------------------ the replay listing


ENTRY_KINDS = ["good", "bad_json", "list", "nan", "schema", "fifo_manifest", "folder_manifest",
               "zero_ticks", "huge_number", "text_fields", "no_ticks"]


def _make_entry(d: Path, kind: str) -> None:
    if kind == "good":
        _copy_run(d)
        return
    d.mkdir(parents=True)
    m = d / "manifest.json"
    if kind == "bad_json":
        m.write_text("{not json")
    elif kind == "list":
        m.write_text("[1, 2]")
    elif kind == "nan":
        m.write_text('{"schema": "drovisio/mission-recording@1", "duration_s": NaN}')
    elif kind == "schema":
        m.write_text('{"schema": "other"}')
    elif kind == "fifo_manifest":
        os.mkfifo(m)
    elif kind == "folder_manifest":
        m.mkdir()
    elif kind == "zero_ticks":
        _copy_run(d, ticks_file="/dev/zero")
    elif kind == "huge_number":
        src = json.loads((_sample_run() / "manifest.json").read_text())
        m.write_text(json.dumps(src)[:-1] + ', "seed2": ' + "9" * 5000 + "}")
    elif kind == "text_fields":
        _copy_run(d)
        src = json.loads(m.read_text())
        src.update(scenario={"a": [1]}, outcome=12, bricks="many")
        m.write_text(json.dumps(src))
    elif kind == "no_ticks":
        _copy_run(d, ticks_text="\n")


@_settings(25)
@given(kinds=st.lists(st.sampled_from(ENTRY_KINDS), min_size=1, max_size=5))
def test_replay_listing_and_loads_survive_any_folder(tmp_path_factory, ledger, kinds):
    from webtool.app import create_app
    from webtool.settings import Settings

    root = tmp_path_factory.mktemp("replays")
    for i, kind in enumerate(kinds):
        _make_entry(root / f"{i:02d}-{kind}", kind)
    with TestClient(create_app(Settings(replay_dir=root)), base_url=LOCAL,
                    raise_server_exceptions=False) as c:
        ledger.tried_one("listings: replay runs")
        r = c.get("/api/replay/runs")
        if r.status_code >= 500:
            ledger.failure("HTTP 500")
        assert r.status_code == 200, r.text
        runs = {x["name"]: x for x in r.json()["runs"]}
        for i, kind in enumerate(kinds):
            name = f"{i:02d}-{kind}"
            if kind in ("good", "text_fields", "zero_ticks", "no_ticks"):
                continue     # the manifest is sound; the ticks are checked on load
            assert name not in runs or runs[name]["ok"] is False, (name, runs.get(name))
            if name in runs:
                assert runs[name]["error"]
        good = [f"{i:02d}-good" for i, k in enumerate(kinds) if k == "good"]
        for name in good:
            assert runs[name]["ok"] is True
        loaded = None
        for i, kind in enumerate(kinds):
            name = f"{i:02d}-{kind}"
            ledger.tried_one("listings: replay loads")
            r = c.post("/api/replay/load", json={"name": name})
            if r.status_code >= 500:
                ledger.failure("HTTP 500")
            assert r.status_code < 500, (kind, r.text)
            if kind in ("good", "text_fields"):
                assert r.status_code == 200, (kind, r.text)
                loaded = name
            else:
                assert r.status_code in (404, 422), (kind, r.status_code, r.text)
            s = c.get("/api/replay/state")
            assert s.status_code == 200, s.text
            st_ = s.json()
            assert st_["loaded"] is (loaded is not None)
            if loaded:
                assert st_["name"] == loaded, "a bad load never replaces the loaded recording"


# ------------------------------------------------------------------ the study listing


SUMMARY_KINDS = {
    "good": '{"protocol": "p", "frames": 3, "seconds": 1.5, "skipped": []}',
    "bad_json": "{", "list": "[]", "string": '"x"',
    "nan": '{"protocol": "p", "frames": 3, "seconds": NaN}',
    "frames_text": '{"frames": "many"}', "skipped_number": '{"skipped": 5}',
    "huge": '{"frames": ' + "9" * 5000 + "}",
    "negative": '{"frames": -1}', "deep": "[" * 100 + "]" * 100,
    "protocol_object": '{"protocol": {"a": 1}, "frames": 2}',
}


@_settings(25)
@given(kinds=st.lists(st.sampled_from([*SUMMARY_KINDS, "fifo", "folder", "no_html"]),
                      min_size=1, max_size=5))
def test_study_listing_names_every_bad_report_and_lists_the_good(tmp_path_factory, ledger,
                                                                 kinds):
    from webtool.app import create_app
    from webtool.settings import Settings

    root = tmp_path_factory.mktemp("study")
    for i, kind in enumerate(kinds):
        d = root / f"r{i:02d}-{kind}"
        d.mkdir()
        if kind != "no_html":
            (d / "report.html").write_text("<html></html>")
        s = d / "summary.json"
        if kind == "fifo":
            os.mkfifo(s)
        elif kind == "folder":
            s.mkdir()
        else:
            s.write_text(SUMMARY_KINDS.get(kind, SUMMARY_KINDS["good"]))
    with TestClient(create_app(Settings(study_dir=root)), base_url=LOCAL,
                    raise_server_exceptions=False) as c:
        ledger.tried_one("listings: study reports")
        r = c.get("/api/study/reports")
        if r.status_code >= 500:
            ledger.failure("HTTP 500")
        assert r.status_code == 200, r.text
        js = r.json()
        listed = {x["name"] for x in js["reports"]}
        skipped = {x["name"] for x in js["skipped"]}
        for i, kind in enumerate(kinds):
            name = f"r{i:02d}-{kind}"
            if kind in ("good", "protocol_object"):
                assert name in listed
            elif kind == "no_html":
                assert name not in listed and name not in skipped  # not a report at all
            else:
                assert name in skipped and name not in listed, (kind, js)
        for x in js["skipped"]:
            assert x["error"] and "\n" not in x["error"]


# ------------------------------------------------------------------ a calibration session folder


@pytest.mark.parametrize("kind", ["fifo", "digits", "sparse"])
def test_a_calibration_session_folder_with_hostile_images_opens(tmp_path, ledger, kind):
    """Images left in a session's folder (recovered after a crash) are read through the
    bounded image reader: a FIFO or a 10 GB file named like an image, a capture number of
    5,000 digits — the session opens, each is named, nothing blocks."""
    from webtool.app import create_app
    from webtool.services import close_services
    from webtool.settings import Settings

    settings = Settings(calibration_dir=tmp_path, source="0")
    app = create_app(settings)
    with TestClient(app, base_url=LOCAL, raise_server_exceptions=False) as c:
        assert c.get("/api/calibration/state").status_code == 200
    close_services(app)
    sid = (tmp_path / "current").read_text().strip()
    images = tmp_path / sid / "images"
    images.mkdir(parents=True, exist_ok=True)
    if kind == "fifo":
        os.mkfifo(images / "capture-0007.jpg")
    elif kind == "digits":
        (images / ("capture-" + "9" * 200 + ".jpg")).write_bytes(b"\xff\xd8 not really")
    else:
        with open(images / "capture-0008.png", "wb") as f:
            f.truncate(10 * 2**30)
    app = create_app(settings)
    ledger.tried_one("files inside files: calibration session folder")
    with TestClient(app, base_url=LOCAL, raise_server_exceptions=False) as c:
        r = c.get("/api/calibration/state")
        if r.status_code >= 500:
            ledger.failure("HTTP 500")
        assert r.status_code == 200, r.text
    close_services(app)


@pytest.mark.parametrize("mesh", ["../../../../../../../../etc/passwd", "meshes/pipe.stl",
                                  "meshes/missing.stl", "meshes/../../outside.stl"])
def test_a_layouts_mesh_is_read_only_inside_the_layouts_folder(tmp_path, ledger, mesh):
    from drovisio.layout import load_layout
    from drovisio.mesh_file import load_layout_mesh
    from drovisio.resources import layouts_dir

    d = tmp_path / "lib" / "layouts"
    (d / "meshes").mkdir(parents=True)
    os.mkfifo(d / "meshes" / "pipe.stl")
    (tmp_path / "lib" / "outside.stl").write_text("solid x\nendsolid x\n")
    data = json.loads((layouts_dir() / "drick-aruco-centre.json").read_text())
    data["mesh"] = mesh
    (d / "x.json").write_text(json.dumps(data))
    ledger.tried_one("files inside files: layout mesh")
    with pytest.raises(InputError) as e:
        load_layout_mesh(load_layout(d / "x.json"))
    assert "mesh" in str(e.value) and "x.json" in str(e.value)


@pytest.mark.parametrize("body", [{"path": "a\x00b"}, {"name": "a\x00b"}, {"path": "p" * 300},
                                  {"name": "\n"}])
def test_replay_load_names_the_field_of_a_path_no_file_system_holds(tmp_path, ledger, body):
    from webtool.app import create_app
    from webtool.settings import Settings

    with TestClient(create_app(Settings(replay_dir=tmp_path)), base_url=LOCAL,
                    raise_server_exceptions=False) as c:
        ledger.tried_one("listings: replay loads")
        r = c.post("/api/replay/load", json=body)
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith(next(iter(body)) + ":"), r.text
