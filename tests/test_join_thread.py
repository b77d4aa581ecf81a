"""The one way a stop waits for a thread it asked to end (``drovisio._threads.join_thread``):
it waits for the thread however long its last piece of work takes, and says in one warning,
naming the thread, when the limit passed with the thread still alive.

The threads here wait on Events the test sets; each wait is a bound that turns a hang into a
failure, not a timing."""

from __future__ import annotations

import logging
import threading

from drovisio._threads import join_thread

HANG = 60.0   # seconds: a bound for failures only


def test_a_thread_that_ends_is_waited_for(caplog):
    release = threading.Event()
    worker = threading.Thread(target=release.wait, args=(HANG,), name="held-worker",
                              daemon=True)
    ended: list[bool] = []
    joiner = threading.Thread(target=lambda: ended.append(join_thread(worker, "holding")),
                              name="joiner", daemon=True)
    caplog.set_level(logging.WARNING, logger="drovisio.threads")
    try:
        worker.start()
        joiner.start()
        joiner.join(0.5)
        assert joiner.is_alive() and ended == [], "join_thread returned with the thread alive"
        release.set()
        joiner.join(HANG)
        assert ended == [True]
        assert not worker.is_alive()
        assert caplog.records == []
    finally:
        release.set()


def test_a_thread_that_does_not_end_is_named_in_one_warning(caplog):
    release = threading.Event()
    worker = threading.Thread(target=release.wait, args=(HANG,), name="stuck-worker",
                              daemon=True)
    caplog.set_level(logging.WARNING, logger="drovisio.threads")
    try:
        worker.start()
        assert join_thread(worker, "waiting for the test", limit=0.05) is False
        assert worker.is_alive()
        [record] = caplog.records
        assert record.levelno == logging.WARNING
        assert "stuck-worker" in record.getMessage()
        assert "waiting for the test" in record.getMessage()
    finally:
        release.set()
        worker.join(HANG)


def test_no_thread_and_the_calling_thread():
    assert join_thread(None, "nothing") is True
    assert join_thread(threading.current_thread(), "itself", limit=HANG) is False
