"""``drovisio mission``: check, simulate and draw the pick-and-place strategy.

* ``check SCENARIO`` — validate the scenario, then simulate it with each injected fault of
  :data:`drovisio.mission.faults.CHECK_FAULTS` and print the fault table; exit 1 if a safety
  rule broke or an outcome was not the expected one, 2 if the scenario is invalid.
* ``simulate SCENARIO [--vision model|render] --record DIR`` — one run, recorded for replay
  (:mod:`drovisio.mission.record`); prints the placements and their errors.
* ``diagram [--format mermaid|dot|svg]`` — the machine drawn from its transition table.
* ``landing`` — ArduPilot's precision landing onto a brick for a lens, a mount, a detection
  rate and a wind (:mod:`drovisio.autopilot.precland`); ``check`` prints the same for the
  scenario's drone.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from drovisio.arguments import (
    Command,
    bounded,
    nonnegative_float,
    positive_float,
    positive_int,
    seed_number,
    supersampling,
    whole_in,
)
from drovisio.bounds import CAMERA_TILT_MAX_DEG
from drovisio.errors import InputError
from drovisio.fileio import atomic_write_text
from drovisio.mission.faults import CHECK_FAULTS, preset

__all__ = ["COMMAND", "add_arguments", "run"]

# The command's own modules (OpenCV, the pipeline and its configuration, numpy) are imported
# inside the functions that run it: `drovisio --help` imports every command module and must
# stay light.


def _err(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _resolve_scenario(arg: str) -> Path:
    p = Path(arg)
    if not p.exists() and not p.suffix:
        from drovisio.mission.scenario import shipped_scenario

        q = shipped_scenario(arg)
        if q.exists():
            return q
    return p


def _load(arg: str):
    """The scenario (a ScenarioError, an InputError, ends the command in one line)."""
    from drovisio.mission.scenario import load_scenario
    from drovisio.mission.sim import landing_blind_heights

    scn = load_scenario(_resolve_scenario(arg))
    if scn.autopilot.precision_landing:
        landing_blind_heights(scn)   # a brick the landing cannot see is refused here
    return scn


def _params(args: argparse.Namespace):
    from drovisio.mission.sim import SimParams

    p = SimParams(seed=args.seed)
    if getattr(args, "vision", "model") == "render":
        p.vision = "render"
        p.render_ss = args.ss
        p.render_rate_hz = args.render_rate
        if args.render_bricks:
            p.render_bricks = tuple(b.strip() for b in args.render_bricks.split(",") if b.strip())
    if getattr(args, "heading_bias", None) is not None:
        p.heading_bias_deg = args.heading_bias
    return p


def _check(args: argparse.Namespace) -> int:
    from drovisio.mission.check import format_table, run_fault_table

    scn = _load(args.scenario)
    cases = CHECK_FAULTS
    if args.fault:
        try:
            cases = tuple(preset(f) for f in args.fault)
        except KeyError as e:
            _err(f"drovisio mission check: {e.args[0]}")
            return 2
    _err(f"scenario {scn.name!r} is valid ({len(scn.order)} bricks); simulating "
         f"{len(cases)} fault case(s), seed {args.seed}")
    t0 = time.perf_counter()
    results = run_fault_table(scn, cases, _params(args), progress=_err)
    print(format_table(results))
    bad = [r for r in results if not r.all_held or not r.as_expected]
    _print_failures(results)
    if args.json:
        _write_table(args.json, results)
    _print_landings(scn, results, args.seed)
    _err(f"{len(results)} case(s) in {time.perf_counter() - t0:.1f} s: "
         + ("every safety rule held, every outcome as expected" if not bad else
            f"{len(bad)} case(s) FAILED"))
    return 1 if bad else 0


def _print_failures(results: list) -> None:
    """Every broken rule and every outcome that was not the expected one."""
    for r in results:
        for x in r.rules:
            if not x.held:
                print(f"  rule {x.rule} broken in '{r.case.name}': {x.detail}")
        if not r.as_expected:
            print(f"  '{r.case.name}': expected {r.case.expect}, got {r.outcome}")


def _write_table(path: str, results: list) -> None:
    """The fault table as JSON (``--json``)."""
    atomic_write_text(path, json.dumps([{
        "fault": r.case.name, "did": r.narrative, "outcome": r.outcome,
        "expected": r.case.expect,
        "rules": {x.rule: {"held": x.held, "detail": x.detail} for x in r.rules},
        "placements": r.trace.placements, "landings": r.trace.landings}
        for r in results], indent=1))


def _print_landings(scn, results: list, seed: int) -> None:
    """The landings of the run without faults, then the precision-landing model's."""
    from drovisio.mission.check import landing_lines

    clean = next((r for r in results if not r.case.faults), None)
    if clean is not None and clean.trace.landings:
        print(f"landings of the '{clean.case.name}' run"
              + (" (ArduPilot precision landing, "
                 f"latency {scn.autopilot.latency_ms:g} ms, wind {scn.autopilot.wind_mps:g} m/s)"
                 if scn.autopilot.precision_landing else "") + ":")
        for line in landing_lines(clean.trace):
            print("  " + line)
    for line in _landing_lines(scn, seed):
        print(line)


