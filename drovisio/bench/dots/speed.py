"""The dot benchmark's speed parts: per-frame time against a minimal pass, each compiled
kernel against what it replaces, and memory over many frames."""

from __future__ import annotations

import gc
import os
import sys
import time
import tracemalloc

import cv2
import numpy as np

from drovisio.bench.dots.frames import Frame, timing_frames
from drovisio.camera import PIXEL_STENCIL
from drovisio.camera_kernels import lens_coefficients
from drovisio.detect.dots import DotsState, detect_dots
from drovisio.detect.dots import kernels as K
from drovisio.detect.dots.blobs import refine_centers
from drovisio.detect.dots.color import ClaheMap
from drovisio.detect.dots.match import BlobGeometry, generate_hypotheses
from drovisio.pose import batch as dots_pose


def _minimal_pass(palette_specs):
    ranges = [s.cv_ranges()[0] for s in palette_specs]

    def run(img):
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        for lo, hi in ranges:
            cv2.inRange(hsv, lo, hi)
    return run


_Samples = dict[tuple[int, int], tuple[list[float], ...]]
"""(bricks in view, frame) -> wall times of the minimal pass, of the detector, CPU times of
both, wall times of the numpy path (seconds)."""


def part_timing(src, det, args, n, repeats) -> dict:
    """Per-frame time of the detector and of the minimal pass on the same frames, for 1, 5
    and 20 bricks in view. Every repeat visits every frame of every brick count once (minimal
    pass, then detector), so a change of the machine's load hits all counts alike; each
    figure is the median over a frame's repeats, then the median over frames."""
    if args.threads is not None:
        cv2.setNumThreads(args.threads)
    minimal = _minimal_pass(det.specs)
    counts = (1, 5, 20)
    frames = {nb: timing_frames(src, args, nb, n) for nb in counts}
    compiled = K.enabled()
    samples: _Samples = {(nb, k): ([], [], [], [], []) for nb in counts for k in range(n)}
    found = _time_interleaved(det, minimal, frames, samples, repeats)
    if compiled:
        _time_numpy_path(det, frames, samples, repeats)
    out = {"threads": cv2.getNumThreads(), "repeats": repeats, "frames_per_count": n,
           "compiled_kernels": compiled}
    base = None
    for nb in counts:
        row = _timing_row(frames[nb], samples, found[nb], nb, n, compiled)
        if base is None:
            base = row
        row["vs_1_brick"] = row["detect_ms"] / base["detect_ms"]
        row["vs_1_brick_cpu"] = row["detect_cpu_ms"] / base["detect_cpu_ms"]
        out[f"{nb}_bricks"] = row
    return out


def _time_interleaved(det, minimal, frames: dict[int, list[Frame]], samples: _Samples,
                      repeats: int) -> dict[int, list[int]]:
    """The minimal pass and the detector on every frame, ``repeats`` times (after three
    warm-up runs); returns the bricks found per frame."""
    wall, cpu = time.perf_counter, time.process_time
    found = {nb: [0] * len(fr_list) for nb, fr_list in frames.items()}
    for fr_list in frames.values():
        for fr in fr_list:
            for _ in range(3):  # warm-up
                minimal(fr.image)
                det.detect(fr.image, gravity=fr.gravity)
    for _ in range(repeats):
        for nb, fr_list in frames.items():
            for k, fr in enumerate(fr_list):
                a, b, ca, cb, _ = samples[(nb, k)]
                t, c = wall(), cpu()
                minimal(fr.image)
                a.append(wall() - t)
                ca.append(cpu() - c)
                t, c = wall(), cpu()
                poses = det.detect(fr.image, gravity=fr.gravity)
                b.append(wall() - t)
                cb.append(cpu() - c)
                found[nb][k] = len(poses)
    return found


