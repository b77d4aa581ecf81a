"""Run a study: every step's frames through every method that can read its layout, the
speed and memory runs, the figures and the report.

Used by ``drovisio study run`` (and the web tool's Study page). Progress goes to a callback
(the CLI prints a bar on stderr); a step that cannot be read (a missing video, too few
frames) is skipped with its reason and the study goes on. A study can be cancelled from
another thread (the web tool stopping): it ends at its next frame or step, with no result.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio.autopilot.blind import blind_height
from drovisio.autopilot.precland import LandingParams, landing_summary
from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.errors import InputError
from drovisio.geometry import rotation_about
from drovisio.layout import LayoutError, load_layout, shipped_layout_file, with_dictionary
from drovisio.mount import Mount
from drovisio.scenes import SceneSpec, random_scene
from drovisio.study.analysis import frame_errors
from drovisio.study.frames import StepFrame, step_frames
from drovisio.study.methods import METHODS
from drovisio.study.protocol import FIGURES, Protocol, Step
from drovisio.synth import check_render_work, render

__all__ = ["StudyCancelled", "StudyResult", "resolve_layouts", "run_study"]

Progress = Callable[[float, str], None]
Check = Callable[[], None]


class StudyCancelled(Exception):
    """Raised by :func:`run_study` when its ``cancel`` was set before the end: a part of a
    study is no result (a report of it would pass for the whole)."""


def _checkpoint(cancel: threading.Event | None) -> Check:
    """A check the work calls between frames and steps: raises :class:`StudyCancelled` once
    ``cancel`` is set."""
    def check() -> None:
        if cancel is not None and cancel.is_set():
            raise StudyCancelled("the study was cancelled before its end")
    return check


@dataclass
class StudyResult:
    protocol: Protocol
    records: list[dict] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    not_applicable: dict[str, dict[str, str]] = field(default_factory=dict)
    left_out: dict[str, str] = field(default_factory=dict)
    """Methods left out of the whole study, with why and how to add them."""
    speed: list[dict] = field(default_factory=list)
    memory: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    landing: list[dict] = field(default_factory=list)
    """ArduPilot's precision landing per layout and mount (:func:`_landing`)."""
    seconds: float = 0.0


def resolve_layouts(protocol: Protocol, base: Path) -> dict:
    """name → layout (shipped names, or paths relative to the protocol; a dictionary
    override applied)."""
    out = {}
    for ref in protocol.layouts:
        try:
            path = shipped_layout_file(ref.layout)
        except InputError:   # not a shipped name: a path (relative to the protocol)
            path = base / ref.layout   # (absolute stays so)
        try:
            lay = load_layout(path)
            out[ref.name] = with_dictionary(lay, ref.dictionary) if ref.dictionary else lay
        except (LayoutError, OSError) as e:
            raise InputError(f"layouts: {ref.name}: {e}") from None
    return out


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:  # not Linux: the peak is the best there is
        import resource  # (Unix only: deferred)

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _imu_gravity(camera_from_brick: np.ndarray, seed: int, step: int, k: int) -> np.ndarray:
    """Gravity as a drone's autopilot gives it: the brick (lying on the ground) down in the
    camera frame, turned by a 1° attitude error (drawn per frame)."""
    rng = np.random.default_rng([seed, step, k, 7])
    axis = rng.normal(size=3)
    err = rotation_about(axis / np.linalg.norm(axis), np.radians(rng.normal(0.0, 1.0)))
    return err @ (camera_from_brick[:3, :3] @ np.array([0.0, 0.0, -1.0]))


def _pick(found, layout) -> tuple[np.ndarray | None, bool]:
    for name, inst, T, ambiguous in found:
        if name == layout.name and (inst in (0, None)):
            return T, ambiguous
    return None, False


