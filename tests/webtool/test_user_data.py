"""What the user makes lives in the user's data folder (per server with `--data`), never in
the checkout or the installed package; the designer never answers 500."""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.resources import DATA_ENV, user_data_dir
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"
API = "/api/designer"
CODE_RAYS = [([-0.076, 0.003, 1.0], [0.0, 0.0, -1.0]), ([0.074, -0.002, 1.0], [0.0, 0.0, -1.0])]
DOT_RAYS = [([x + 0.0012, y - 0.0014, 1.0], [0.0, 0.0, -1.0])
            for x in (-0.1, 0.0, 0.1) for y in (0.05, -0.05)]


def _shipped_digest() -> str:
    h = hashlib.sha256()
    for p in sorted(shipped_layouts_dir().rglob("*")):
        if p.is_file() and "__pycache__" not in p.parts:
            h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


@pytest.fixture
def client(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data"))
    yield TestClient(app, base_url=LOCAL)
    from webtool.services import close_services

    close_services(app)


def _design(client, dots=DOT_RAYS):
    drick = (shipped_layouts_dir() / "meshes" / "drick.stl").read_bytes()
    assert client.post(f"{API}/mesh?filename=drick.stl&units=auto", content=drick).status_code \
        == 200
    client.post(f"{API}/mode", json={"mode": "code"})
    for o, d in CODE_RAYS:
        client.post(f"{API}/click", json={"origin": o, "direction": d})
    client.post(f"{API}/mode", json={"mode": "dot"})
    s = None
    for o, d in dots:
        s = client.post(f"{API}/click", json={"origin": o, "direction": d}).json()
    return s


def test_each_test_has_its_own_data_folder(tmp_path_factory):
    import os

    here = Path(os.environ[DATA_ENV])
    assert user_data_dir("mount") == here / "mount"
    assert not here.is_relative_to(Path(__file__).resolve().parents[2])


def test_settings_put_every_area_in_the_data_folder(tmp_path):
    s = Settings(data_dir=tmp_path)
    assert {a: s.user_folder(a) for a in ("calibration", "mount", "layouts", "study")} == \
        {a: tmp_path / a for a in ("calibration", "mount", "layouts", "study")}
    assert Settings(data_dir=tmp_path, mount_dir=tmp_path / "x").user_folder("mount") == \
        tmp_path / "x"
    assert Settings().user_folder("layouts") == user_data_dir("layouts")


def test_saving_a_design_writes_into_the_data_folder_not_the_shipped_layouts(client, tmp_path):
    before = _shipped_digest()
    s = _design(client)
    sym = next(c for c in s["checks"] if c["key"] == "symmetric-dots")
    client.post(f"{API}/fix", json={"action": sym["fixes"][0]["action"]})
    assert client.post(f"{API}/layout", json={"name": "my-brick"}).status_code == 200
    r = client.post(f"{API}/save", json={})
    assert r.status_code == 200, r.text
    saved = tmp_path / "data" / "layouts"
    assert load_layout(saved / "my-brick.json").name == "my-brick"
    assert (saved / "meshes" / "my-brick.stl").is_file()
    assert _shipped_digest() == before
    # a shipped layout's name is refused by name, even with "replace"
    client.post(f"{API}/layout", json={"name": "drick-aruco-pyramids"})
    r = client.post(f"{API}/save", json={"overwrite": True})
    assert r.status_code == 422 and "shipped layout" in r.json()["detail"]
    assert _shipped_digest() == before
    # the saved layout is offered beside the shipped ones
    labels = {e["id"]: e["label"] for e in client.get(f"{API}/state").json()["examples"]}
    assert labels["layout:my-brick.json"] == "Edit your layout 'my-brick'"
    assert labels["layout:drick-aruco-pyramids.json"].startswith("Start from the shipped")


def test_verify_with_codes_and_one_dot_is_explained_not_500(client):
    s = _design(client, dots=DOT_RAYS[:1])
    few = next(c for c in s["checks"] if c["key"] == "dots-few")
    assert few["severity"] == "error" and "at least 4 dots" in few["message"]
    assert not s["can_export"]
    r = client.post(f"{API}/verify")
    assert r.status_code == 422 and "at least 4 dots" in r.json()["detail"]
    assert client.post(f"{API}/save", json={}).status_code == 422
    s = client.post(f"{API}/fix", json={"action": few["fixes"][0]["action"]}).json()
    assert "dots-few" not in [c["key"] for c in s["checks"]]
    r = client.post(f"{API}/verify")
    assert r.status_code == 200, r.text
    assert [x["method"] for x in r.json()["results"]] == ["aruco"]
    assert r.json()["results"][0]["found"]


def test_no_property_test_has_a_wall_clock_deadline():
    tests = Path(__file__).resolve().parents[1]
    seen = 0
    for p in tests.rglob("*.py"):
        text = p.read_text()
        # hypothesis' settings(...) calls, and the deadline each gives
        for call in re.finditer(r"settings\((?:[^()]|\([^()]*\))*\)", text):
            m = re.search(r"\bdeadline\s*=\s*(\w+)", call.group(0))
            if m:
                seen += 1
                assert m.group(1) == "None", f"{p}: {call.group(0)[:80]}"
    assert seen >= 3


def test_serve_on_a_busy_port_says_so_before_any_address(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "drovisio", "serve", "--port", str(port),
                            "--data", str(tmp_path)], capture_output=True, text=True,
                           timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "cannot listen" in r.stderr and "http://" not in r.stdout, r.stdout
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
