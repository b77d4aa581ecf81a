"""``drovisio synth samples``: regenerate the sample sessions the web tool runs on without a
camera (:mod:`drovisio.synth_samples`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from drovisio.arguments import Command

__all__ = ["COMMAND", "add_arguments", "run"]


def run(args: argparse.Namespace) -> int:
    # deferred: the renderer loads OpenCV and numba, which `drovisio --help` must not
    from drovisio.synth_samples import main as generate

    only = getattr(args, "only", None)
    return int((generate(args.out) if only is None else generate(args.out, only)) or 0)

# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio synth samples``."""
    sub = p.add_subparsers(dest="synth_action", metavar="ACTION", required=True)
    samples = sub.add_parser(
        "samples",
        help="regenerate the sample sessions the web tool runs on without a camera",
        description="Render the sample sessions (images, camera file, ground truth) with "
                    "drovisio's synthetic renderer.",
        epilog="Example:\n  drovisio synth samples --out sample_sessions",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    samples.add_argument("--out", type=Path, default=None, metavar="DIR",
                         help="output folder (default: sample_sessions/ of this checkout)")
    samples.add_argument("--only", choices=("calibration", "approach", "missions", "study",
                                            "pad"),
                         help="rewrite only this part (default: all)")


COMMAND = Command(
    name="synth",
    summary="generate synthetic data (sample sessions, scenes)",
    description="Generate synthetic data with drovisio's renderer. `samples` regenerates "
                "the sample sessions shipped in sample_sessions/.",
    example="drovisio synth samples --out sample_sessions",
    add_arguments=add_arguments,
)