def run_study(protocol: Protocol, base: Path, methods: list[str] | None = None,
              memory_seconds: float = 20.0, speed_bricks=(1, 2, 5, 10, 20),
              speed_frames: int = 3, progress: Progress | None = None,
              landing_runs: int = 10, where: str | None = None,
              cancel: threading.Event | None = None) -> StudyResult:
    """Run ``protocol`` (paths relative to ``base``).

    Args:
        methods: Names from :data:`drovisio.study.methods.METHODS` (default: all).
        memory_seconds: Length of the memory run of each method (Fig. 6.11; 0: none).
        speed_bricks: Brick counts of the frame-rate run (Fig. 6.10; empty: none).
        landing_runs: Simulated precision landings per layout and mount (0: none).
        where: The protocol file's name, for messages (None: "the protocol").
        cancel: Set (from another thread) to stop the study at its next frame or step.

    Raises:
        InputError: an unknown method, or a protocol whose render memory or total work
            (steps × frames × image size, estimated first) is over its cap.
        StudyCancelled: ``cancel`` was set before the study's end.
    """
    t_start = time.perf_counter()
    say = progress or (lambda f, m: None)
    check = _checkpoint(cancel)
    res = StudyResult(protocol)
    names = methods or list(METHODS)
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise InputError(f"--methods: unknown {', '.join(unknown)}; choose from "
                         f"{', '.join(METHODS)}")
    camera = (load_camera(base / protocol.camera if not Path(protocol.camera).is_absolute()
                          else protocol.camera) if protocol.camera else Camera.drone_webcam())
    # a render's memory and the whole protocol's work, before anything starts (recorded
    # steps are counted at the camera's size: their frames are checked when read)
    check_render_work(camera, 2, sum(s.frames for s in protocol.steps if s.source is None),
                      sum(s.frames for s in protocol.steps), len(names),
                      f"{where or 'the protocol'}: steps and camera")
    layouts = resolve_layouts(protocol, base)
    if "apriltag3" in names and not _apriltag_installed():
        res.left_out["apriltag3"] = ("AprilTag 3 is not installed: pip install "
                                     "drovisio[peers] (or pip install pupil-apriltags)")
    estimators = _estimators(layouts, names, camera, res)
    _accuracy_runs(protocol, base, layouts, names, estimators, camera, res, say, check)
    if speed_bricks:
        say(0.8, "frame rate against the number of bricks")
        res.speed = _speed(layouts, names, estimators, camera, speed_bricks, speed_frames,
                           protocol.seed, check)
    if memory_seconds > 0:
        res.memory = _memory(layouts, names, estimators, camera, memory_seconds, say, check)
    if landing_runs > 0 and camera.size_known:
        say(0.95, "precision landing (ArduPilot model)")
        res.landing = _landing(layouts, camera, res.speed, landing_runs, protocol.seed,
                               check)
    res.seconds = time.perf_counter() - t_start
    say(1.0, "done")
    return res


def _apriltag_installed() -> bool:
    try:
        import pupil_apriltags  # noqa: F401  (optional: the peers extra)
    except ImportError:
        return False
    return True


def _estimators(layouts: dict, names: list[str], camera: Camera, res: StudyResult
                ) -> dict[tuple[str, str], Callable]:
    """(layout name, method) → its estimator, for each method that can read the layout; the
    others go to ``res.not_applicable`` with why."""
    estimators: dict[tuple[str, str], Callable] = {}
    for lname, lay in layouts.items():
        for m in names:
            why = METHODS[m].applies(lay)
            if why is None:
                estimators[(lname, m)] = METHODS[m].make(camera, [lay])
            else:
                res.not_applicable.setdefault(lname, {})[m] = why
    return estimators


def _accuracy_runs(protocol: Protocol, base: Path, layouts: dict, names: list[str],
                   estimators: dict[tuple[str, str], Callable], camera: Camera,
                   res: StudyResult, say: Progress, check: Check) -> None:
    """Every step's frames through every method that reads its layout, into ``res.records``;
    a step that cannot be read goes to ``res.skipped`` with its reason."""
    total = sum(s.frames for s in protocol.steps)
    done = 0
    for i, step in enumerate(protocol.steps):
        lay = layouts[step.layout]
        say(done / max(1, total) * 0.8, f"Fig. {step.figure} {step.layout} {step.label}")
        try:
            for k, fr in enumerate(step_frames(step, lay, camera, protocol.seed * 100_003 + i,
                                               base)):
                check()
                g_imu = _imu_gravity(fr.camera_from_brick, protocol.seed, i, k)
                res.records += _frame_records(i, step, lay, fr, g_imu, names, estimators)
                done += 1
        except InputError as e:
            res.skipped.append(f"step {i + 1} (Fig. {step.figure}, {step.layout}, "
                               f"{step.label}): {e}")
            done += step.frames


def _frame_records(i: int, step: Step, lay: Any, fr: StepFrame, g_imu: np.ndarray,
                   names: list[str], estimators: dict[tuple[str, str], Callable]
                   ) -> list[dict]:
    """One frame of step ``i`` through each method: one record per method."""
    turned = step.vary[-1] if step.vary in ("rot_x", "rot_y") else None
    symmetric = getattr(lay, "symmetry", "none") not in (None, "none")
    out = []
    for m in names:
        est = estimators.get((step.layout, m))
        if est is None:
            continue
        t0 = time.perf_counter()
        g = g_imu if METHODS[m].gravity else None
        T, ambiguous = _pick(est(fr.image, g), lay)
        dt = time.perf_counter() - t0
        out.append({
            "step": i, "figure": step.figure, "layout": step.layout,
            "vary": step.vary, "value": step.value, "method": m, "frame": fr.name,
            "recorded": step.source is not None, "found": T is not None,
            "ambiguous": ambiguous,
            "time_ms": 1000 * dt,
            "errors": None if T is None else frame_errors(
                T, fr.camera_from_brick, symmetric, turned,
                "dots" if m.startswith("drovisio-dots") else "codes")})
    return out


