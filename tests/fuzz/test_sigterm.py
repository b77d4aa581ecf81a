"""Class: processes that must end on SIGTERM, whatever they are waiting for.

``drovisio run`` on an endless source (a stream whose loopback peer stalls after a few
frames) and ``drovisio serve`` (loopback, a free port) while a live viewer watches that
stalled stream, an HTTP client stalls in the middle of its request headers and another waits
on a route: each ends on SIGTERM, without a traceback. The bound (30 s) is generous: it
catches a hang, not a slow machine.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
CAMERA = REPO / "sample_sessions" / "camera.yaml"
LAYOUT = REPO / "marker_layouts" / "drick-aruco-centre.json"
#: bounds for failures (a hang) only: a loaded machine is slow, not wrong
BOUND_S = 60
START_S = 300


class _StallingStream:
    """A loopback MJPEG server: each connection gets the HTTP header and two frames, then
    nothing (held open) until :meth:`close`."""

    def __init__(self):
        ok, jpg = cv2.imencode(".jpg", np.full((480, 640, 3), 90, np.uint8))
        assert ok
        part = (b"--f\r\nContent-Type: image/jpeg\r\nContent-Length: "
                + str(len(jpg)).encode() + b"\r\n\r\n" + jpg.tobytes() + b"\r\n")
        self.reply = (b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; "
                      b"boundary=f\r\n\r\n" + part * 2)
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}/cam.mjpg"
        self.conns: list[socket.socket] = []
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while not self.stop.is_set():
            try:
                c, _ = self.sock.accept()
                self.conns.append(c)
                c.settimeout(2)
                c.recv(4096)
                c.sendall(self.reply)
            except OSError:
                continue

    def close(self):
        self.stop.set()
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.fixture
def stalling_stream():
    s = _StallingStream()
    yield s
    s.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _terminate(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=BOUND_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f"did not end within {BOUND_S} s of SIGTERM:\n{out[-2000:]}")
    return proc.returncode, out


def _start(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "drovisio", *argv], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def test_run_on_a_stalled_endless_stream_ends_on_sigterm(stalling_stream, ledger, tmp_path):
    ledger.tried_one("signals: SIGTERM")
    outputs = tmp_path / "out.jsonl"
    proc = _start(["run", "--source", stalling_stream.url, "--camera", str(CAMERA),
                   "--layout", str(LAYOUT), "--sink", f"jsonl:{outputs}"])
    try:
        # the frames it was sent come through (waited for: a first run compiles the
        # detectors' kernels first); then the stream stalls
        deadline = time.monotonic() + START_S
        while not (outputs.is_file() and outputs.read_text().count("\n") >= 2):
            assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
            assert time.monotonic() < deadline, "run never processed the stream's frames"
            time.sleep(0.2)
        time.sleep(3)  # past the read deadline: the reader is reconnecting or waiting
        assert proc.poll() is None, "run ended on its own on an endless source"
    except BaseException:
        proc.kill()
        raise
    rc, out = _terminate(proc)
    assert "Traceback" not in out and "internal error" not in out, out[-2000:]
    assert rc in (0, 1), out[-2000:]
    lines = outputs.read_text().splitlines()
    assert len(lines) >= 2 and all('"bricks"' in x for x in lines)  # the frames sent


def test_serve_ends_on_sigterm_with_a_viewer_on_a_stalled_stream(stalling_stream, ledger):
    ledger.tried_one("signals: SIGTERM")
    from websockets.sync.client import connect

    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    proc = _start(["serve", "--port", str(port), "--source", stalling_stream.url,
                   "--camera", str(CAMERA), "--layout", str(LAYOUT)])
    held: list = []
    try:
        deadline = time.monotonic() + START_S
        while True:
            try:
                urllib.request.urlopen(base + "/api/health", timeout=2).read()
                break
            except OSError:
                assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
                assert time.monotonic() < deadline, "serve did not start"
                time.sleep(0.5)
        # a live viewer: starts the pipeline on the stalling stream
        ws = connect(f"ws://127.0.0.1:{port}/api/live/ws", origin=base, open_timeout=BOUND_S)
        held.append(ws)
        # a client that stalls in the middle of its request headers (slow loris)
        s = socket.create_connection(("127.0.0.1", port))
        s.sendall(b"GET /api/live/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        held.append(s)
        deadline = time.monotonic() + START_S
        while not stalling_stream.conns and time.monotonic() < deadline:
            time.sleep(0.2)
        assert stalling_stream.conns, "the live pipeline never connected to the stream"
        time.sleep(3)  # the stream has stalled
        assert proc.poll() is None
    except BaseException:
        proc.kill()
        raise
    try:
        rc, out = _terminate(proc)
    finally:
        for h in held:
            try:
                h.close()
            except Exception:  # noqa: BLE001,S110 - the server may have closed it first
                pass
    assert "Traceback" not in out, out[-3000:]
    assert rc in (0, -signal.SIGTERM), out[-2000:]


def test_serve_ends_on_sigterm_after_requests_on_fifos(tmp_path, ledger):
    """A replay folder whose recordings name a FIFO (as their manifest, or as the ticks file
    their manifest names): the listing and the loads answer at once (a FIFO is never
    opened), and the server still ends on SIGTERM."""
    import json
    import shutil

    from drovisio.resources import sample_sessions_dir

    ledger.tried_one("signals: SIGTERM")
    src = next(p.parent for p in (sample_sessions_dir() / "missions").rglob("manifest.json"))
    root = tmp_path / "runs"
    ticks = root / "ticks-fifo"
    ticks.mkdir(parents=True)
    manifest = json.loads((src / "manifest.json").read_text())
    manifest["ticks_file"] = "ticks.fifo"
    (ticks / "manifest.json").write_text(json.dumps(manifest))
    os.mkfifo(ticks / "ticks.fifo")
    (root / "manifest-fifo").mkdir()
    os.mkfifo(root / "manifest-fifo" / "manifest.json")
    shutil.copytree(src, root / "good")
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    proc = _start(["serve", "--port", str(port), "--replay-dir", str(root)])
    try:
        deadline = time.monotonic() + START_S
        while True:
            try:
                urllib.request.urlopen(base + "/api/health", timeout=2).read()
                break
            except OSError:
                assert proc.poll() is None
                assert time.monotonic() < deadline, "serve did not start"
                time.sleep(0.5)
        with urllib.request.urlopen(base + "/api/replay/runs", timeout=BOUND_S) as r:
            listing = json.loads(r.read())
        assert r.status == 200 and "good" in json.dumps(listing)
        for name in ("ticks-fifo", "manifest-fifo"):
            req = urllib.request.Request(base + "/api/replay/load", method="POST",
                                         data=json.dumps({"name": name}).encode(),
                                         headers={"Content-Type": "application/json",
                                                  "Origin": base})
            try:
                urllib.request.urlopen(req, timeout=BOUND_S)
                pytest.fail(f"{name}: loaded")
            except urllib.error.HTTPError as e:
                assert 400 <= e.code < 500, (name, e.code)
                body = e.read().decode()
                # the field and the reason, never the FIFO's (absent) content
                assert ("ticks_file" in body and "not a regular file" in body
                        if name == "ticks-fifo" else "manifest.json" in body), body
        assert proc.poll() is None
    except BaseException:
        proc.kill()
        raise
    rc, out = _terminate(proc)
    assert "Traceback" not in out, out[-3000:]
    assert rc in (0, -signal.SIGTERM), out[-2000:]
