"""The switch for numba-compiled kernels, shared by the detectors.

Kernels are written as plain-loop Python functions decorated with :func:`jit`; when numba is
importable (a dependency on x86-64 and 64-bit ARM) they are compiled once per machine
(``cache=True``: kept in ``__pycache__`` next to their module) and the detectors call them;
otherwise — 32-bit ARM boards such as the Odroid XU4, or ``DROVISIO_NUMBA=0`` — the
detectors run their numpy reference implementations. :func:`set_enabled` switches at run
time (tests and benchmarks compare the two paths).
"""

from __future__ import annotations

import os

__all__ = ["AVAILABLE", "enabled", "jit", "missing_cache", "set_enabled"]

try:  # pragma: no cover - depends on the platform
    if os.environ.get("DROVISIO_NUMBA", "1") == "0":
        raise ImportError("disabled by DROVISIO_NUMBA=0")
    import numba as _numba

    def jit(fn):
        """Compile ``fn`` with numba (no Python objects, GIL released, cached on disk; where
        no cache folder is writable, compiled again in each process)."""
        try:
            return _numba.njit(cache=True, nogil=True)(fn)
        except RuntimeError:  # "no locator available": read-only install, no writable home
            return _numba.njit(nogil=True)(fn)

    AVAILABLE = True
except ImportError:  # pragma: no cover
    _numba = None  # type: ignore[assignment]
    AVAILABLE = False

    def jit(fn):
        return fn

_FORCE_OFF = False


def enabled() -> bool:
    """Whether the compiled kernels are used (numba importable and not switched off)."""
    return AVAILABLE and not _FORCE_OFF


def set_enabled(on: bool) -> None:
    """Switch the kernels off (``False``) or back on, e.g. to compare with the numpy path."""
    global _FORCE_OFF
    _FORCE_OFF = not on


def missing_cache(namespace: dict) -> list[str]:
    """Names of a module's public kernels that have no compiled cache on disk yet (their
    first call compiles); empty when unknown."""
    if not enabled():
        return []
    try:
        return [name for name, obj in namespace.items()
                if not name.startswith("_") and hasattr(obj, "_cache")
                and not os.path.exists(obj._cache._cache_file._index_path)]
    except Exception:  # noqa: BLE001 - numba internals changed: say nothing
        return []
