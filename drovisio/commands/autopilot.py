"""``drovisio autopilot check CONNECTION``: is the flight controller set up for Drovisio?

Reads the autopilot's type and its precision-landing parameters over MAVLink, asks for the
streams the sink needs and measures them, and (with ``--source``, ``--camera``, ``--layout``)
measures Drovisio's capture-to-send latency and how often it sees the target on the current
scene; prints one line per item, ``ok`` / ``wrong`` → the value to set and why.

Exit status: 0 all ok; 1 something to set or to watch; 2 bad input, or no autopilot answered
on the connection within ``--timeout`` (the connection named leads nowhere).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

from drovisio.arguments import Command, nonnegative_float, positive_float
from drovisio.autopilot.check import evaluate, plnd_lag_for, verdict
from drovisio.autopilot.session import read_vehicle
from drovisio.errors import InputError

__all__ = ["COMMAND", "add_arguments", "measure_pipeline", "run"]

# The command's own modules (OpenCV, the pipeline and its configuration, numpy) are imported
# inside the functions that run it: `drovisio --help` imports every command module and must
# stay light.


#: Seconds the pipeline may take to give its first frame before the measuring gives up.
START_S = 60.0


def measure_pipeline(args: argparse.Namespace, seconds: float) -> tuple[float | None, float]:
    """Run the pipeline (no sinks) for ``seconds`` from its first frame out: (median
    capture-to-send latency in s, target measurements per second).

    The start-up (opening the source, loading the detectors' kernels) is not what the
    autopilot will see, and on a busy machine it could fill the whole window: the window opens
    with the first frame, which may take up to :data:`START_S` seconds."""
    from drovisio.pipeline_config import PipelineConfig
    from drovisio.startup import build_pipeline

    config = PipelineConfig(source=args.source, camera=args.camera, layouts=args.layout or [],
                            mount=args.mount, target=args.target, autopilot=args.autopilot)
    pipeline = build_pipeline(config, default_sinks=())
    measured: list[float] = []
    latency: list[float] = []
    window = threading.Timer(seconds, pipeline.stop)
    opened: list[float] = []      # when the window opened (monotonic)

    class _Probe:
        name = "probe"

        def send(self, out) -> None:
            if not opened:
                opened.append(time.monotonic())
                window.start()
            t = out.target
            if t is not None and t.measured:
                measured.append(out.t_mono)
                latency.append(time.monotonic() - out.t_mono)

        def close(self) -> None:
            pass

        def status(self) -> dict:
            return {"sink": "probe", "errors": 0}

    pipeline.sinks.append(_Probe())
    start_up = threading.Timer(START_S + seconds, pipeline.stop)
    t0 = time.monotonic()
    start_up.start()
    try:
        pipeline.run()
    finally:
        window.cancel()
        start_up.cancel()
        pipeline.close()
    lat = sorted(latency)[len(latency) // 2] if latency else None
    # between the first and the last measurement: the first frames are not the rate the
    # autopilot will see either
    if len(measured) >= 2 and measured[-1] > measured[0]:
        return lat, (len(measured) - 1) / (measured[-1] - measured[0])
    return lat, len(measured) / max(time.monotonic() - (opened[0] if opened else t0), 1e-6)


def _blind(args: argparse.Namespace) -> tuple[float | None, list[str]]:
    if not (args.mount and args.camera and args.layout):
        return None, []
    from drovisio.autopilot.blind import blind_height, blind_heights_text
    from drovisio.camera_file import load_camera
    from drovisio.layout import load_layouts
    from drovisio.mount import load_mount

    cam = load_camera(args.camera)
    if not cam.size_known:
        return None, []
    mount = load_mount(args.mount)
    worst, lines = None, []
    for lay in load_layouts(args.layout):
        b = blind_height(cam, mount, lay)
        lines.append(blind_heights_text(cam, mount, lay))
        if b.leaves_at_m is not None:
            worst = b.leaves_at_m if worst is None else max(worst, b.leaves_at_m)
    return worst, lines


def run(args: argparse.Namespace) -> int:
    if args.autopilot_action != "check":
        raise InputError("expected an action: check")
    if (args.source is None) != (args.camera is None) or (args.source and not args.layout):
        raise InputError("--source, --camera and --layout go together (to measure the latency "
                         "and the detection rate on the current scene)")
    blind, blind_lines = _blind(args)
    latency, rate = (None, None)
    if args.source:
        latency, rate = measure_pipeline(args, args.seconds)
    if args.latency_ms is not None:
        latency = args.latency_ms / 1e3
    facts = read_vehicle(args.connection, args.autopilot, timeout_s=args.timeout)
    facts.latency_s = latency
    facts.detection_hz = rate
    facts.blind_height_m = blind
    findings = evaluate(facts)
    for f in findings:
        print(f.line())
    for line in blind_lines:
        print(f"note    {line}")
    if latency is not None:
        print(f"note    set PLND_LAG = {plnd_lag_for(latency):.2f} (ArduPilot) for the measured "
              f"{latency * 1e3:.0f} ms capture-to-send latency")
    code = verdict(findings)
    print(("all ok" if code == 0 else
           f"{sum(f.status in ('wrong', 'warn') for f in findings)} item(s) to fix or watch"),
          file=sys.stderr)
    return code


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio autopilot check``."""
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
                   help="how long to measure the pipeline, from its first frame (default 5)")
    c.add_argument("--latency-ms", type=nonnegative_float, metavar="MS",
                   help="capture-to-send latency measured elsewhere (instead of --source)")


COMMAND = Command(
    name="autopilot",
    summary="check the flight controller's precision-landing set-up over MAVLink",
    description="Before the first flight: is the autopilot (ArduPilot or PX4) set up "
                "for the LANDING_TARGET messages Drovisio sends?",
    example="drovisio autopilot check udpin:0.0.0.0:14550\n"
            "  drovisio autopilot check /dev/ttyAMA0,921600 --source 0 "
            "--camera camera.yaml \\\n"
            "      --layout marker_layouts/drick-aruco-centre.json --mount mount.json",
    add_arguments=add_arguments,
)
