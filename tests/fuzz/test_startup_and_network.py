"""Class: start-up checks and network connects.

* ``run`` and ``serve`` share one start-up check (:mod:`drovisio.startup`): a sink that
  cannot open, a bad target, a recording folder that is a file, a FIFO sink nobody reads —
  one line, exit 2, before the server starts (a port in use stands by: a serve that got past
  its checks ends there instead of serving).
* Every connect has a deadline: a ``mavlink:tcp:`` peer that never answers (a listening
  socket whose backlog is full: SYNs are dropped, as by a firewall) is reported in one line
  after :attr:`~drovisio.errors.Limits.connect_timeout_s`, a refused one at once.
* The lifespan never raises to uvicorn: a pipeline that cannot start there is recorded as the
  app's start-up error (one line) and ends the server.
"""

from __future__ import annotations

import os
import socket
import threading

import pytest
from fastapi.testclient import TestClient

from drovisio.errors import LIMITS


@pytest.fixture
def silent_peer():
    """A loopback TCP port that accepts nothing: its backlog is filled, later SYNs dropped."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(0)
    port = server.getsockname()[1]
    fillers = []
    for _ in range(4):
        c = socket.socket()
        c.setblocking(False)
        try:
            c.connect(("127.0.0.1", port))
        except BlockingIOError:
            pass
        fillers.append(c)
    probe = socket.socket()
    probe.settimeout(0.3)
    try:
        probe.connect(("127.0.0.1", port))
        pytest.skip("this kernel accepts past a full backlog: no silent peer")
    except TimeoutError:
        pass
    finally:
        probe.close()
    yield port
    for c in fillers:
        c.close()
    server.close()


@pytest.fixture
def short_deadline(monkeypatch):
    monkeypatch.setattr(LIMITS, "connect_timeout_s", 0.5)


def _serve(f, *opts):
    return ("serve", "--port", f["busy_port"], *opts)


def _run(f, *opts):
    return ("run", "--source", f["video"], "--camera", f["camera"], "--layout", f["layout"],
            "--frames", "1", "--quiet", *opts)


@pytest.mark.parametrize("command", ["run", "serve"])
@pytest.mark.parametrize("opts,needle", [
    (("--sink", "bogus"), "unknown sink"),
    (("--sink", "udp://"), "--sink"),
    (("--sink", "udp://[::1]:99999"), "--sink"),
    (("--sink", "ws://127.0.0.1:99999"), "--sink"),
    (("--sink", "ws://nohost"), "--sink"),
    (("--sink", "mavlink:tcp:127.0.0.1:notaport"), "HOST:PORT"),
    (("--sink", "mavlink:udpout:no.such.host.invalid:14550"), "unknown host"),
    (("--sink", "jsonl:-", "--target", "a:b:c"), "--target"),
    (("--sink", "jsonl:-", "--target", "track:" + "9" * 5000), "--target"),
    (("--sink", "jsonl:-", "--record", "/dev/null"), "--record"),
    (("--sink", "jsonl:/proc/no/such/dir/x.jsonl"), "--sink"),
])
def test_run_and_serve_refuse_the_same_set_up_in_one_line(cli, hostile_files, command, opts,
                                                          needle):
    argv = (_run if command == "run" else _serve)(hostile_files, *opts)
    rc, _, err = cli(*argv, cls="start-up: run and serve")
    assert rc == 2, err[-300:]
    assert needle in err, err[-300:]
    assert "cannot listen" not in err, "refused for its options, before the port"
    assert len(err.strip().splitlines()) <= 2 and "Traceback" not in err


@pytest.mark.parametrize("command", ["run", "serve"])
def test_a_fifo_sink_nobody_reads_is_refused_not_waited_for(cli, hostile_files, tmp_path,
                                                            command):
    fifo = tmp_path / "out.jsonl"
    os.mkfifo(fifo)
    argv = (_run if command == "run" else _serve)(hostile_files, "--sink", f"jsonl:{fifo}")
    rc, _, err = cli(*argv, cls="start-up: run and serve", seconds=180)
    assert rc == 2 and "--sink" in err, err[-300:]


@pytest.mark.parametrize("command", ["run", "serve"])
def test_a_silent_mavlink_peer_is_reported_after_the_deadline(cli, hostile_files, silent_peer,
                                                              short_deadline, ledger, command):
    argv = (_run if command == "run" else _serve)(
        hostile_files, "--sink", f"mavlink:tcp:127.0.0.1:{silent_peer}")
    ledger.tried_one("network: connect deadline")
    rc, _, err = cli(*argv, cls="start-up: run and serve", seconds=180)
    assert rc == 2 and "no answer" in err and "0.5 s" in err, err[-300:]


def test_a_refused_mavlink_peer_is_reported_at_once(cli, hostile_files, ledger):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                                   # nothing listens there now
    ledger.tried_one("network: connect deadline")
    rc, _, err = cli(*_run(hostile_files, "--sink", f"mavlink:tcp:127.0.0.1:{port}"),
                     cls="start-up: run and serve", seconds=180)
    assert rc == 2 and "cannot connect" in err, err[-300:]


def test_the_lifespan_never_raises_to_uvicorn(hostile_files, silent_peer, short_deadline,
                                              ledger):
    """A pipeline that cannot start in the lifespan (the link went silent after the check)
    becomes the app's start-up error, in one line; the app itself still starts and stops."""
    from webtool.app import create_app
    from webtool.settings import Settings

    app = create_app(Settings(source=str(hostile_files["video"]),
                              camera=hostile_files["camera"],
                              layouts=[hostile_files["layout"]],
                              sinks=[f"mavlink:tcp:127.0.0.1:{silent_peer}"]))

    class Server:
        should_exit = False

    app.state.uvicorn_server = Server()
    ledger.tried_one("start-up: lifespan")
    with TestClient(app, base_url="http://127.0.0.1:8080") as c:
        assert c.get("/api/health").status_code < 500
    err = app.state.startup_error
    assert err and "no answer" in err and "\n" not in err
    assert app.state.uvicorn_server.should_exit is True


def test_serve_ends_with_one_line_when_its_lifespan_fails(monkeypatch, cli, hostile_files):
    """`drovisio serve` through uvicorn: the lifespan's failure is exit 2, one line."""
    import webtool.serve as serve

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    monkeypatch.setattr(serve, "_check_inputs", lambda args: None)  # as if the link died since
    monkeypatch.setattr(serve, "_warm_up_in_background",        # a warm-up already done
                        lambda: threading.Thread(target=lambda: None))
    rc, out, err = cli("serve", "--port", port, "--source", hostile_files["video"],
                       "--camera", hostile_files["camera"], "--layout",
                       hostile_files["layout"], "--sink", "bogus",
                       cls="start-up: run and serve", seconds=180)
    assert rc == 2 and "the pipeline could not start" in err and "unknown sink" in err, err
    assert "Traceback" not in err
