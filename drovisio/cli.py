"""The ``drovisio`` command line.

This module *declares* the commands (their arguments, help and examples: the contract of
DESIGN.md) and dispatches to their implementations, imported lazily so that ``drovisio --help``
stays fast (no OpenCV, no web stack). Where a command's code lives is written in ``COMMANDS``
as ``"module:function"`` (default ``drovisio.commands.<name>:run``).

Every error is handled once, here: bad input (:class:`~drovisio.errors.InputError`, and
:class:`~drovisio.errors.WriteError` for a file that could not be written) prints one line
``drovisio COMMAND: FILE: FIELD: what to do`` and exits 2; anything unexpected prints one line
and the path of a file holding the full traceback (``--debug`` prints it instead) and exits 1.
A closed output pipe (``drovisio detect ... | head -1``) ends the command quietly.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

PROG = "drovisio"
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 1
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader left


def _version() -> str:
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("drovisio")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "0+unknown"


def one_line(text: object, limit: int = 400) -> str:
    from drovisio.errors import one_line as fold

    return fold(text, limit)


def positive_int(text: str) -> int:
    """argparse type: a whole number from 1 to a billion (:mod:`drovisio.bounds`)."""
    from drovisio.bounds import whole

    return whole(1, 10**9)(text)


def finite_float(text: str) -> float:
    """argparse type: a finite number (at most 10⁹ in size)."""
    from drovisio.bounds import number

    return number(-1e9, 1e9)(text)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (at most 10⁹)."""
    from drovisio.bounds import number

    return number(0.0, 1e9, above=True)(text)


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number ≥ 0 (at most 10⁹)."""
    from drovisio.bounds import number

    return number(0.0, 1e9)(text)


def mount_offset(text: str) -> float:
    """argparse type: one coordinate of the camera's offset, metres, within the bound every
    mount file is held to (:data:`drovisio.bounds.MOUNT_OFFSET_MAX_M`)."""
    from drovisio.bounds import MOUNT_OFFSET_MAX_M, number

    return number(-MOUNT_OFFSET_MAX_M, MOUNT_OFFSET_MAX_M, unit="m")(text)


def seed_number(text: str) -> int:
    """argparse type: a random seed, 0 to 2³²−1 (what numpy's generators take)."""
    from drovisio.bounds import whole

    return whole(0, 2**32 - 1)(text)


def supersampling(text: str) -> int:
    """argparse type: the renderer's samples per pixel and axis, 1 to
    :data:`drovisio.bounds.MAX_SUPERSAMPLING` (its memory grows with the square)."""
    from drovisio.bounds import MAX_SUPERSAMPLING, whole

    return whole(1, MAX_SUPERSAMPLING)(text)


def board_square(text: str) -> float:
    """argparse type: a board square's side, metres (above 0, at most 1 m)."""
    from drovisio.bounds import number

    return number(0.0, 1.0, above=True, unit="m")(text)


def _whole(lo: int, hi: int) -> Callable[[str], int]:
    """argparse type: a whole number in ``lo..hi`` (parsed when used: --help stays light)."""
    def parse(text: str) -> int:
        from drovisio.bounds import whole

        return whole(lo, hi)(text)

    parse.__name__ = "whole number"
    return parse


def _bounded(lo: float, hi: float, above: bool = False) -> Callable[[str], float]:
    """argparse type: a finite number in ``[lo, hi]`` (``above``: ``lo`` excluded)."""
    def parse(text: str) -> float:
        from drovisio.bounds import number

        return number(lo, hi, above=above)(text)

    parse.__name__ = "number"
    return parse


def drone_id(text: str) -> str:
    """A drone id usable in ROS names and Zenoh keys."""
    import re

    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,31}", text):
        raise argparse.ArgumentTypeError(
            f"{text!r}: a letter, then letters, digits or _ (at most 32), e.g. drone1")
    return text


def port_number(text: str) -> int:
    """argparse type: a TCP port, 1 to 65535."""
    from drovisio.bounds import parse_whole

    try:
        return parse_whole(text, 1, 65535)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{one_line(text, 40)} is not a port (1 to 65535)") \
            from None


