"""Shared fixtures.

* ``chromium_path``: path of Debian's Chromium (or $DROVISIO_CHROMIUM); skips the test if it is missing, or fails it when
  DROVISIO_REQUIRE_BROWSER=1 (CI), so that browser tests can't silently vanish.
* ``browser`` (session): a headless Playwright Chromium browser.
* ``page``: a fresh browser page (own context) per test.
* ``live_server`` (session): base URL (no trailing slash) of the web tool with default settings,
  served by uvicorn in a background thread on a free port.
* ``live_server_factory``: ``start(settings_or_app) -> base URL`` for tests needing other settings;
  each server is stopped at the end of the test.
* ``until`` (session): ``until(ask, bound=60, *, done=bool, step=None, pause=0.02, say=None)``,
  the one wait for a condition: ``ask()`` again until its answer is done, that answer; a bound
  for failures only (:func:`_until`).
"""

from __future__ import annotations

import atexit
import os
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings as _hypothesis_settings

# No property test has a wall-clock deadline: a busy machine is not a failure; each test
# bounds its work (example counts, input sizes) instead.
_hypothesis_settings.register_profile("drovisio", deadline=None)
_hypothesis_settings.load_profile("drovisio")

# The web tool keeps what the user makes (calibration, mount, layouts, study reports) in the
# user's data folder: the test session gets a folder of its own, and each test a fresh one
# inside it (`_own_data_folder`), so that neither the user's data nor another test's changes
# what a test sees.
os.environ["XDG_DATA_HOME"] = _DATA_HOME = tempfile.mkdtemp(prefix="drovisio-test-data-")
atexit.register(shutil.rmtree, _DATA_HOME, ignore_errors=True)


@pytest.fixture(autouse=True)
def _own_data_folder(tmp_path_factory, monkeypatch):
    """Each test its own user data folder (drovisio.resources.user_data_dir)."""
    from drovisio.resources import DATA_ENV

    monkeypatch.setenv(DATA_ENV, str(tmp_path_factory.mktemp("data")))


def _until(ask: Callable[[], Any], bound: float = 60.0, *,
           done: Callable[[Any], object] = bool, step: Callable[[], object] | None = None,
           pause: float = 0.02, say: Callable[[Any], object] | None = None) -> Any:
    """Ask ``ask()`` again until ``done(answer)`` holds (by default: until the answer is
    true), and return that answer. Between two asks ``step()`` runs (a message sent again, a
    peer polled), then a pause of ``pause`` seconds.

    The bound only turns a hang into a failure, and is generous: a loaded machine is slow,
    not wrong; nothing is measured by it.

    Raises:
        AssertionError: not done within ``bound`` seconds; says the last answer, or
            ``say(last answer)``.
    """
    end = time.monotonic() + bound
    while True:
        got = ask()
        if done(got):
            return got
        if time.monotonic() > end:
            said = say(got) if say is not None else repr(got)
            raise AssertionError(f"not done within {bound:g} s; last: {str(said)[:2000]}")
        if step is not None:
            step()
        time.sleep(pause)