def _landing_lines(scn, seed: int, runs: int = 10) -> list[str]:
    """The scenario's drone landing on its first brick type with ArduPilot's precision
    landing (:mod:`drovisio.autopilot.precland`)."""
    from drovisio.autopilot.precland import LandingParams, landing_report
    from drovisio.mission.sim import body_from_camera_for, camera_for
    from drovisio.mission.vision import DetectorModelParams
    from drovisio.mount import Mount

    layout = scn.layout(scn.layouts[0])
    ap = scn.autopilot
    d = DetectorModelParams()
    params = LandingParams(rate_hz=ap.rate_hz if ap.rate_hz is not None else d.rate_hz,
                           detect_prob=ap.detect_prob if ap.detect_prob is not None
                           else LandingParams().detect_prob,
                           latency_s=ap.latency_ms / 1e3,
                           plnd_lag_s=None if ap.plnd_lag_ms is None else ap.plnd_lag_ms / 1e3,
                           wind_mps=ap.wind_mps if ap.precision_landing else 3.0, seed=seed)
    return landing_report(camera_for(scn), Mount(body_from_camera_for(scn)), layout, params,
                          runs)


def _landing(args: argparse.Namespace) -> int:
    from drovisio.autopilot.precland import LandingParams, landing_report
    from drovisio.camera import Camera
    from drovisio.camera_file import load_camera
    from drovisio.layout import load_layout, shipped_layouts_dir
    from drovisio.mount import Mount, load_mount

    camera = load_camera(args.camera) if args.camera else Camera.drone_webcam()
    if not camera.size_known:
        raise InputError(f"{args.camera}: image_width/image_height: the landing model needs "
                         "the image size; add it to the camera file")
    if args.mount:
        mount = load_mount(args.mount)
    else:
        mount = Mount.from_angles(args.tilt, offset_m=(0.08, 0.0, 0.05))
    layout = load_layout(args.layout or shipped_layouts_dir() / "drick-aruco-centre.json")
    p = LandingParams(rate_hz=args.rate, wind_mps=args.wind, latency_s=args.latency_ms / 1e3,
                      plnd_lag_s=None if args.plnd_lag_ms is None else args.plnd_lag_ms / 1e3,
                      detect_prob=args.detect_prob, seed=args.seed)
    for line in landing_report(camera, mount, layout, p, args.runs):
        print(line)
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from drovisio.mission.check import check_rules, narrate
    from drovisio.mission.record import write_recording
    from drovisio.mission.sim import simulate

    scn = _load(args.scenario)
    faults: tuple = ()
    if args.fault:
        try:
            faults = tuple(f for name in args.fault
                           for f in preset(name).for_order(scn.order).faults)
        except KeyError as e:
            _err(f"drovisio mission simulate: {e.args[0]}")
            return 2
    params = _params(args)
    if args.bricks:
        scn = scn.subset(scn.order[:args.bricks])
    _err(f"simulating {scn.name!r} ({len(scn.order)} bricks), vision {params.vision}, "
         f"seed {params.seed}")
    t0 = time.perf_counter()
    tr = simulate(scn, faults, params, progress=_err if args.verbose else None)
    wall = time.perf_counter() - t0
    rules = check_rules(tr)
    out = write_recording(tr, args.record, extra={"wall_time_s": round(wall, 1),
                                                  "rules": {r.rule: r.held for r in rules},
                                                  "landings": tr.landings})
    print(f"outcome: {tr.final_state} after {tr.ticks[-1].t:.1f} s simulated "
          f"({wall:.1f} s wall); vision: {tr.detector}"
          + (f"; {tr.render_frames} rendered frames (render + detect "
             f"{tr.render_seconds:.0f} s), {tr.vision_frames - tr.render_frames} model frames"
             if params.vision == "render" else ""))
    print(f"what the machine did: {narrate(tr)}")
    from drovisio.mission.check import landing_lines

    for line in landing_lines(tr):
        print(line)
    if tr.placements:
        _print_placements(tr, scn)
    for r in rules:
        print(f"rule {r.rule}: {'held' if r.held else 'BROKEN'} ({r.detail})")
    print(f"recorded {out / 'manifest.json'}")
    return 0 if all(r.held for r in rules) else 1


