"""Closing the Study page's service (the app's shutdown) cancels the study in progress and
waits for its thread to end: a study renders and detects in native code (numba, OpenCV) for
minutes, and a thread left there while the interpreter exits aborts the process ("terminate
called without an active exception"). A cancelled study writes no report and says so.

Each wait is a bound that turns a hang into a failure, not a timing."""

from __future__ import annotations

import threading

from drovisio.resources import sample_sessions_dir
from drovisio.study import run as study_run
from drovisio.study.protocol import load_protocol
from webtool.settings import Settings
from webtool.study.service import StudyService

HANG = 120.0   # seconds: a bound for failures only


def test_close_cancels_the_study_and_waits_for_its_thread(tmp_path, monkeypatch):
    entered, release = threading.Event(), threading.Event()
    steps: list[str] = []
    workers: list[threading.Thread] = []
    real = study_run.step_frames

    def held_step_frames(step, *args, **kwargs):
        """The first step waits for the test before its frames are read."""
        steps.append(step.label)
        if len(steps) == 1:
            workers.append(threading.current_thread())
            entered.set()
            if not release.wait(HANG):
                raise TimeoutError("the test never released the step")
        return real(step, *args, **kwargs)

    monkeypatch.setattr(study_run, "step_frames", held_step_frames)
    svc = StudyService(Settings(study_dir=tmp_path / "study",
                                calibration_dir=tmp_path / "cal"))
    worker_alive_after_close: list[bool] = []

    def close() -> None:
        svc.close()
        worker_alive_after_close.append(workers[0].is_alive())

    closer = threading.Thread(target=close, daemon=True, name="closer")
    try:
        svc.start()
        assert entered.wait(HANG), "the study never reached its first step"
        closer.start()
        # released once close runs: it asked the study to stop, which it does at its next
        # frame (or, were this release first, a frame or so later: still long before its end)
        release.set()
        closer.join(HANG)
        assert not closer.is_alive(), "close never returned"
        assert worker_alive_after_close == [False], "close returned before the study ended"
        asked = len(load_protocol(sample_sessions_dir() / "study" / "protocol.yaml").steps)
        assert len(steps) < asked, (steps, asked)
        p = svc.progress
        assert (p["running"], p["cancelled"], p["error"], p["report"]) == (
            False, True, None, None), p
        assert not (tmp_path / "study").exists() or not any((tmp_path / "study").iterdir())
    finally:
        release.set()
        if not closer.is_alive():
            svc.close()
