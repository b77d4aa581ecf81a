"""``drovisio bench dots``: its arguments and its run."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

from drovisio.bench.dots.accuracy import part_accuracy, part_clutter, part_hidden, part_lighting
from drovisio.bench.dots.frames import FrameSource, bench_layout
from drovisio.bench.dots.report import print_report
from drovisio.bench.dots.speed import part_kernels, part_memory, part_timing
from drovisio.bounds import ArgumentParser, whole
from drovisio.detect.dots import DotDetector
from drovisio.fileio import atomic_write_text, check_output_path

EXAMPLE = """example:
  drovisio bench dots                      # all parts, default frame counts (~15 min first run)
  drovisio bench dots --quick              # small counts, a couple of minutes
  drovisio bench dots --parts timing,memory --memory-frames 20000
  drovisio bench dots --json report.json   # also write the figures as JSON
"""


PARTS = ("accuracy", "hidden", "clutter", "lighting", "timing", "memory", "kernels")


def _parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="drovisio bench dots",
        description="Benchmark of the colour-dot detector on rendered scenes: "
                    "recall, pose errors, flips, false bricks, lighting, speed, memory.",
        epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default=",".join(PARTS),
                   help=f"comma-separated parts to run (default: all of {','.join(PARTS)})")
    p.add_argument("--quick", action="store_true", help="small frame counts (a smoke run)")
    p.add_argument("--frames", type=whole(1, 1_000_000), default=None,
                   help="frames of the accuracy part (default 300; quick 40)")
    p.add_argument("--hidden-frames", type=whole(1, 1_000_000), default=None, help="default 200; quick 30")
    p.add_argument("--clutter-frames", type=whole(1, 1_000_000), default=None, help="default 220; quick 30")
    p.add_argument("--lighting-frames", type=whole(1, 1_000_000), default=None,
                   help="frames per gain × gamma cell (default 12; quick 2)")
    p.add_argument("--timing-frames", type=whole(1, 1_000_000), default=None,
                   help="frames per brick count (default 6; quick 3)")
    p.add_argument("--timing-repeats", type=whole(1, 1_000_000), default=None,
                   help="timed runs per frame (default 40; quick 10)")
    p.add_argument("--memory-frames", type=whole(1, 1_000_000), default=None,
                   help="frames of the memory loop (default 20000; quick 2000)")
    p.add_argument("--memory-trace", action="store_true",
                   help="also trace Python's allocations in the memory part (slower)")
    p.add_argument("--seed", type=whole(0, 2**32 - 1), default=0, help="first scene seed")
    p.add_argument("--layout", default=None,
                   help="layout file (default: the shipped drick-dots-2x3.json)")
    p.add_argument("--cache", default=None,
                   help="folder for rendered frames (default ~/.cache/drovisio/bench-dots)")
    p.add_argument("--no-cache", action="store_true", help="render every frame afresh")
    p.add_argument("--threads", type=whole(1, 256), default=None,
                   help="cv2.setNumThreads for the timing part (default: OpenCV's own)")
    p.add_argument("--json", metavar="FILE", help="write all figures as JSON")
    return p


def _counts(args: argparse.Namespace) -> dict[str, int]:
    """Frames (and timing repeats) of each part: the options', else the defaults (quick or
    full)."""
    q = args.quick
    return {
        "accuracy": args.frames or (40 if q else 300),
        "hidden": args.hidden_frames or (30 if q else 200),
        "clutter": args.clutter_frames or (30 if q else 220),
        "lighting": args.lighting_frames or (2 if q else 12),
        "timing": args.timing_frames or (3 if q else 6),
        "repeats": args.timing_repeats or (10 if q else 40),
        "memory": args.memory_frames or (2000 if q else 20000),
    }


def _run_parts(parts: list[str], src: FrameSource, det: DotDetector, args: argparse.Namespace
               ) -> dict:
    """The figures of each part asked for, in the order of :data:`PARTS`."""
    n = _counts(args)
    reps = n["repeats"]
    run: dict[str, Callable[[], dict]] = {
        "accuracy": lambda: part_accuracy(src, det, args, n["accuracy"]),
        "hidden": lambda: part_hidden(src, det, args, n["hidden"]),
        "clutter": lambda: part_clutter(src, det, args, n["clutter"]),
        "lighting": lambda: part_lighting(src, det, args, n["lighting"]),
        "timing": lambda: part_timing(src, det, args, n["timing"], reps),
        "memory": lambda: part_memory(src, det, args, n["memory"]),
        "kernels": lambda: part_kernels(src, det, args, n["timing"], max(10, reps // 2)),
    }
    return {name: run[name]() for name in PARTS if name in parts}


def main(argv: list[str]) -> int:
    """``drovisio bench dots`` (exit 0, or 2 for an unknown part)."""
    args = _parser().parse_args(argv)
    if args.json:
        check_output_path(args.json, "--json", folder_must_exist=True)
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad:
        print(f"drovisio bench dots: unknown part(s) {', '.join(bad)}; choose from "
              f"{', '.join(PARTS)}", file=sys.stderr)
        return 2
    layout = bench_layout(args.layout)
    cache = None if args.no_cache else Path(args.cache or Path.home() / ".cache" / "drovisio"
                                            / "bench-dots")
    src = FrameSource(layout, cache)
    det = DotDetector(src.camera, [layout])
    rep: dict = {"layout": layout.name, "camera": src.camera.name}
    t0 = time.time()
    rep.update(_run_parts(parts, src, det, args))
    rep["seconds"] = time.time() - t0
    print_report(rep)
    if args.json:
        atomic_write_text(args.json, json.dumps(rep, indent=2, default=float))
    return 0