def _print_placements(tr, scn) -> None:
    """Each brick's placement error against the plan, and their worst and 95th percentile."""
    import numpy as np

    print(f"{'brick':6} {'error':>8} {'along':>8} {'yaw':>7}  verified")
    for b, p in tr.placements.items():
        print(f"{b:6} {p['error_m'] * 100:6.2f}cm {p['error_along_m'] * 100:6.2f}cm "
              f"{p['yaw_error_deg']:6.2f}°  {p['verified']}")
    pos, yaw = tr.placement_errors()
    print(f"placement error: max {pos.max() * 100:.2f} cm, p95 "
          f"{np.percentile(pos, 95) * 100:.2f} cm; yaw max {yaw.max():.2f}°, p95 "
          f"{np.percentile(yaw, 95):.2f}° (tolerance "
          f"{scn.placement_tolerance.position_m * 100:.0f} cm, "
          f"{scn.placement_tolerance.yaw_deg:g}°)")


def _diagram(args: argparse.Namespace) -> int:
    from drovisio.mission import diagram

    text = {"mermaid": diagram.mermaid, "dot": diagram.dot, "svg": diagram.svg}[args.format]()
    if args.out:
        atomic_write_text(args.out, text)
        _err(f"wrote {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def run(args: argparse.Namespace) -> int:
    action = getattr(args, "mission_action", None)
    if action == "check":
        return _check(args)
    if action == "simulate":
        return _simulate(args)
    if action == "diagram":
        return _diagram(args)
    if action == "landing":
        return _landing(args)
    _err("drovisio mission: give an action: check, simulate, landing or diagram (see --help)")
    return 2


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


_SCENARIO_HELP = ("scenario file (YAML/JSON), or the name of a shipped one "
                  "(wall-2-courses)")
_FMT = argparse.RawDescriptionHelpFormatter


def _add_check(sub: argparse._SubParsersAction) -> None:
    """``mission check``: validate, then the fault table."""
    c = sub.add_parser(
        "check", help="validate a scenario and simulate it with injected faults",
        description="Validate the scenario, then simulate it once per injected fault (a missed "
                    "grab, vision lost during descent, a total-station dropout, a total-station/"
                    "vision disagreement, three failed drops, ...) and print a table: fault, "
                    "what the machine did, outcome, whether every safety rule held. Exit 1 if "
                    "a rule broke or an outcome was not the expected one, 2 if the scenario is "
                    "invalid.",
        epilog="Example:\n  drovisio mission check drovisio/mission/scenarios/wall-2-courses.yaml",
        formatter_class=_FMT)
    c.add_argument("scenario", metavar="SCENARIO", help=_SCENARIO_HELP)
    c.add_argument("--fault", action="append", metavar="NAME",
                   help="run only this fault case (name prefix, e.g. 'missed grab'); repeatable")
    c.add_argument("--seed", type=seed_number, default=0, help="simulator seed (default: 0)")
    c.add_argument("--json", metavar="FILE", help="also write the table as JSON here")


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    """``mission simulate``: one run recorded for replay."""
    s = sub.add_parser(
        "simulate", help="simulate one mission and record it for 3D replay",
        description="Simulate the mission (kinematic drone with gusts, total station, picker, "
                    "vision from a detector model or from rendered images through the real "
                    "detectors) and record every tick (time, drone pose, setpoint, state, "
                    "events, bricks' poses) as JSON Lines with a manifest, for the live page "
                    "to replay. Prints each brick's placement error against the plan.",
        epilog="Example:\n  drovisio mission simulate wall-2-courses --record runs/wall\n"
               "  drovisio mission simulate wall-2-courses --vision render --record runs/render",
        formatter_class=_FMT)
    s.add_argument("scenario", metavar="SCENARIO", help=_SCENARIO_HELP)
    s.add_argument("--vision", choices=("model", "render"), default="model",
                   help="detector model (fast, default) or renders through the real detectors")
    s.add_argument("--record", required=True, metavar="DIR", help="folder to write the run to")
    s.add_argument("--seed", type=seed_number, default=0, help="simulator seed (default: 0)")
    s.add_argument("--fault", action="append", metavar="NAME",
                   help="inject the faults of a fault case (see `check`); repeatable")
    s.add_argument("--bricks", type=whole_in(1, 10_000), metavar="N",
                   help="build only the first N bricks")
    s.add_argument("--ss", type=supersampling, default=2,
                   help="render: samples per pixel per axis (default: 2)")
    s.add_argument("--render-rate", type=bounded(0.0, 120.0, above=True), default=4.0,
                   metavar="HZ",
                   help="render: frames per second while vision is in use (default: 4)")
    s.add_argument("--render-bricks", metavar="IDS",
                   help="render: only while working on these bricks (comma-separated); the "
                        "others use the detector model")
    s.add_argument("--heading-bias", type=bounded(-180.0, 180.0), metavar="DEG",
                   help="compass bias of the simulated autopilot (default: 1)")
    s.add_argument("-v", "--verbose", action="store_true", help="print events as they happen")


def _add_landing(sub: argparse._SubParsersAction) -> None:
    """``mission landing``: precision landing errors."""
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
        formatter_class=_FMT)
    g.add_argument("--camera", metavar="CAMERA_FILE",
                   help="camera file (default: the 60° 640x480 drone webcam)")
    g.add_argument("--mount", metavar="MOUNT_FILE", help="mount file (default: --tilt)")
    g.add_argument("--tilt", type=bounded(-CAMERA_TILT_MAX_DEG, CAMERA_TILT_MAX_DEG),
                   default=20.0, metavar="DEG",
                   help="without --mount: forward tilt from straight down, -90 to 90 degrees, "
                        "camera 8 cm ahead and 5 cm below the body origin (default 20)")
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


def _add_diagram(sub: argparse._SubParsersAction) -> None:
    """``mission diagram``: the machine drawn from its table."""
    d = sub.add_parser(
        "diagram", help="print the state machine as Mermaid, Graphviz DOT or SVG",
        description="Draw the mission state machine from its transition table (the code).",
        epilog="Example:\n  drovisio mission diagram --format mermaid > machine.mmd\n"
               "  drovisio mission diagram --format svg --out machine.svg",
        formatter_class=_FMT)
    d.add_argument("--format", choices=("mermaid", "dot", "svg"), default="mermaid",
                   help="output format (default: mermaid)")
    d.add_argument("--out", metavar="FILE", help="write here instead of stdout")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio mission check|simulate|landing|diagram``."""
    sub = p.add_subparsers(dest="mission_action", metavar="ACTION")
    _add_check(sub)
    _add_simulate(sub)
    _add_landing(sub)
    _add_diagram(sub)


COMMAND = Command(
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
    add_arguments=add_arguments,
)
