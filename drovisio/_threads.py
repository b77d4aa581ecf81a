"""One BLAS thread for a frame's small dense products.

numpy's matrix products go to OpenBLAS, which splits a product over its own threads once it
is a few hundred thousand multiply-adds (a code reader's batch, the corner fit's normal
equations). On a drone's two cores shared with OpenCV and the camera, those threads wait
for a core by spinning: a 0.3-ms product measured 2–35 ms of the calling thread's time on a
loaded machine, and the frame's time then followed the load. Detection therefore runs its
products on the calling thread (:func:`one_blas_thread`), the way OpenCV runs with
``cv2.setNumThreads(1)``; the results are the same bits whatever the thread count.

``threadpoolctl`` (a dependency) switches the BLAS library found in the process; without it,
or with no BLAS it knows, this does nothing.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

__all__ = ["one_blas_thread"]

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