# --------------------------------------------------------------------------------------------
# Command table
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Command:
    name: str
    summary: str  # one line, shown in `drovisio --help`
    description: str  # a paragraph, shown in `drovisio NAME --help`
    example: str  # shown under "Example:" in `drovisio NAME --help`
    add_arguments: Callable[[argparse.ArgumentParser], None]
    target: str = ""  # "module:function"; default drovisio.commands.<name>:run
    spelled: str = ""  # how users type it, when not its name (``calibrate board``)

    @property
    def entry_point(self) -> str:
        return self.target or f"drovisio.commands.{self.name}:run"


def _add_bench(p: argparse.ArgumentParser) -> None:
    from drovisio.commands.bench import BENCHMARKS  # light: names and one-line summaries

    p.add_argument("benchmark", metavar="NAME",
                   help="which benchmark: " + "; ".join(f"{k} ({v})"
                                                        for k, v in BENCHMARKS.items()))
    p.add_argument("bench_args", nargs=argparse.REMAINDER, metavar="...",
                   help="options of that benchmark (drovisio bench NAME --help)")


def _add_detect(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", required=True, metavar="CAMERA_FILE",
                   help="camera file (OpenCV FileStorage YAML/XML/JSON or ROS camera_info YAML)")
    p.add_argument("--layout", required=True, action="append", metavar="LAYOUT.json",
                   help="marker layout file; repeat for several brick types")
    p.add_argument("--method", choices=("auto", "aruco", "dots"), default="auto",
                   help="detector to use (default: auto, i.e. whatever the layouts need)")
    p.add_argument("--gravity-file", metavar="FILE",
                   help='JSON Lines {"file": ..., "gravity": [gx, gy, gz]} per frame, unit vector '
                        "pointing down in the camera frame; resolves flip ambiguities")
    p.add_argument("--out", metavar="FILE", help="write JSON Lines here instead of stdout")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="image files, folders of images, or video files")


def _add_calibrate(p: argparse.ArgumentParser) -> None:
    p.add_argument("--board", required=True, metavar="KIND:COLSxROWS",
                   help="calibration target, e.g. chessboard:9x6 (inner corners, columns x rows)")
    p.add_argument("--square", required=True, type=board_square, metavar="METRES",
                   help="side of one board square in metres, e.g. 0.025")
    p.add_argument("--report", metavar="REPORT.json",
                   help="write the calibration report (errors, rejected views, verdict) here")
    p.add_argument("--out", required=True, metavar="CAMERA.yaml",
                   help="camera file to write (OpenCV FileStorage form)")
    p.add_argument("--model", default="plumb_bob",
                   choices=("auto", "plumb_bob", "rational", "thin_prism", "tilted", "fisheye"),
                   help="lens model: plumb_bob (OpenCV's 5 coefficients, default), rational "
                        "(8), thin_prism (12: rational + thin prism), tilted (14: + the "
                        "sensor's tilt), fisheye (Kannala-Brandt, 4: lenses of 120 deg and "
                        "more), or auto (plumb_bob, rational or fisheye, chosen on held-out "
                        "views; the report says why)")
    p.add_argument("--board-flatness", action="store_true",
                   help="also measure how far the board bowed (fitted with the lens, as "
                        "mrcal's board warp): a bow of a millimetre "
                        "moves the focal length by about 1 %%; the report says it")
    p.add_argument("images", nargs="+", metavar="IMAGE_OR_FOLDER",
                   help="calibration images, or folders of them")


