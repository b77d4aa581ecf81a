"""``drovisio bench NAME ...``: dispatch to the benchmark module ``drovisio.bench.NAME``.

A benchmark module exposes ``main(argv: list[str]) -> int`` and parses its own options.
"""

from __future__ import annotations

import argparse
import sys

from drovisio.cli import NotImplementedYet, resolve

#: benchmark name → issue that tracks it (shown while it does not exist yet)
BENCHMARKS = {"aruco": "issue #3", "dots": "issue #4", "renderer": "issue #2",
              "pipeline": "issue #7"}


def run(args: argparse.Namespace) -> int:
    name = args.benchmark
    if name not in BENCHMARKS:
        print(f"drovisio bench: unknown benchmark {name!r}; choose one of "
              f"{', '.join(sorted(BENCHMARKS))}", file=sys.stderr)
        return 2
    try:
        main = resolve(f"drovisio.bench.{name}:main")
    except NotImplementedYet:
        print(f"drovisio bench {name}: not implemented yet (tracked in {BENCHMARKS[name]})",
              file=sys.stderr)
        return 2
    return int(main(list(args.bench_args)) or 0)
