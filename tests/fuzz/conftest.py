"""The hostile-input suite, by class (one file per class of failure): what each class tried
and what went wrong is counted and printed at the end of the session, e.g.::

    hostile inputs tried: cli argv 412, ... | tracebacks 0, internal errors 0, HTTP 500 0,
    hangs 0, data losses 0, cross-origin writes 0

Fixtures:

* ``ledger`` (session): counts inputs tried per class and the failures seen;
* ``cli``: runs ``drovisio ARGV`` in this process with a deadline (a hang fails the test
  instead of stalling CI), returns (exit status, stdout, stderr), counts tracebacks and
  internal errors;
* ``hostile_files``: a folder of things that are not what they claim (a FIFO, a 10 GB sparse
  file, a folder, a file of 5,000-digit numbers) and valid inputs to start from.
"""

from __future__ import annotations

import io
import os
import signal
import socket
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from drovisio.resources import layouts_dir, sample_sessions_dir

SAMPLE = sample_sessions_dir()
FAILURES = ("tracebacks", "internal errors", "HTTP 500", "hangs", "data losses",
            "cross-origin writes")

#: bounded, derandomized and without wall-clock deadlines (CI machines are shared)
HOSTILE = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                   suppress_health_check=[HealthCheck.too_slow,
                                          HealthCheck.function_scoped_fixture,
                                          HealthCheck.data_too_large])


class Ledger:
    """Inputs tried per class, failures per kind."""

    def __init__(self) -> None:
        self.tried: Counter[str] = Counter()
        self.failed: Counter[str] = Counter()

    def tried_one(self, cls: str) -> None:
        self.tried[cls] += 1

    def failure(self, kind: str) -> None:
        assert kind in FAILURES
        self.failed[kind] += 1


_LEDGER = Ledger()
_KEEP: list = []


@pytest.fixture(scope="session")
def ledger() -> Ledger:
    return _LEDGER


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if _LEDGER.tried:
        terminalreporter.write_line(
            "hostile inputs tried: " + ", ".join(f"{k} {v}" for k, v in
                                                 sorted(_LEDGER.tried.items()))
            + " | " + ", ".join(f"{k} {_LEDGER.failed[k]}" for k in FAILURES))


class Hang(BaseException):
    """Raised by the alarm in a command that did not end in time (not an Exception: the
    command line's own handler must not swallow it)."""


@pytest.fixture
def cli(ledger):
    """``cli(*argv, cls="...", seconds=180) -> (status, stdout, stderr)``: ``seconds`` bounds
    a hang only (a loaded machine, or a first run compiling the kernels, is slow, not wrong)."""
    from drovisio.cli import main

    def run(*argv, cls: str = "cli argv", seconds: int = 180) -> tuple[int, str, str]:
        out, err = io.StringIO(), io.StringIO()

        def alarm(signum, frame):
            raise Hang(f"drovisio {' '.join(map(str, argv))[:200]} did not end in {seconds} s")

        old = signal.signal(signal.SIGALRM, alarm)
        signal.alarm(seconds)
        try:
            with redirect_stdout(out), redirect_stderr(err):
                rc = main([str(a) for a in argv])
        except Hang:
            ledger.failure("hangs")
            raise
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, old)
        ledger.tried_one(cls)
        text = err.getvalue()
        if "Traceback" in text or "Traceback" in out.getvalue():
            ledger.failure("tracebacks")
        if "internal error" in text:
            ledger.failure("internal errors")
        return rc, out.getvalue(), text

    return run


@pytest.fixture(scope="session")
def hostile_files(tmp_path_factory) -> dict[str, Path]:
    """Valid inputs and things that only look like them."""
    d = tmp_path_factory.mktemp("hostile")
    fifo = d / "pipe.yaml"
    os.mkfifo(fifo)
    sparse = d / "huge.png"
    with open(sparse, "wb") as f:       # 10 GB that occupy nothing: never read whole
        f.truncate(10 * 2**30)
    digits = d / "digits.yaml"
    digits.write_text("schema: drovisio/mount@1\nseed: " + "9" * 5000 + "\n")
    (d / "folder.json").mkdir()
    images = d / "images"
    images.mkdir()
    taken = socket.socket()            # a port in use: a serve that got past its checks ends
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    _KEEP.append(taken)
    return {
        "busy_port": taken.getsockname()[1],
        "camera": SAMPLE / "camera.yaml",
        "layout": layouts_dir() / "drick-aruco-pyramids.json",
        "pad": layouts_dir() / "landing-pad.json",
        "mount": SAMPLE / "approach" / "mount.json",
        "video": SAMPLE / "approach" / "approach.mp4",
        "protocol": SAMPLE / "study" / "protocol.yaml",
        "images": images,
        "fifo": fifo,
        "sparse": sparse,
        "digits": digits,
        "folder": d / "folder.json",
        "root": d,
    }
