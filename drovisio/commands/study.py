"""``drovisio study run|example``: the evaluation study (:mod:`drovisio.study`)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from drovisio.arguments import Command, bounded, whole_in
from drovisio.fileio import FOLDER, check_outputs, output_folder

__all__ = ["COMMAND", "add_arguments", "run"]

# The study's own modules are imported inside the functions that run it: `drovisio --help`
# imports every command module and must not load OpenCV.


_last = [-1]


def _bar(frac: float, msg: str, width: int = 28) -> None:
    """A bar redrawn in place on a terminal; a line per 5 % into a log."""
    n = int(round(frac * width))
    if sys.stderr.isatty():
        sys.stderr.write(f"\r[{'#' * n}{'.' * (width - n)}] {100 * frac:3.0f}% {msg[:60]:<60}")
    elif int(frac * 20) != _last[0]:
        _last[0] = int(frac * 20)
        sys.stderr.write(f"[{'#' * n}{'.' * (width - n)}] {100 * frac:3.0f}% {msg}\n")
    sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    if args.study_action == "example":
        return _example(args)
    return _run(args)


def _protocol(args: argparse.Namespace):
    """(the protocol, the folder its paths are relative to, its text for the report)."""
    import yaml

    from drovisio.study.protocol import default_protocol, load_protocol

    if args.protocol:
        protocol = load_protocol(args.protocol)
        base = Path(args.protocol).resolve().parent
        text = Path(args.protocol).read_text(encoding="utf-8")
    else:
        protocol = default_protocol(quick=args.quick, frames=args.frames)
        base = Path.cwd()
        text = yaml.safe_dump(protocol.model_dump(mode="json", by_alias=True),
                              sort_keys=False, allow_unicode=True)
    if args.frames and args.protocol:
        protocol = protocol.model_copy(update={"steps": [
            s.model_copy(update={"frames": args.frames}) for s in protocol.steps]})
    return protocol, base, text


def _run(args: argparse.Namespace) -> int:
    from drovisio.study.report import write_report
    from drovisio.study.run import run_study

    protocol, base, text = _protocol(args)
    # the steps' recordings come from the protocol: the command line's guard cannot see them
    where = args.protocol or "the default protocol"
    check_outputs([("--out", args.out, FOLDER)],
                  {f"step {k}'s source {s.source} ({where})": base / s.source
                   for k, s in enumerate(protocol.steps, 1) if s.source})
    out = output_folder(args.out, "--out")
    memory = args.memory_seconds if args.memory_seconds is not None else (
        3.0 if args.quick else 20.0)
    methods = [m.strip() for m in args.methods.split(",")] if args.methods else None
    print(f"study {protocol.name!r}: {len(protocol.steps)} steps, "
          f"{sum(s.frames for s in protocol.steps)} frames", file=sys.stderr)
    res = run_study(protocol, base, methods=methods, memory_seconds=memory,
                    speed_bricks=(1, 10) if args.quick else (1, 2, 5, 10, 20),
                    speed_frames=2 if args.quick else 3, progress=_bar,
                    landing_runs=4 if args.quick else 10,
                    where=args.protocol or "the default protocol")
    sys.stderr.write("\n")
    command = "drovisio study run " + " ".join(shlex.quote(a) for a in args.argv_tail)
    data = write_report(res, out, command, text)
    for m, why in res.left_out.items():
        print(f"left out: {m}: {why}", file=sys.stderr)
    for s in res.skipped:
        print(f"skipped: {s}", file=sys.stderr)
    print(f"wrote {out / 'report.html'} ({len(data['figures'])} figures, {data['frames']} "
          f"frames, {res.seconds:.0f} s), {out / 'frames.jsonl'}, {out / 'summary.json'}",
          file=sys.stderr)
    return 0


def _example(args: argparse.Namespace) -> int:
    from drovisio.study.example import write_recorded_example

    out = output_folder(args.out, "--out")
    p = write_recorded_example(out, frames=args.frames or 6)
    print(f"wrote {p} and its recordings; run: drovisio study run --protocol {p} --out "
          f"{out / 'report'}", file=sys.stderr)
    return 0


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio study run|example``."""
    sub = p.add_subparsers(dest="study_action", metavar="ACTION", required=True)
    fmt = argparse.RawDescriptionHelpFormatter
    r = sub.add_parser(
        "run", help="run a study and write its report",
        description="Run the thesis's evaluation (chapter 6) on renders or recordings: every "
                    "step through Drovisio, plain OpenCV and AprilTag 3 (if installed), the "
                    "frame rate against the number of bricks, memory over a run; writes "
                    "report.html (figures 6.2-6.11 embedded), frames.jsonl and summary.json.",
        epilog="Example:\n  drovisio study run --out study/              # the thesis's "
               "protocol, rendered\n  drovisio study run --quick --out study-quick/   # about 5 min "
               "on a small laptop\n"
               "  drovisio study run --protocol my_brick.yaml --out my_brick_study/",
        formatter_class=fmt)
    r.add_argument("--protocol", metavar="PROTOCOL.yaml",
                   help="protocol file (default: the thesis's protocol, rendered)")
    r.add_argument("--out", required=True, metavar="DIR", help="folder for the report")
    r.add_argument("--quick", action="store_true",
                   help="fewer steps and frames: about 5 minutes on a small laptop")
    r.add_argument("--frames", type=whole_in(1, 100_000), metavar="N",
                   help="frames per step (default: the protocol's; 8 rendered, 2 quick)")
    r.add_argument("--methods", metavar="LIST",
                   help="comma-separated: drovisio-codes, drovisio-codes-image, "
                        "drovisio-dots, drovisio-dots-image, opencv, apriltag3 (default: all)")
    r.add_argument("--memory-seconds", type=bounded(0.0, 86400.0), metavar="S",
                   help="length of each method's memory run (default 20, quick 3; the "
                        "thesis ran 1800)")
    e = sub.add_parser(
        "example", help="write a recorded-style example (videos, images, protocol)",
        description="Write renders as recordings (videos and a folder of images) with the "
                    "protocol that gives their truth: the shape of a study of your own "
                    "recordings.",
        epilog="Example:\n  drovisio study example --out my_study/\n"
               "  drovisio study run --protocol my_study/protocol.yaml --out my_study/report",
        formatter_class=fmt)
    e.add_argument("--out", required=True, metavar="DIR", help="folder to write")
    e.add_argument("--frames", type=whole_in(1, 10_000), metavar="N", help="frames per step (6)")


COMMAND = Command(
    name="study",
    summary="is it accurate enough for my brick? the evaluation study and its report",
    description="The thesis's evaluation (chapter 6) on renders or on your own "
                "recordings, Drovisio beside plain OpenCV and AprilTag 3: box plots of "
                "each pose error, frame rate against the number of bricks, memory "
                "over a run, in one HTML report.",
    example="drovisio study run --out study/\n  drovisio study run --quick --out "
            "study-quick/\n  drovisio study example --out my_study/",
    add_arguments=add_arguments,
)
