"""Where each model's solve starts: OpenCV's closed-form pinhole start, the pinhole and
plumb_bob solves of the same corners (kept for reuse), and the fisheye's three starts."""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Iterator

import cv2
import numpy as np

from drovisio.calibration.lm import Refined, initial_poses, make_camera, refine
from drovisio.calibration.solve.results import CalibrationError
from drovisio.calibration.uncertainty import param_names

_STAGES_CACHE: OrderedDict[bytes, tuple[Refined, Refined]] = OrderedDict()
_STAGES_LOCK = threading.Lock()


def pinhole_stages(O, I, size, fix_k3: bool) -> tuple[Refined, Refined]:
    """The pinhole solve (no distortion) and the plumb_bob solve started from it, k1 k2 p1 p2
    first, then k3 unless fixed: every other model starts from these. Kept for the last 64
    sets of views (``auto`` solves three models on the same views and folds)."""
    h = hashlib.sha1(repr((tuple(size), bool(fix_k3))).encode())
    for o, i in zip(O, I):
        h.update(np.ascontiguousarray(o, np.float64).tobytes())
        h.update(np.ascontiguousarray(i, np.float64).tobytes())
    key = h.digest()
    with _STAGES_LOCK:
        if key in _STAGES_CACHE:
            _STAGES_CACHE.move_to_end(key)
            return _STAGES_CACHE[key]
    out = _solve_pinhole_stages(O, I, size, fix_k3)
    with _STAGES_LOCK:
        _STAGES_CACHE[key] = out
        while len(_STAGES_CACHE) > 64:
            _STAGES_CACHE.popitem(last=False)
    return out


def clear_cache() -> None:
    """Forget the pinhole solves kept for reuse (tests that compare fresh solves)."""
    with _STAGES_LOCK:
        _STAGES_CACHE.clear()


def _solve_pinhole_stages(O, I, size, fix_k3: bool) -> tuple[Refined, Refined]:
    try:
        K0 = cv2.initCameraMatrix2D([o.astype(np.float32) for o in O],
                                    [i.astype(np.float32) for i in I], size)
    except cv2.error:
        K0 = None
    if K0 is None or not np.all(np.isfinite(K0)) or K0[0, 0] <= 0 or K0[1, 1] <= 0:
        raise CalibrationError(
            f"no pinhole camera fits the {len(O)} views (OpenCV's closed-form start failed): "
            "the boards are probably all parallel to the image; add views with the board "
            "tilted 20-40 degrees toward each side")
    th = np.r_[K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], np.zeros(5)]
    poses = initial_poses(make_camera(th, "plumb_bob", size), O, I)
    if poses is None:
        raise CalibrationError("a board cannot be posed through the closed-form pinhole start; "
                               "check --board and --square against the printed board")
    free = np.zeros(9, bool)
    free[:4] = True
    pin = refine(th, poses, "plumb_bob", size, O, I, free)
    free[4:8] = True
    pb = refine(pin.theta, pin.poses, "plumb_bob", size, O, I, free)
    if not fix_k3:
        free[8] = True
        pb = refine(pb.theta, pb.poses, "plumb_bob", size, O, I, free)
    return pin, pb


def _fisheye_starts(pin: Refined, pb: Refined, size) -> list[tuple[str, np.ndarray]]:
    """Starts of the fisheye solve: the plumb_bob and pinhole solves' K, and the
    equidistant model's own closed form for a lens whose image circle fills the diagonal
    (f = diagonal / π, centred: OpenCV's fisheye start)."""
    f0 = float(np.hypot(*size)) / np.pi
    return [("plumb_bob K", pb.theta[:4]), ("pinhole K", pin.theta[:4]),
            ("equidistant closed form",
             np.array([f0, f0, (size[0] - 1) / 2.0, (size[1] - 1) / 2.0]))]


def candidates(O, I, size, model: str, stages: tuple[Refined, Refined],
                fixed_coefficients: int = 0) -> Iterator[tuple[Refined, str]]:
    """Solves of ``model``, one per start, lazily (the caller stops at the first that
    passes :func:`diagnose`): every non-pinhole model starts from the pinhole / plumb_bob
    solve of the same corners ``stages`` (module doc). ``fixed_coefficients`` holds that
    many of the model's highest-order coefficients at 0 (a retry with fewer free
    coefficients).

    Yields:
        (refined solve, which start it came from).
    """
    pin, pb = stages
    if model == "plumb_bob":
        yield pb, "pinhole solve"
        return
    n = len(param_names(model))
    free = np.ones(n, bool)
    if fixed_coefficients:
        free[n - fixed_coefficients:] = False
    if model == "fisheye":
        for name, k in _fisheye_starts(pin, pb, size):
            th = np.r_[k, np.zeros(4)]
            poses = initial_poses(make_camera(th, "fisheye", size), O, I)
            if poses is None:
                continue
            stage = free.copy()
            stage[6:] = False           # k1 k2 first: fewer free coefficients, then all
            r = refine(th, poses, "fisheye", size, O, I, stage)
            if np.any(free[6:]):
                r = refine(r.theta, r.poses, "fisheye", size, O, I, free)
            yield r, name
        return
    th = np.zeros(n)
    th[:9] = pb.theta
    yield refine(th, pb.poses, model, size, O, I, free), "plumb_bob solve"