def _add_calibrate_board(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pdf", required=True, metavar="BOARD.pdf", help="PDF file to write")
    p.add_argument("--board", default="chessboard:9x6", metavar="KIND:COLSxROWS",
                   help="chessboard:9x6 (default) or charuco:7x5 (inner corners)")
    p.add_argument("--paper", default="A4", choices=("A4", "A3", "Letter"),
                   help="paper size (default A4); the board is as large as fits")
    p.add_argument("--square", type=board_square, metavar="METRES",
                   help="side of one square on paper (default: the largest whole mm that fits)")


def _add_calibrate_mount(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", required=True, metavar="CAMERA_FILE", help="camera file")
    p.add_argument("--layout", action="append", metavar="LAYOUT.json",
                   help="layout of the code lying flat (default: the shipped landing pad and "
                        "dricks)")
    p.add_argument("--aligned", action="store_true",
                   help="the code's x axis points toward the drone's nose: measure the pan too")
    p.add_argument("--offset", nargs=3, type=mount_offset, default=(0.0, 0.0, 0.0),
                   metavar=("FORWARD", "RIGHT", "DOWN"),
                   help="the camera's centre from the body origin, metres (measured with a "
                        "tape; default 0 0 0)")
    p.add_argument("--out", required=True, metavar="MOUNT.json", help="mount file to write")
    p.add_argument("images", nargs="+", metavar="IMAGE_OR_FOLDER",
                   help="pictures from the drone's camera, the drone standing level")


def _add_pipeline(p: argparse.ArgumentParser, serving: bool) -> None:
    """The pipeline's options, shared by ``run`` and ``serve`` (one process on the drone)."""
    p.add_argument("--layout", required=not serving, action="append", metavar="LAYOUT.json",
                   help="marker layout file; repeat for several brick types"
                        + (" (default: the shipped layouts)" if serving else ""))
    p.add_argument("--mount", metavar="MOUNT_FILE",
                   help="camera mount (tilt, pan, roll and offset, or body_from_camera) for "
                        "poses in the drone's FRD body frame")
    p.add_argument("--sink", action="append", metavar="SINK",
                   help="jsonl:-, jsonl:PATH, udp://HOST:PORT, mavlink:CONNECTION, ws://HOST:PORT "
                        "(WebSocket feed) or zenoh:connect=tcp/HOST:PORT (ROS 2 messages over "
                        "Zenoh, as rmw_zenoh); repeatable"
                        + (" (with a sink, the pipeline runs from the start, watched or not)"
                           if serving else " (default jsonl:-)"))
    p.add_argument("--record", metavar="DIR|FILE.mcap",
                   help="also record the frames and results here: a folder (Drovisio's own "
                        "form) or an .mcap file (ROS 2 messages, for ros2 bag and Foxglove)")
    p.add_argument("--drone-id", type=drone_id, metavar="ID",
                   help="this drone's name on a site with several (letters, digits, _): ROS 2 "
                        "topics under /drovisio/ID and frame ids ID/base_link (zenoh: sinks, "
                        ".mcap recordings)")
    p.add_argument("--record-images", choices=("jpeg", "png"), default="jpeg",
                   help="images of an .mcap recording: jpeg (quality 95, default) or png "
                        "(lossless: a replay sees exactly the frames the run saw; ~4x larger "
                        "and slower to write)")
    p.add_argument("--target", default="nearest", metavar="TARGET",
                   help="brick sent to the flight controller: nearest (default), LAYOUT, "
                        "LAYOUT:INSTANCE, track:N or none; changeable at run time"
                        + (" on the live page" if serving else " through a ws:// sink"))
    p.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                   help="LANDING_TARGET flavour of mavlink: sinks: ardupilot (BODY_FRD + "
                        "distance, default) or px4 (LOCAL_NED from the link's attitude and "
                        "position)")
    p.add_argument("--send-held-targets", action="store_true",
                   help="also send the flight controller a target not seen in the current frame "
                        "(its last measurement, stamped with that measurement's time). Off by "
                        "default: autopilots filter line-of-sight measurements and expect "
                        "silence when the target is not seen")
    p.add_argument("--max-age", type=_bounded(0.0, 3600.0, above=True), default=0.5,
                   metavar="SECONDS",
                   help="drop a brick not seen for this long (default 0.5 s)")


def _add_run(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", required=True, metavar="SOURCE",
                   help="camera index (0), video file, folder of images (name order) or stream URL")
    p.add_argument("--camera", required=True, metavar="CAMERA_FILE", help="camera file")
    _add_pipeline(p, serving=False)
    p.add_argument("--pace", choices=("realtime", "max"), default="realtime",
                   help="files and recordings: play at their own frame rate like a camera "
                        "(realtime, default) or process every frame as fast as possible (max)")
    p.add_argument("--frames", type=positive_int, metavar="N",
                   help="stop after N processed frames")
    p.add_argument("--quiet", action="store_true", help="no status line every second")


def _add_serve(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default: 127.0.0.1, this machine only; any other "
                        "address turns on token access)")
    p.add_argument("--port", type=port_number, default=8080,
                   help="port to listen on (default: 8080)")
    p.add_argument("--source", metavar="SOURCE",
                   help="camera index, video file, folder of images or stream URL "
                        "(default: the built-in sample session)")
    p.add_argument("--camera", metavar="CAMERA_FILE", help="camera file")
    _add_pipeline(p, serving=True)
    p.add_argument("--data", metavar="DIR",
                   help="this server's data folder: calibration, mount, saved layouts and "
                        "study reports (default: $DROVISIO_DATA, else "
                        "~/.local/share/drovisio); never the checkout")
    p.add_argument("--replay-dir", metavar="DIR",
                   help="folder of mission recordings (drovisio mission simulate --record) to "
                        "replay in 3D on the live page (default: the sample mission)")


def _add_mission(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="mission_action", metavar="ACTION")
    fmt = argparse.RawDescriptionHelpFormatter
    scenario_help = ("scenario file (YAML/JSON), or the name of a shipped one "
                     "(wall-2-courses)")
    c = sub.add_parser(
        "check", help="validate a scenario and simulate it with injected faults",
        description="Validate the scenario, then simulate it once per injected fault (a missed "
                    "grab, vision lost during descent, a total-station dropout, a total-station/"
                    "vision disagreement, three failed drops, ...) and print a table: fault, "
                    "what the machine did, outcome, whether every safety rule held. Exit 1 if "
                    "a rule broke or an outcome was not the expected one, 2 if the scenario is "
                    "invalid.",
        epilog="Example:\n  drovisio mission check drovisio/mission/scenarios/wall-2-courses.yaml",
        formatter_class=fmt)
    c.add_argument("scenario", metavar="SCENARIO", help=scenario_help)
    c.add_argument("--fault", action="append", metavar="NAME",
                   help="run only this fault case (name prefix, e.g. 'missed grab'); repeatable")
    c.add_argument("--seed", type=seed_number, default=0, help="simulator seed (default: 0)")
    c.add_argument("--json", metavar="FILE", help="also write the table as JSON here")
    s = sub.add_parser(
        "simulate", help="simulate one mission and record it for 3D replay",
        description="Simulate the mission (kinematic drone with gusts, total station, picker, "
                    "vision from a detector model or from rendered images through the real "
                    "detectors) and record every tick (time, drone pose, setpoint, state, "
                    "events, bricks' poses) as JSON Lines with a manifest, for the live page "
                    "to replay. Prints each brick's placement error against the plan.",
        epilog="Example:\n  drovisio mission simulate wall-2-courses --record runs/wall\n"
               "  drovisio mission simulate wall-2-courses --vision render --record runs/render",
        formatter_class=fmt)
    s.add_argument("scenario", metavar="SCENARIO", help=scenario_help)
    s.add_argument("--vision", choices=("model", "render"), default="model",
                   help="detector model (fast, default) or renders through the real detectors")
    s.add_argument("--record", required=True, metavar="DIR", help="folder to write the run to")
    s.add_argument("--seed", type=seed_number, default=0, help="simulator seed (default: 0)")
    s.add_argument("--fault", action="append", metavar="NAME",
                   help="inject the faults of a fault case (see `check`); repeatable")
    s.add_argument("--bricks", type=_whole(1, 10_000), metavar="N",
                   help="build only the first N bricks")
    s.add_argument("--ss", type=supersampling, default=2,
                   help="render: samples per pixel per axis (default: 2)")
    s.add_argument("--render-rate", type=_bounded(0.0, 120.0, above=True), default=4.0,
                   metavar="HZ",
                   help="render: frames per second while vision is in use (default: 4)")
    s.add_argument("--render-bricks", metavar="IDS",
                   help="render: only while working on these bricks (comma-separated); the "
                        "others use the detector model")
    s.add_argument("--heading-bias", type=_bounded(-180.0, 180.0), metavar="DEG",
                   help="compass bias of the simulated autopilot (default: 1)")
    s.add_argument("-v", "--verbose", action="store_true", help="print events as they happen")
    g = sub.add_parser(
        "landing", help="precision landing errors for a lens, a mount and a frame rate",
        description="Simulate LAND-mode descents onto a brick with a model of ArduPilot's "
                    "precision landing (PLND_LAG buffer, initialisation only after updates at "
                    "most 0.5 s apart for 2 s, 2 s target timeout, descent on the last estimate "
                    "once the brick leaves the picture) and print the touchdown error with "
                    "this mount and with the camera straight down, and where the brick "
                    "leaves the picture.",
        epilog="Example:\n  drovisio mission landing --camera camera.yaml --mount mount.json "
               "--rate 15 --wind 3\n  drovisio mission landing --tilt 20 --rate 1.5",
        formatter_class=fmt)
    g.add_argument("--camera", metavar="CAMERA_FILE",
                   help="camera file (default: the 60° 640x480 drone webcam)")
    g.add_argument("--mount", metavar="MOUNT_FILE", help="mount file (default: --tilt)")
    g.add_argument("--tilt", type=finite_float, default=20.0, metavar="DEG",
                   help="without --mount: forward tilt, camera 8 cm ahead and 5 cm below the "
                        "body origin (default 20)")
    g.add_argument("--layout", metavar="LAYOUT.json",
                   help="the brick (default: drick-aruco-centre)")
    g.add_argument("--rate", type=positive_float, default=15.0, metavar="HZ",
                   help="frames the pipeline processes a second (default 15)")
    g.add_argument("--detect-prob", type=positive_float, default=0.95, metavar="P",
                   help="chance that a frame showing the brick detects it (default 0.95)")
    g.add_argument("--wind", type=nonnegative_float, default=3.0, metavar="M/S",
                   help="wind speed (default 3)")
    g.add_argument("--latency-ms", type=nonnegative_float, default=50.0, metavar="MS",
                   help="capture to LANDING_TARGET at the autopilot (default 50)")
    g.add_argument("--plnd-lag-ms", type=nonnegative_float, metavar="MS",
                   help="the autopilot's PLND_LAG (default: equal to the latency)")
    g.add_argument("--runs", type=positive_int, default=20, help="landings (default 20)")
    g.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    d = sub.add_parser(
        "diagram", help="print the state machine as Mermaid, Graphviz DOT or SVG",
        description="Draw the mission state machine from its transition table (the code).",
        epilog="Example:\n  drovisio mission diagram --format mermaid > machine.mmd\n"
               "  drovisio mission diagram --format svg --out machine.svg",
        formatter_class=fmt)
    d.add_argument("--format", choices=("mermaid", "dot", "svg"), default="mermaid",
                   help="output format (default: mermaid)")
    d.add_argument("--out", metavar="FILE", help="write here instead of stdout")


def _add_autopilot(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="autopilot_action", metavar="ACTION", required=True)
    c = sub.add_parser(
        "check", help="compare the flight controller's precision-landing set-up with what "
                      "Drovisio sends",
        description="Connect to the flight controller as the mavlink: sink would, read its type "
                    "and precision-landing parameters (ArduPilot PLND_*, the serial port's "
                    "protocol; PX4 LTEST_*/PLD_*), ask for the streams Drovisio needs and "
                    "measure them; with --source/--camera/--layout also measure the "
                    "capture-to-send latency (PLND_LAG) and how often the target is seen (the "
                    "landing filter needs 2 Hz). One line per item: ok, or wrong -> the value "
                    "to set and why. Exit 0 all ok, 1 something to fix, 2 bad input or no "
                    "autopilot on the connection.",
        epilog="Example:\n  drovisio autopilot check udpin:0.0.0.0:14550\n"
               "  drovisio autopilot check /dev/ttyAMA0,921600 --source 0 --camera camera.yaml "
               "\\\n      --layout marker_layouts/drick-aruco-centre.json --mount mount.json",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    c.add_argument("connection", metavar="CONNECTION",
                   help="pymavlink connection, as after mavlink: in --sink (udpin:0.0.0.0:14550, "
                        "tcp:127.0.0.1:5760, /dev/ttyAMA0,921600; ?sysid=N&compid=M)")
    c.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                   help="the LANDING_TARGET flavour Drovisio will send (as run --autopilot)")
    c.add_argument("--timeout", type=positive_float, default=5.0, metavar="SECONDS",
                   help="wait this long for the vehicle, then for its parameters (default 5)")
    c.add_argument("--source", metavar="SOURCE", help="camera or video to measure latency and "
                   "detection rate on (with --camera and --layout)")
    c.add_argument("--camera", metavar="CAMERA_FILE", help="camera file")
    c.add_argument("--layout", action="append", metavar="LAYOUT.json", help="layout; repeatable")
    c.add_argument("--mount", metavar="MOUNT_FILE",
                   help="camera mount (also gives the height at which the brick leaves the "
                        "picture)")
    c.add_argument("--target", default="nearest", metavar="TARGET", help="as run --target")
    c.add_argument("--seconds", type=positive_float, default=5.0,
                   help="how long to measure the pipeline (default 5)")
    c.add_argument("--latency-ms", type=nonnegative_float, metavar="MS",
                   help="capture-to-send latency measured elsewhere (instead of --source)")


def _add_synth(p: argparse.ArgumentParser) -> None:
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


def _add_study(p: argparse.ArgumentParser) -> None:
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
    r.add_argument("--frames", type=_whole(1, 100_000), metavar="N",
                   help="frames per step (default: the protocol's; 8 rendered, 2 quick)")
    r.add_argument("--methods", metavar="LIST",
                   help="comma-separated: drovisio-codes, drovisio-codes-image, "
                        "drovisio-dots, drovisio-dots-image, opencv, apriltag3 (default: all)")
    r.add_argument("--memory-seconds", type=_bounded(0.0, 86400.0), metavar="S",
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
    e.add_argument("--frames", type=_whole(1, 10_000), metavar="N", help="frames per step (6)")


COMMANDS: dict[str, Command] = {
    c.name: c
    for c in [
        Command(
            name="detect",
            summary="find bricks in images or videos and print their poses (JSON Lines)",
            description="Detect bricks by their ArUco codes or colour dots and estimate each "
                        "brick's pose relative to the camera (camera_from_brick: rvec, tvec in "
                        "metres). One JSON object per frame, in input order, on stdout unless "
                        "--out is given; timings and summaries go to stderr.",
            example="drovisio detect --camera camera.yaml \\\n"
                    "    --layout marker_layouts/drick-aruco-pyramids.json frames/ > poses.jsonl",
            add_arguments=_add_detect,
        ),
        Command(
            name="calibrate",
            summary="calibrate a camera from chessboard images",
            description="Calibrate the camera and its lens model (--model) from views of a "
                        "chessboard or ChArUco board. Writes the camera file and, with --report, "
                        "the RMS reprojection error, per-view errors, rejected views and corners, "
                        "and a verdict. To print a board first: drovisio calibrate board --pdf "
                        "board.pdf [--board chessboard:9x6] [--paper A4|A3|Letter].",
            example="drovisio calibrate --board chessboard:9x6 --square 0.025 \\\n"
                    "    --report report.json --out camera.yaml calib_images/",
            add_arguments=_add_calibrate,
        ),
        Command(
            name="calibrate-board",
            spelled="calibrate board",
            summary="write the calibration board to print (true-scale PDF)",
            description="Write a true-scale PDF of a calibration board to print, with a 100 mm "
                        "ruler to check the print; measure a printed square and give it to "
                        "--square when calibrating.",
            example="drovisio calibrate board --pdf board.pdf --board chessboard:9x6 --paper A4",
            add_arguments=_add_calibrate_board,
            target="drovisio.commands.calibrate:print_board",
        ),
        Command(
            name="calibrate-mount",
            spelled="calibrate mount",
            summary="measure the camera mount from pictures of the landing pad",
            description="Measure the camera mount (tilt, roll, and pan with --aligned) from "
                        "pictures of a shipped code lying flat (the landing pad is best) in "
                        "front of the drone standing level, and write the mount file.",
            example="drovisio calibrate mount --camera sample_sessions/camera.yaml --aligned "
                    "--offset 0.08 0 0.05 \\\n    --out mount.json sample_sessions/pad",
            add_arguments=_add_calibrate_mount,
            target="drovisio.commands.calibrate:measure_mount_command",
        ),
        Command(
            name="run",
            summary="run the positioning pipeline headless (on the drone)",
            description="Read frames from a source, detect bricks, estimate and track their "
                        "poses, and send the results to one or more sinks. A finite source (a "
                        "video, a folder) ends the run when it is exhausted.",
            example="drovisio run --source 0 --camera camera.yaml \\\n"
                    "    --layout marker_layouts/drick-aruco-pyramids.json --mount mount.json \\\n"
                    "    --sink jsonl:- --sink mavlink:udpout:127.0.0.1:14550",
            add_arguments=_add_run,
        ),
        Command(
            name="serve",
            summary="serve the web tool (calibration, marker designer, live view)",
            description="Serve the browser tool used in the field: camera calibration, marker "
                        "design on a brick's 3D mesh, and live detections. With no --source it "
                        "runs on the built-in sample session. The default host 127.0.0.1 is "
                        "reachable from this machine only; binding any other address (e.g. "
                        "0.0.0.0 for a tablet on the drone's Wi-Fi) turns on token access: open "
                        "the printed URL, which carries the token.",
            example="drovisio serve\n"
                    "  drovisio serve --host 0.0.0.0 --port 8080 --source 0 --camera camera.yaml\n"
                    "  drovisio serve --host 0.0.0.0 --source 0 --camera camera.yaml "
                    "--mount mount.json \\\n"
                    "      --layout marker_layouts/drick-aruco-pyramids.json "
                    "--sink mavlink:/dev/ttyAMA0,921600",
            add_arguments=_add_serve,
            target="webtool.serve:run",
        ),
        Command(
            name="bench",
            summary="benchmarks and the evaluation study",
            description="Measure detection accuracy and speed on synthetic and recorded sessions "
                        "(the evaluation study).",
            example="drovisio bench aruco --frames 50\n  drovisio bench dots --help",
            add_arguments=_add_bench,
        ),
        Command(
            name="study",
            summary="is it accurate enough for my brick? the evaluation study and its report",
            description="The thesis's evaluation (chapter 6) on renders or on your own "
                        "recordings, Drovisio beside plain OpenCV and AprilTag 3: box plots of "
                        "each pose error, frame rate against the number of bricks, memory "
                        "over a run, in one HTML report.",
            example="drovisio study run --out study/\n  drovisio study run --quick --out "
                    "study-quick/\n  drovisio study example --out my_study/",
            add_arguments=_add_study,
        ),
        Command(
            name="mission",
            summary="check and simulate a mission strategy (finite-state machine)",
            description="Check a mission scenario (take off, go to brick, align, descend, grab, "
                        "climb, go to wall, place, release) before the flight and simulate it. "
                        "Actions: check (validate, then simulate injected faults and print the "
                        "fault table), simulate (one run recorded for 3D replay), diagram (the "
                        "state machine drawn from its transition table).",
            example="drovisio mission check wall-2-courses\n"
                    "  drovisio mission simulate wall-2-courses --record runs/wall\n"
                    "  drovisio mission diagram --format mermaid",
            add_arguments=_add_mission,
        ),
        Command(
            name="autopilot",
            summary="check the flight controller's precision-landing set-up over MAVLink",
            description="Before the first flight: is the autopilot (ArduPilot or PX4) set up "
                        "for the LANDING_TARGET messages Drovisio sends?",
            example="drovisio autopilot check udpin:0.0.0.0:14550\n"
                    "  drovisio autopilot check /dev/ttyAMA0,921600 --source 0 "
                    "--camera camera.yaml \\\n"
                    "      --layout marker_layouts/drick-aruco-centre.json --mount mount.json",
            add_arguments=_add_autopilot,
        ),
        Command(
            name="synth",
            summary="generate synthetic data (sample sessions, scenes)",
            description="Generate synthetic data with drovisio's renderer. `samples` regenerates "
                        "the sample sessions shipped in sample_sessions/.",
            example="drovisio synth samples --out sample_sessions",
            add_arguments=_add_synth,
            target="drovisio.cli:_run_synth",
        ),
    ]
}


# --------------------------------------------------------------------------------------------
# Parser and dispatch
# --------------------------------------------------------------------------------------------


def plain_help(doc: str | None) -> str:
    """A docstring as a person reads it in a terminal: reST's markup (````code````,
    ``**bold**``, ``:role:`~x.y```) taken out, the words kept."""
    import re

    text = doc or ""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], text)
    text = text.replace("``", "").replace("**", "")
    return text