def _free_port() -> int:
    """A loopback TCP port nothing listens on (bound once and let go)."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="session")
def free_port() -> Callable[[], int]:
    """The one way a test picks an unused loopback port (:func:`_free_port`)."""
    return _free_port


@pytest.fixture(scope="session")
def until() -> Callable[..., Any]:
    """The one wait for a condition (:func:`_until`), for every test and fixture."""
    return _until


def _stop_waits_for_held_work(stop: Callable[[], None],
                              held: Callable[[], threading.Thread],
                              release: threading.Event, what: str, *, hold: float = 5.0,
                              hang: float = 60.0) -> None:
    """Run ``stop`` from another thread while some work is held on ``release`` (the caller
    got it there): ``stop`` must not return while it is held (``hold`` seconds: longer than a
    stop that gives up after a few seconds waits; one that waits passes with any), must
    return once it is released, and the held work's thread (``held()``) must have ended by
    then. ``release`` is set whatever happens."""
    alive_after: list[bool] = []

    def run() -> None:
        stop()
        alive_after.append(held().is_alive())

    stopper = threading.Thread(target=run, daemon=True, name="stopper")
    try:
        stopper.start()
        stopper.join(hold)
        assert stopper.is_alive(), f"{what} returned while the work was still held"
        release.set()
        stopper.join(hang)
        assert not stopper.is_alive(), f"{what} never returned"
        assert alive_after == [False], f"{what} returned before the held work ended"
    finally:
        release.set()


@pytest.fixture(scope="session")
def stop_waits_for_held_work() -> Callable[..., None]:
    """The one check that a stop waits for work in progress (:func:`_stop_waits_for_held_work`)."""
    return _stop_waits_for_held_work


# DROVISIO_CHROMIUM overrides the path (other distributions); the default is Debian's.
CHROMIUM = Path(os.environ.get("DROVISIO_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def _browser_required() -> bool:
    return os.environ.get("DROVISIO_REQUIRE_BROWSER", "") == "1"


@pytest.fixture(scope="session")
def chromium_path() -> Path:
    if not CHROMIUM.exists():
        msg = (
            f"{CHROMIUM} is missing: browser tests need Debian's chromium "
            "(apt-get install -y chromium)"
        )
        if _browser_required():
            pytest.fail(msg + " and DROVISIO_REQUIRE_BROWSER=1 forbids skipping them.",
                        pytrace=False)
        pytest.skip(msg)
    return CHROMIUM


@pytest.fixture(scope="module")
def browser(chromium_path: Path):
    # Module scope, not session: Playwright's sync API runs an asyncio loop in the main thread
    # for as long as it lives, and tests after the browser tests call asyncio.run().
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(chromium_path), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser):
    context = browser.new_context()
    pg = context.new_page()
    pg.set_default_timeout(60_000)   # waits on state: a bound for failures only
    try:
        yield pg
    finally:
        context.close()


class _ServerThread:
    """A uvicorn server on an already-bound socket (no port race), in a daemon thread."""

    def __init__(self, app) -> None:
        import uvicorn

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        # connections kept open as long as a test may take between two requests: a loaded
        # machine's test client idle past uvicorn's 5 s met a server closing the connection
        # as it sent on it (ECONNRESET; a browser retries, a test's request client does not)
        config = uvicorn.Config(app, log_level="warning", lifespan="on",
                                timeout_keep_alive=600)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True,
            name=f"live-server-{self.port}",
        )

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 120.0) -> str:   # a bound for failures only
        self.thread.start()
        deadline = time.monotonic() + timeout
        while not self.server.started:
            if not self.thread.is_alive():
                raise RuntimeError("the live server thread died during start-up")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the live server did not start within {timeout} s")
            time.sleep(0.02)
        return self.url

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=60)
        self.sock.close()


def _as_app(settings_or_app):
    from fastapi import FastAPI

    from webtool.app import create_app
    from webtool.settings import Settings

    if isinstance(settings_or_app, FastAPI):
        return settings_or_app
    return create_app(settings_or_app if settings_or_app is not None else Settings())


@pytest.fixture
def live_server_factory() -> Iterator:
    servers: list[_ServerThread] = []

    def start(settings_or_app=None) -> str:
        srv = _ServerThread(_as_app(settings_or_app))
        servers.append(srv)
        return srv.start()

    yield start
    for srv in servers:
        srv.stop()


@pytest.fixture(scope="session")
def live_server() -> Iterator[str]:
    srv = _ServerThread(_as_app(None))
    try:
        yield srv.start()
    finally:
        srv.stop()


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """How many inputs the fuzz suite (tests/test_fuzz.py) tried, per reader and route."""
    tried = getattr(config, "fuzz_tried", None)
    if tried:
        terminalreporter.write_line("fuzz inputs tried: " + ", ".join(
            f"{k} {v}" for k, v in sorted(tried.items())))


@pytest.fixture
def no_apriltag(monkeypatch):
    """As if pupil-apriltags (the peers extra) were not installed."""
    import builtins

    real = builtins.__import__

    def without(name, *a, **kw):
        if name == "pupil_apriltags":
            raise ImportError(name)
        return real(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", without)
