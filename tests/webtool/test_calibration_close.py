"""Closing the calibration page's service (the app's shutdown) waits for the previous session a
"New session" set aside: that session closes in its own thread, waiting for its solve in
progress (OpenCV), and a solve left running while the interpreter exits can abort the process
("terminate called without an active exception").

The previous session's solve is held on an Event while another thread closes the service.
Each wait is a bound that turns a hang into a failure, not a timing."""

from __future__ import annotations

import threading

from webtool.calibration.service import CalibrationService
from webtool.settings import Settings

HANG = 60.0   # seconds: a bound for failures only
HOLD = 5.0    # seconds the solve stays blocked under close (a close that waits passes with any)


class NoCamera:
    """A camera that never gives a frame (the test needs none)."""

    label = "no camera"
    finite = False

    def open(self) -> None:
        pass

    def read(self) -> None:
        return None

    def close(self) -> None:
        pass


def test_close_waits_for_the_previous_session_and_its_solve(tmp_path,
                                                            stop_waits_for_held_work):
    svc = CalibrationService(Settings(calibration_dir=tmp_path / "cal"),
                             source_factory=NoCamera)
    solving, release = threading.Event(), threading.Event()
    solvers: list[threading.Thread] = []

    def held_solve() -> None:
        solvers.append(threading.current_thread())
        solving.set()
        if not release.wait(HANG):
            raise TimeoutError("the test never released the solve")

    try:
        old = svc.session
        old.solve = held_solve  # type: ignore[method-assign]
        old.solve_async()
        assert solving.wait(HANG), "the solve never began"
        svc.new_session()
        assert svc.session is not old
        # the previous session's solve stays blocked a while after close began, then returns
        stop_waits_for_held_work(svc.close, lambda: solvers[0], release, "close", hold=HOLD,
                                 hang=HANG)
        assert not any(t.name == "calibration-session-close" for t in threading.enumerate())
    finally:
        release.set()
        svc.close()
