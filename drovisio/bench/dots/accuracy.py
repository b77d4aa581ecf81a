"""The dot benchmark's accuracy parts: random scenes, hidden dots, clutter, lighting."""

from __future__ import annotations

import sys
import time

from drovisio.bench.dots.frames import FrameSource, scene_spec
from drovisio.bench.dots.scoring import Tally


def _run_frames(src: FrameSource, det, key: str, seeds, spec, hide=None, gravity=(True, False),
                progress: str = "") -> dict:
    tallies = {g: Tally() for g in gravity}
    sym = {m.name: m.sym_perm is not None for m in det.models}
    perms = {m.name: m.sym_perm for m in det.models}
    t0 = time.time()
    for n, seed in enumerate(seeds):
        fr = src.get(key, seed, spec, hide)
        for g in gravity:
            poses = det.detect(fr.image, gravity=fr.gravity if g else None)
            tallies[g].add(fr, poses, lambda name: sym.get(name, False), tag=f"{key}:{seed}",
                           perm_of=perms.get)
        if progress and (n + 1) % 25 == 0:
            print(f"  {progress}: {n + 1}/{len(seeds)} frames ({time.time() - t0:.0f} s)",
                  file=sys.stderr, flush=True)
    return {("gravity" if g else "no_gravity"): tallies[g].summary() | {
        "missed": tallies[g].missed[:20]} for g in gravity}


def part_accuracy(src, det, args, n) -> dict:
    spec = scene_spec(src.layout, n_bricks=3, props=2)
    return _run_frames(src, det, "acc", range(args.seed, args.seed + n), spec,
                       progress="accuracy")


def part_hidden(src, det, args, n) -> dict:
    out = {}
    spec = scene_spec(src.layout, n_bricks=3, props=1)
    out["unpainted_1_2"] = _run_frames(src, det, "hid", range(args.seed, args.seed + n), spec,
                                       hide=(1, 2), gravity=(True,), progress="hidden dots")
    spec2 = scene_spec(src.layout, n_bricks=3, props=1, stack_prob=0.6)
    out["stacked"] = _run_frames(src, det, "stk", range(args.seed, args.seed + n // 2), spec2,
                                 gravity=(True,), progress="stacked bricks")
    return out


def part_clutter(src, det, args, n) -> dict:
    spec = scene_spec(src.layout, n_bricks=0, props=8, grounds=("clutter",),
                       distance=(0.4, 2.0))
    res = _run_frames(src, det, "clu", range(args.seed, args.seed + n), spec,
                      progress="clutter")
    return {k: {"frames": v["frames"], "false_bricks": v["false_bricks"]}
            for k, v in res.items()}


def part_lighting(src, det, args, n) -> dict:
    out = {}
    for gain in (0.6, 0.8, 1.0, 1.3):
        for gamma in (0.8, 1.0, 1.25):
            spec = scene_spec(src.layout, n_bricks=3, props=2, gain=(gain, gain),
                               gamma=(gamma, gamma))
            r = _run_frames(src, det, f"lit{gain}-{gamma}", range(args.seed, args.seed + n),
                            spec, gravity=(True,))["gravity"]
            out[f"gain {gain} gamma {gamma}"] = {k: r[k] for k in (
                "eligible", "found", "recall", "lateral_p95_cm", "depth_p95_pct",
                "yaw_p95_deg", "false_bricks")}
    return out