def _sub_commands() -> list[str]:
    """Every ``COMMAND ACTION`` of the parser (sub-parsers and benchmark names), for the
    top-level help."""
    out: list[str] = []
    for cmd in COMMANDS.values():
        if cmd.spelled:
            continue
        if cmd.name == "bench":
            from drovisio.commands.bench import BENCHMARKS

            out.append(f"bench {'|'.join(BENCHMARKS)}")
            continue
        p = build_command_parser(cmd)
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                out.append(f"{cmd.name} {'|'.join(a.choices)}")
    return out


def build_command_parser(cmd: Command) -> argparse.ArgumentParser:
    from drovisio.bounds import ArgumentParser

    p = ArgumentParser(prog=f"{PROG} {cmd.spelled or cmd.name}", add_help=False)
    cmd.add_arguments(p)
    return p


def build_parser() -> argparse.ArgumentParser:
    from drovisio.bounds import ArgumentParser

    parser = ArgumentParser(
        prog=PROG,
        description="Drovisio: local positioning for builder drones.\n"
                    "Finds bricks by their colour dots or ArUco codes and gives each brick's "
                    "6-DoF pose.",
        epilog="Sub-commands:\n  " + "\n  ".join(_sub_commands()) + "\n\n"
               "Example:\n  drovisio serve          # then open the printed URL\n"
               "Run `drovisio COMMAND --help` (e.g. `drovisio calibrate mount --help`) for a "
               "command's options and an example.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("--debug", action="store_true",
                        help="print the full traceback of an unexpected error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for cmd in COMMANDS.values():
        p = sub.add_parser(
            cmd.name,
            prog=f"{PROG} {cmd.spelled or cmd.name}",
            help=cmd.summary,
            description=cmd.description,
            epilog=f"Example:\n  {cmd.example}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        if cmd.spelled:     # listed as people type it ("calibrate board")
            sub._choices_actions[-1].metavar = cmd.spelled
        cmd.add_arguments(p)
    return parser


def resolve(entry_point: str) -> Callable[[argparse.Namespace], int | None]:
    """The function of a ``"module:function"`` entry point."""
    module_name, _, func_name = entry_point.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, func_name or "run")


def _run_synth(args: argparse.Namespace) -> int:
    from drovisio.synth_samples import main as generate

    only = getattr(args, "only", None)
    return int((generate(args.out) if only is None else generate(args.out, only)) or 0)


def _crash_report(command: str, exc: BaseException) -> str | None:
    """Write the traceback of an unexpected error to a file; its path, or None."""
    import tempfile
    import time
    import traceback

    text = "".join(traceback.format_exception(exc))
    name = f"drovisio-{command}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.txt"
    path = Path(tempfile.gettempdir()) / name
    from drovisio.fileio import atomic_write_text

    try:
        # never over an existing name: in a shared /tmp it may be another user's symlink
        atomic_write_text(path, f"drovisio {_version()} {command}\n{' '.join(sys.argv)}\n\n"
                                f"{text}", overwrite=False, mode=0o600)
    except OSError:
        return None
    return str(path)


def _say(label: str, message: str) -> None:
    from drovisio.errors import one_line

    try:
        print(f"{label}: {one_line(message, 600)}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # stderr itself is gone
        pass


def _quiet_stdout() -> None:
    """After a broken pipe, point stdout at /dev/null so the interpreter's final flush does
    not raise again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:2] == ["calibrate", "board"] and any(
            a in ("--pdf", "-h", "--help") or a.startswith("--pdf=") for a in argv[2:]):
        argv = ["calibrate-board", *argv[2:]]     # printing the board, not calibrating
    elif argv[:2] == ["calibrate", "mount"] and "--board" not in argv:
        argv = ["calibrate-mount", *argv[2:]]     # the mount, not the lens
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors: return, don't exit
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    args.argv_tail = argv[2:] if args.command == "study" else argv[1:]
    label = f"{PROG} {COMMANDS[args.command].spelled or args.command}"
    debug = args.debug or os.environ.get("DROVISIO_DEBUG", "") not in ("", "0")
    from drovisio.errors import InputError, WriteError, limit_message
    from drovisio.fileio import guard_outputs

    try:
        guard_outputs(args)
        func = resolve(COMMANDS[args.command].entry_point)
        result = func(args)
    except KeyboardInterrupt:
        return 130
    except SystemExit as exc:  # a benchmark's own parser: its usage line is said already
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_BROKEN_PIPE
    except (InputError, WriteError) as e:
        if debug:
            raise
        _say(label, str(e))
        return EXIT_BAD_INPUT
    except Exception as e:  # noqa: BLE001 - the one place that reports what nobody expected
        if debug:
            raise
        limit = limit_message(e)
        if limit is not None:  # an OS or Python limit reached by the input: bad input
            _say(label, limit)
            return EXIT_BAD_INPUT
        where = _crash_report(args.command, e)
        _say(label, f"internal error: {type(e).__name__}: {e}"
                    + (f" (full traceback in {where}; --debug prints it; please report it)"
                       if where else " (run with --debug for the traceback)"))
        return EXIT_INTERNAL
    return int(result or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
