"""``drovisio run``: the positioning pipeline, headless (on the drone).

Reads frames from --source, detects the bricks of the --layout files, fuses and tracks them,
and sends one JSON object per frame / one LANDING_TARGET per frame to each --sink. Prints a
status line per second on stderr (fps, detection time, latency capture → sent, bricks,
source state, target). A finite source ends the run when it is exhausted; Ctrl+C or SIGTERM
ends it cleanly (sinks closed, recording flushed).
"""

from __future__ import annotations

import argparse
import signal
import sys
import time

__all__ = ["build_pipeline", "run", "status_line"]


def _err(msg: str) -> None:
    print(f"drovisio run: {msg}", file=sys.stderr, flush=True)


def status_line(st: dict, elapsed: float) -> str:
    src = st["source"]
    state = src["state"] + (f" ({src['error']})" if src["state"] == "lost" and src["error"]
                            else "")
    tb = st.get("target_brick")
    if tb:
        name = tb["layout"] + (f":{tb['instance']}" if tb["instance"] is not None
                               else f" track {tb['track']}")
        target = f"target {name} at {tb['distance']:.2f} m"
    else:
        target = f"target ({st['target']['spec']}) none"
    extra = f" | {st['detector_errors']} detector errors" if st["detector_errors"] else ""
    return (f"{elapsed:7.1f} s | {st['fps']:5.1f} fps | detect {st['detect_ms']:6.1f} ms | "
            f"latency {st['latency_ms']:6.1f} ms | {st['bricks']} bricks | source {state} | "
            f"{target}{extra}")


def build_pipeline(args: argparse.Namespace, out=None):
    """The pipeline a ``drovisio run`` namespace describes (also used by the benchmark)."""
    from drovisio.camera import load_camera
    from drovisio.layout import load_layouts
    from drovisio.mount import load_mount
    from drovisio.pipeline import Pipeline, detectors_for
    from drovisio.recording import Recorder
    from drovisio.sinks import open_sink
    from drovisio.sinks.mavlink import MavlinkSink
    from drovisio.sinks.target import TargetSelector
    from drovisio.sources import FrameSource, reader_for

    camera = load_camera(args.camera)
    layouts = load_layouts(args.layout)
    mount = load_mount(args.mount) if getattr(args, "mount", None) else None
    target = TargetSelector(getattr(args, "target", None) or "nearest")
    sinks = []
    try:
        for spec in (args.sink or ["jsonl:-"]):
            sinks.append(open_sink(spec, target=target,
                                   autopilot=getattr(args, "autopilot", "ardupilot"),
                                   mount=mount, layouts=layouts))
    except Exception:
        for s in sinks:
            s.close()
        raise
    mav = next((s for s in sinks if isinstance(s, MavlinkSink)), None)

    def attitude_gravity(t_mono: float):
        """Gravity in the camera frame: the autopilot's roll/pitch if the link gives them,
        else level flight."""
        if mav is not None:
            att = mav.attitude_at(t_mono)
            if att is not None:
                return mount.gravity_in_camera(att[0], att[1])
        return level

    level = mount.gravity_in_camera() if mount is not None else None
    gravity = attitude_gravity if mount is not None else None

    source = FrameSource(reader_for(args.source), pace=getattr(args, "pace", "realtime"))
    recorder = None
    if getattr(args, "record", None):
        recorder = Recorder(args.record, source=args.source, camera_file=args.camera,
                            mount_file=getattr(args, "mount", None))
    pipeline = Pipeline(source, detectors_for(camera, layouts), sinks=sinks, mount=mount,
                        target=target, gravity=gravity, recorder=recorder,
                        max_age=getattr(args, "max_age", 0.5), layouts=layouts)
    pipeline.camera = camera
    pipeline.warm_up(camera.width, camera.height)
    return pipeline


def run(args: argparse.Namespace) -> int:
    from drovisio.camera import CameraFileError
    from drovisio.layout import LayoutError
    from drovisio.mount import MountError
    from drovisio.sinks.base import SinkError

    try:
        pipeline = build_pipeline(args)
    except (CameraFileError, LayoutError, MountError, SinkError, OSError, ValueError) as e:
        _err(str(e))
        return 2
    if not pipeline.detectors:
        _err("the layouts have neither codes nor dots: nothing to detect")
        pipeline.close()
        return 2

    def _terminate(signum, _frame) -> None:
        pipeline.stop()

    old = signal.signal(signal.SIGTERM, _terminate) if hasattr(signal, "SIGTERM") else None
    t0 = time.monotonic()
    quiet = getattr(args, "quiet", False)

    def on_status(st: dict) -> None:
        if not quiet:
            print(status_line(st, time.monotonic() - t0), file=sys.stderr, flush=True)

    names = ", ".join(d.name for d in pipeline.detectors)
    _err(f"source {args.source}; detectors {names}; sinks "
         f"{', '.join(s.name for s in pipeline.sinks)}; target {pipeline.target.spec}"
         + ("" if pipeline.mount is not None else "; no --mount: poses in the camera frame "
            "only (MAVLink assumes a camera looking straight down)"))
    n = 0
    try:
        n = pipeline.run(max_frames=getattr(args, "frames", None), on_status=on_status)
    except KeyboardInterrupt:
        pass
    finally:
        st = pipeline.status()
        pipeline.close()
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    if not quiet:
        print(status_line(st, time.monotonic() - t0), file=sys.stderr, flush=True)
    _err(f"done: {n} frames, source {st['source']['state']}, "
         f"{st['source']['dropped']} frames dropped (newest-frame policy)")
    return 0