def _scene_frames(lay, camera, n: int, count: int, seed: int, check: Check
                  ) -> list[np.ndarray]:
    spec = SceneSpec(layouts=[lay], n_bricks=n, distance=(1.2, 1.8),
                     instances=max(n, min(lay.instances or n, 20)))
    out = []
    for k in range(count):
        check()
        scene, fx = random_scene(seed + 1000 * n + k, spec, camera)
        out.append(render(scene, fx, ss=2).image)
    return out


def _speed(layouts, names, estimators, camera, bricks, count, seed, check: Check
           ) -> list[dict]:
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)        # one core, as on the drone's board; the process's own after
    try:
        return _speed_runs(layouts, names, estimators, camera, bricks, count, seed, check)
    finally:
        cv2.setNumThreads(threads)


def _speed_runs(layouts, names, estimators, camera, bricks, count, seed, check: Check
                ) -> list[dict]:
    out = []
    for lname, lay in layouts.items():
        ms = [m for m in names if (lname, m) in estimators and not METHODS[m].accuracy_only]
        if not ms:
            continue
        for n in bricks:
            n_eff = min(n, lay.instances or n)
            frames = _scene_frames(lay, camera, n_eff, count, seed, check)
            for m in ms:
                check()
                est = estimators[(lname, m)]
                est(frames[0], None)                # warm (compiled kernels, caches)
                times = []
                for img in frames:
                    best = float("inf")
                    for _ in range(3):
                        t0 = time.thread_time()
                        est(img, None)
                        best = min(best, time.thread_time() - t0)
                    times.append(best)
                med = float(np.median(times))
                out.append({"method": m, "layout": lname, "bricks": n_eff,
                            "ms": 1000 * med, "fps": 1.0 / max(med, 1e-6)})
    return out


LANDING_TILTS_DEG = (0.0, 20.0)
"""Mounts of the landing runs: straight down and the sample mount's 20° forward."""


def _landing(layouts, camera, speed: list[dict], runs: int, seed: int, check: Check
             ) -> list[dict]:
    """Per layout and mount (camera 8 cm ahead, 5 cm below the body origin): touchdown
    errors of ArduPilot's precision landing (:mod:`drovisio.autopilot.precland`) at the
    frame rate Drovisio reached on this machine for one brick (the camera's 30 at most;
    15 when not measured), in 3 m/s wind."""
    out = []
    for lname, lay in layouts.items():
        fps = [x["fps"] for x in speed if x["layout"] == lname and x["bricks"] == 1
               and x["method"].startswith("drovisio") and not x["method"].endswith("-image")]
        rate = min(30.0, max(fps)) if fps else 15.0
        for tilt in LANDING_TILTS_DEG:
            check()
            mount = Mount.from_angles(tilt, offset_m=(0.08, 0.0, 0.05))
            sm = landing_summary(camera, mount, lay, LandingParams(rate_hz=rate, seed=seed),
                                 runs)
            out.append({"layout": lname, "tilt_deg": tilt, "rate_hz": round(rate, 1),
                        "runs": runs, "median_error_m": round(sm["median_error_m"], 4),
                        "p90_error_m": round(sm["p90_error_m"], 4),
                        "initialised": sm["initialised"], "wind_mps": sm["wind_mps"],
                        "blind_height_m": blind_height(camera, mount, lay).leaves_at_m})
    return out


def _memory(layouts, names, estimators, camera, seconds, say, check: Check) -> dict:
    out: dict[str, list[tuple[float, float]]] = {}
    for m in names:
        lname = next((ln for ln in layouts if (ln, m) in estimators), None)
        if lname is None or METHODS[m].accuracy_only:
            continue
        frames = _scene_frames(layouts[lname], camera, 5, 4, 77, check)
        est = estimators[(lname, m)]
        for img in frames:
            est(img, None)                          # warm-up before the baseline
        gc.collect()
        series = [(0.0, _rss_mb())]
        t0 = last = time.perf_counter()
        k = 0
        while time.perf_counter() - t0 < seconds:
            check()
            est(frames[k % len(frames)], None)
            k += 1
            now = time.perf_counter()
            if now - last >= max(0.25, seconds / 200):
                series.append((now - t0, _rss_mb()))
                last = now
        series.append((time.perf_counter() - t0, _rss_mb()))
        out[m] = series
        say(0.9, f"memory: {m} ({k} frames in {seconds:g} s)")
    return out


def figure_ids(result: StudyResult) -> list[str]:
    """The thesis figures this study's records can draw."""
    return [f for f in FIGURES if any(r["figure"] == f for r in result.records)]
