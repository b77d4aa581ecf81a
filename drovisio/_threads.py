"""The project's threads: one BLAS thread for a frame's small dense products, and the one
way a stop waits for a thread it asked to end.

numpy's matrix products go to OpenBLAS, which splits a product over its own threads once it
is a few hundred thousand multiply-adds (a code reader's batch, the corner fit's normal
equations). On a drone's two cores shared with OpenCV and the camera, those threads wait
for a core by spinning: a 0.3-ms product measured 2–35 ms of the calling thread's time on a
loaded machine, and the frame's time then followed the load. Detection therefore runs its
products on the calling thread (:func:`one_blas_thread`), the way OpenCV runs with
``cv2.setNumThreads(1)``; the results are the same bits whatever the thread count.

``threadpoolctl`` (a dependency) switches the BLAS library found in the process; without it,
or with no BLAS it knows, this does nothing.

A thread still inside native code (OpenCV, numba, numpy) while the interpreter exits aborts
the process ("terminate called without an active exception", exit 134), and one still running
when the next session starts works beside it. So every stop waits for the threads it asked to
end through :func:`join_thread`, up to :data:`STOP_WAIT_S`: a bound that only turns a hang
into a log line, never a time the work is expected to take.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator

__all__ = ["STOP_WAIT_S", "join_thread", "one_blas_thread"]

log = logging.getLogger("drovisio.threads")

STOP_WAIT_S = 600.0
"""How long a stop waits for work in progress: a first run's frame compiles the detectors'
kernels (minutes on a small board). The bound only turns a hang into a message."""

_LOCK = threading.Lock()
_STATE: dict = {"controller": None, "depth": 0, "limiter": None}


def _controller():
    ctl = _STATE["controller"]
    if ctl is None:
        try:
            import numpy  # noqa: F401 - its BLAS must be loaded to be found
            from threadpoolctl import ThreadpoolController

            ctl = ThreadpoolController().select(user_api="blas")
            if not ctl.lib_controllers:
                ctl = False
        except Exception:  # noqa: BLE001 - not installed or no BLAS it can drive: no limit
            ctl = False
        _STATE["controller"] = ctl
    return ctl


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with one BLAS thread (nested and concurrent uses share one limit; the
    previous thread count comes back when the last one leaves)."""
    ctl = _controller()
    if not ctl:
        yield
        return
    with _LOCK:
        if _STATE["depth"] == 0:
            _STATE["limiter"] = ctl.limit(limits=1)
        _STATE["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _STATE["depth"] -= 1
            if _STATE["depth"] == 0 and _STATE["limiter"] is not None:
                _STATE["limiter"].restore_original_limits()
                _STATE["limiter"] = None


def join_thread(thread: threading.Thread | None, doing: str,
                limit: float = STOP_WAIT_S) -> bool:
    """Wait up to ``limit`` seconds for ``thread`` to end; whether it ended.

    The thread must already have been told to stop: nothing is signalled here. When it is
    still alive at the limit, one warning names it and what it was ``doing`` (words such as
    "drawing the live 3D scene"). None counts as ended; the calling thread itself cannot be
    waited for (False, no warning).
    """
    if thread is None:
        return True
    if thread is threading.current_thread():
        return False
    thread.join(limit)
    if thread.is_alive():
        log.warning("thread %r (%s) did not end within %.0f s; going on without it",
                    thread.name, doing, limit)
        return False
    return True