def _time_numpy_path(det, frames: dict[int, list[Frame]], samples: _Samples,
                     repeats: int) -> None:
    """The same detector on its numpy path, for comparison (a pass of its own: interleaved,
    its larger working set would evict the compiled path's data between calls)."""
    wall = time.perf_counter
    K.set_enabled(False)
    try:
        for _ in range(max(3, repeats // 4)):
            for nb, fr_list in frames.items():
                for k, fr in enumerate(fr_list):
                    t = wall()
                    det.detect(fr.image, gravity=fr.gravity)
                    samples[(nb, k)][4].append(wall() - t)
    finally:
        K.set_enabled(True)


def _timing_row(fr_list: list[Frame], samples: _Samples, found: list[int], nb: int, n: int,
                compiled: bool) -> dict:
    """The figures of one brick count (medians over frames of the medians over repeats)."""
    t_min, t_det, c_min, c_det = ([float(np.median(samples[(nb, k)][i])) for k in range(n)]
                                  for i in range(4))
    inview = [sum(int(np.sum(x.visible)) >= 4 for x in fr.bricks) for fr in fr_list]
    row = {"frames": n, "bricks_in_view_median": float(np.median(inview)),
           "bricks_found_median": float(np.median(found)),
           "minimal_ms": 1e3 * float(np.median(t_min)),
           "detect_ms": 1e3 * float(np.median(t_det)),
           "ratio": float(np.median(np.asarray(t_det) / np.asarray(t_min))),
           "minimal_cpu_ms": 1e3 * float(np.median(c_min)),
           "detect_cpu_ms": 1e3 * float(np.median(c_det)),
           "ratio_cpu": float(np.median(c_det) / max(np.median(c_min), 1e-9)),
           "loadavg": os.getloadavg()[0]}
    if compiled:
        t_npy = [float(np.median(samples[(nb, k)][4])) for k in range(n)]
        row["numpy_path_ms"] = 1e3 * float(np.median(t_npy))
        row["numpy_path_vs_compiled"] = float(np.median(np.asarray(t_npy) / np.asarray(t_det)))
    return row


def _time_pair(fast, ref, repeats: int) -> tuple[float, float]:
    """Median seconds of ``fast`` and of ``ref`` over ``repeats`` interleaved runs (after
    one warm-up run of each)."""
    fast()
    ref()
    fast_s: list[float] = []
    ref_s: list[float] = []
    for _ in range(repeats):
        t = time.perf_counter()
        fast()
        fast_s.append(time.perf_counter() - t)
        t = time.perf_counter()
        ref()
        ref_s.append(time.perf_counter() - t)
    return float(np.median(fast_s)), float(np.median(ref_s))


def part_kernels(src, det, args, n, repeats) -> dict:
    """Median time of each compiled kernel and of what it replaces, on the same inputs (the
    stages of the 20-brick timing frames), in this process."""

    if not K.enabled():
        return {"skipped": "numba is not installed (or DROVISIO_NUMBA=0)"}
    cfg = det.config
    m = det.models[0]
    T = m.plane_from_brick
    cases: dict[str, list[tuple[float, float]]] = {}

    def both(name, fast, ref):
        # timed at once: the closures read this frame's inputs, which the next frame rebinds
        cases.setdefault(name, []).append(_time_pair(fast, ref, repeats))

    for fr in timing_frames(src, args, 20, n):
        img = fr.image
        blobs, hsv = det.blobs(img)
        poses = det.detect(img, gravity=fr.gravity)
        if not len(blobs) or not poses:
            continue
        idx = np.arange(len(blobs))

        def off(fn):
            def run():
                K.set_enabled(False)
                try:
                    return fn()
                finally:
                    K.set_enabled(True)
            return run

        both("sub-pixel centres (all blobs)", lambda: refine_centers(img, blobs, idx),
             off(lambda: refine_centers(img, blobs, idx)))
        v = hsv[:, :, 2]
        x, y = np.ascontiguousarray(blobs.x), np.ascontiguousarray(blobs.y)
        raw = v[np.clip(np.rint(y).astype(int), 0, v.shape[0] - 1),
                np.clip(np.rint(x).astype(int), 0, v.shape[1] - 1)].astype(float)
        both("CLAHE at the blobs", lambda: K.clahe_at(hsv, x, y, 8, 8, cfg.clahe_stride,
                                                      cfg.clahe_clip),
             lambda: ClaheMap(v, cfg.clahe_clip, cfg.clahe_tiles, cfg.clahe_stride)(x, y, raw))
        q, cov = det._blob_geometry(blobs)
        geo = BlobGeometry.build(q, cov, blobs.color, ~blobs.border)
        hyp = lambda: generate_hypotheses(m, geo, cfg.seeds_per_blob, cfg.ratio_tol,  # noqa
                                          cfg.match_tol, cfg.min_dots)
        both("matching hypotheses", hyp, off(hyp))
        # poses: the bricks found, their dots' normalised image points
        B = len(poses)
        qs = np.zeros((B, m.n, 2))
        w = np.zeros((B, m.n))
        for b, p in enumerate(poses):
            qs[b, p.markers] = det.camera.normalize_fast(p.image_points)
            w[b, p.markers] = 1.0
        Pm = np.repeat(m.P[None], B, axis=0)
        Rpb, tpb = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
        both("IPPE, both solutions (vs cv2.solvePnPGeneric per brick)",
             lambda: K.ippe(Pm, qs, w, Rpb, tpb),
             lambda: [cv2.solvePnPGeneric(m.X[w[b] > 0], qs[b][w[b] > 0], np.eye(3), None,
                                          flags=cv2.SOLVEPNP_IPPE) for b in range(B)])
        R0 = np.array([cv2.Rodrigues(p.rvec)[0] for p in poses])
        t0 = np.array([p.tvec for p in poses])
        X = np.repeat(m.X[None], B, axis=0)
        lm = lambda: dots_pose.refine_poses(X, qs, w, R0, t0 + 0.003, 4)  # noqa: E731
        both("Levenberg-Marquardt, all bricks", lm, off(lm))
        px = np.stack([blobs.x, blobs.y], axis=1)
        Kc, dist = det.camera.K, det.camera.dist
        d12 = None if det.camera.is_fisheye else lens_coefficients(dist)
        if d12 is not None:
            args12 = (Kc[0, 0], Kc[1, 1], Kc[0, 2], Kc[1, 2], d12)
            both("undistortion + local Jacobian (vs cv2.undistortPoints, 5-point stencil)",
                 lambda: K.undistort(px, *args12),
                 lambda: cv2.undistortPoints((px[None] + PIXEL_STENCIL[:, None]).reshape(-1, 1, 2),
                                             Kc, dist, None, None, None,
                                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                              20, 1e-12)))
    out = {}
    for name, pairs in cases.items():
        tf = np.array([p[0] for p in pairs])
        tr = np.array([p[1] for p in pairs])
        out[name] = {"compiled_us": 1e6 * float(np.median(tf)),
                     "reference_us": 1e6 * float(np.median(tr)),
                     "speedup": float(np.median(tr / tf))}
    return out


def _rss_kb() -> int:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") // 1024


def part_memory(src, det, args, nframes) -> dict:
    """Resident memory over ``nframes`` calls of :func:`detect_dots` (with a stream state) on
    a loop of cached frames with 1, 5 and 20 bricks.

    RSS is sampled every 250 frames after the warm-up (after ``gc.collect()``). It oscillates
    by about a megabyte as malloc grows and trims its heap for the frames' temporaries, so
    besides the raw end − warm-up difference the report gives the growth of the floor (lowest
    sample of the last quarter − lowest of the first quarter) and the trend (least-squares
    slope × frames); with ``--memory-trace`` also the growth of Python's own allocations
    (tracemalloc), which is what a leak would show first.
    """

    frames = (timing_frames(src, args, 1, 2) + timing_frames(src, args, 5, 2)
              + timing_frames(src, args, 20, 2))
    state = DotsState()
    nf = len(frames)
    # warm-up and end both just after the last frame of the loop (the same objects alive)
    nframes = max(nf * 2, -(-nframes // nf) * nf)
    warm = max(nf, min(1000, nframes // 10) // nf * nf) - 1
    xs, samples = [], []
    t0 = time.time()
    rss_warm = None
    traced0 = None
    if args.memory_trace:
        tracemalloc.start()
    for k in range(nframes):
        fr = frames[k % len(frames)]
        detect_dots(fr.image, src.camera, [src.layout], gravity=fr.gravity, state=state)
        if k == warm:
            gc.collect()
            rss_warm = _rss_kb()
            if args.memory_trace:
                traced0 = tracemalloc.get_traced_memory()[0]
        if k >= warm and (k - warm) % 250 == 0:
            gc.collect()
            xs.append(k)
            samples.append(_rss_kb())
        if (k + 1) % 2000 == 0:
            print(f"  memory: {k + 1}/{nframes} frames ({time.time() - t0:.0f} s, RSS "
                  f"{_rss_kb() / 1024:.1f} MB)", file=sys.stderr, flush=True)
    gc.collect()
    rss_end = _rss_kb()
    assert rss_warm is not None, "the warm-up ends inside the loop"
    xs.append(nframes)
    samples.append(rss_end)
    traced = None
    if traced0 is not None:
        traced = (tracemalloc.get_traced_memory()[0] - traced0) / 1024
        tracemalloc.stop()
    q = max(1, len(samples) // 4)
    slope = float(np.polyfit(np.asarray(xs, float), np.asarray(samples, float), 1)[0]) \
        if len(samples) > 2 else 0.0
    return {"frames": nframes, "warmup_frames": warm, "rss_after_warmup_kb": rss_warm,
            "rss_end_kb": rss_end, "growth_kb": rss_end - rss_warm,
            "floor_growth_kb": min(samples[-q:]) - min(samples[:q]),
            "trend_kb": slope * (nframes - warm),
            "band_kb": max(samples) - min(samples),
            "python_heap_growth_kb": traced, "seconds": time.time() - t0}
