"""``drovisio bench NAME ...``: dispatch to the benchmark module ``drovisio.bench.NAME``.

A benchmark module exposes ``main(argv: list[str]) -> int`` and parses its own options.
"""

from __future__ import annotations

import argparse
import importlib

from drovisio.arguments import Command
from drovisio.errors import InputError

__all__ = ["BENCHMARKS", "COMMAND", "add_arguments", "run"]

#: benchmark name → what it measures (``drovisio bench --help``)
BENCHMARKS = {
    "aruco": "code bricks: corners, recall, pose accuracy, speed against plain OpenCV",
    "dots": "colour-dot bricks: recall, accuracy, speed, memory",
    "lens": "both detectors and the calibration through a 150° fisheye lens",
    "pipeline": "the live pipeline: latency, frame rate, memory",
    "real": "real photos (tags, ChArUco, chessboards): Drovisio beside OpenCV and AprilTag 3",
    "renderer": "exactness of the synthetic renderer",
    "fleet": "a station and several drones over Zenoh: memory, latency, frames lost",
}


def run(args: argparse.Namespace) -> int:
    name = args.benchmark
    if name not in BENCHMARKS:
        raise InputError(f"unknown benchmark {name!r}; choose one of "
                         f"{', '.join(sorted(BENCHMARKS))}")
    main = importlib.import_module(f"drovisio.bench.{name}").main
    return int(main(list(args.bench_args)) or 0)


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio bench``: the benchmark's name, then its own options."""
    p.add_argument("benchmark", metavar="NAME",
                   help="which benchmark: " + "; ".join(f"{k} ({v})"
                                                        for k, v in BENCHMARKS.items()))
    p.add_argument("bench_args", nargs=argparse.REMAINDER, metavar="...",
                   help="options of that benchmark (drovisio bench NAME --help)")


COMMAND = Command(
    name="bench",
    summary="benchmarks and the evaluation study",
    description="Measure detection accuracy and speed on synthetic and recorded sessions "
                "(the evaluation study).",
    example="drovisio bench aruco --frames 50\n  drovisio bench dots --help",
    add_arguments=add_arguments,
)
