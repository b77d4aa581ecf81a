"""The wheel works like the checkout: built, installed in a new virtual environment outside the
checkout, it serves every page on the sample session, detects on the shipped sample and checks
the shipped mission. (About a minute and a half: pip takes the dependencies from its cache.)"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900, **kw)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict]:
    d = tmp_path_factory.mktemp("wheel")
    # from a copy without build leftovers (setuptools packs a stale build/lib as well)
    src = d / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache"))
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(d / "dist"),
          str(src)])
    wheels = list((d / "dist").glob("drovisio-*.whl"))
    assert len(wheels) == 1
    _run([sys.executable, "-m", "venv", str(d / "venv")])
    py = d / "venv" / "bin" / "python"
    _run([str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check",
          str(wheels[0])])
    env = {**os.environ, "DROVISIO_NUMBA": "0", "XDG_DATA_HOME": str(d / "data"),
           "PYTHONPATH": ""}
    return d, {"py": py, "bin": d / "venv" / "bin", "env": env, "cwd": d}


def _where(ctx, expr: str) -> str:
    r = _run([str(ctx["py"]), "-c", f"from drovisio import resources as r; print({expr})"],
             cwd=ctx["cwd"], env=ctx["env"])
    return r.stdout.strip()


def test_the_wheel_holds_every_module_and_no_other(installed):
    d, _ = installed
    wheel = next((d / "dist").glob("drovisio-*.whl"))
    with zipfile.ZipFile(wheel) as z:
        packed = {n for n in z.namelist() if n.endswith(".py")}
    here = {str(p.relative_to(REPO)) for top in ("drovisio", "webtool")
            for p in (REPO / top).rglob("*.py") if "__pycache__" not in p.parts}
    assert {n for n in packed if n.startswith(("drovisio/", "webtool/"))
            and not n.startswith(("drovisio/marker_layouts/", "drovisio/sample_sessions/",
                                  "drovisio/docs/", "webtool/templates/"))} == here


def test_the_wheel_holds_the_data_and_not_the_checkout(installed):
    d, ctx = installed
    for expr in ("r.layouts_dir()", "r.sample_sessions_dir()", "r.templates_dir()",
                 "r.static_dir()", "r.scenarios_dir()", "r.docs_dir()"):
        where = Path(_where(ctx, expr))
        assert "site-packages" in str(where) and REPO not in where.parents, (expr, where)
        assert any(where.iterdir())


def test_detect_and_mission_check_from_the_wheel(installed):
    d, ctx = installed
    sample = Path(_where(ctx, "r.sample_sessions_dir()"))
    layouts = Path(_where(ctx, "r.layouts_dir()"))
    r = _run([str(ctx["bin"] / "drovisio"), "detect", "--camera", str(sample / "camera.yaml"),
              "--layout", str(layouts / "drick-aruco-centre.json"), "--layout",
              str(layouts / "drick-aruco-pyramids.json"), "--out", str(d / "poses.jsonl"),
              str(sample / "approach" / "approach.mp4")], cwd=ctx["cwd"], env=ctx["env"])
    lines = (d / "poses.jsonl").read_text().splitlines()
    assert len(lines) == 150 and '"bricks": [{' in lines[99], r.stderr
    _run([str(ctx["bin"] / "drovisio"), "mission", "check", "wall-2-courses", "--fault",
          "missed grab"], cwd=ctx["cwd"], env=ctx["env"])


def test_serve_from_the_wheel_serves_every_page(installed):
    d, ctx = installed
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([str(ctx["bin"] / "drovisio"), "serve", "--port", str(port)],
                            cwd=ctx["cwd"], env=ctx["env"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 300     # bounds for failures only (a loaded machine)
        while True:
            try:
                urllib.request.urlopen(base + "/api/health", timeout=2).read()
                break
            except OSError:
                assert proc.poll() is None, proc.stdout.read()
                assert time.monotonic() < deadline, "the wheel's server did not start"
                time.sleep(0.5)
        for path in ("/", "/calibration", "/designer", "/live", "/static/live.js",
                     "/static/calibration.css", "/api/calibration/state", "/live/3d/"):
            with urllib.request.urlopen(base + path, timeout=120) as r:
                assert r.status == 200, path
                assert len(r.read()) > 100, path
    finally:
        proc.terminate()
        proc.wait(60)
