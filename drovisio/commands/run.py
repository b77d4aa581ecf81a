"""``drovisio run``: the positioning pipeline, headless (on the drone).

Reads frames from --source, detects the bricks of the --layout files, fuses and tracks them,
and sends one JSON object per frame / one LANDING_TARGET per frame to each --sink. Prints a
status line per second on stderr (fps, detection time, latency capture → sent, bricks,
source state, target, sink failures). Ctrl+C or SIGTERM ends it cleanly (sinks closed,
recording flushed).

Finite means finite: a file, folder or recording that cannot be opened (or fails while
read) ends the run at once with one line and exit status 2; one that ends ends the run, with
exit status 1 when nothing could be read from it (no frame, or none that decoded). Cameras and stream URLs keep reconnecting
(said on a line when lost, even with --quiet; the status line says so too). Frames of
another size than the camera file's are not measured: said on a line at the first, and the
exit status is 2. A sink that fails (a full disk, a closed pipe, an unreachable link, a link
whose peer went away) is counted (never as sent), said on a line when it starts failing and
when it works again (even with --quiet), shown in the status line, and makes the exit status
1 at the end, which says how many messages each sink did not send. A --record recording that
could not write some frames is said the same way at the end (exit status 1), and so are frames
a slow disk made it drop; one that got no frame is removed at the end, said on a line (the next
run may record there again).
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, NamedTuple

from drovisio.arguments import Command, bounded, drone_id, positive_int
from drovisio.errors import InputError

if TYPE_CHECKING:   # the pipeline loads OpenCV, which `drovisio --help` must not
    from drovisio.pipeline import Pipeline
    from drovisio.pipeline_config import PipelineConfig
    from drovisio.pipeline_status import PipelineStatus
    from drovisio.sources import SourceStatus

__all__ = ["COMMAND", "Alarms", "SinkFailure", "add_arguments", "add_pipeline_arguments",
           "build_pipeline", "new_notes", "run", "sink_failures", "status_line"]

# The command's own modules (OpenCV, the pipeline and its configuration, numpy) are imported
# inside the functions that run it: `drovisio --help` imports every command module and must
# stay light.


def _err(msg: str) -> None:
    try:
        print(f"drovisio run: {msg}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _sinks_of(st: PipelineStatus | Mapping[str, Any]) -> list[dict[str, Any]]:
    """Each sink's own status, from the snapshot or its JSON form."""
    return list(st.get("sinks", [])) if isinstance(st, Mapping) else st.sinks


class SinkFailure(NamedTuple):
    """What a sink did not deliver (its status's ``errors`` and ``lost``)."""

    sink: str
    errors: int
    """Writes that failed."""
    lost: int
    """Messages dropped while its link was down (nothing written)."""
    sent: int
    last_error: str | None


def sink_failures(st: PipelineStatus | Mapping[str, Any]) -> list[SinkFailure]:
    """Every sink that failed to deliver at least once."""
    out = []
    for s in _sinks_of(st):
        f = SinkFailure(s.get("sink", "?"), int(s.get("errors") or 0), int(s.get("lost") or 0),
                        int(s.get("sent") or 0), s.get("last_error"))
        if f.errors or f.lost:
            out.append(f)
    return out


def _source_words(src: SourceStatus) -> str:
    state = src.state + (f" ({src.error})" if src.state in ("lost", "failed")
                         and src.error else "")
    if src.frame_errors:
        state += f", {src.frame_errors} undecodable frames"
    return state


def _target_words(st: PipelineStatus) -> str:
    tb = st.target_brick
    if tb is None:
        return f"target ({st.target}) none"
    name = tb.layout + (f":{tb.instance}" if tb.instance is not None else f" track {tb.track}")
    return f"target {name} at {tb.distance_m:.2f} m"


def _trouble_words(st: PipelineStatus) -> str:
    extra = f" | {st.detector_errors} detector errors" if st.detector_errors else ""
    if st.unfit_frames:
        extra += f" | {st.unfit_frames} frames not measured ({st.unfit})"
    for f in sink_failures(st):
        if f.errors:
            extra += f" | sink {f.sink}: {f.errors} failed" + (f" ({f.last_error})"
                                                               if f.last_error else "")
        if f.lost:
            extra += f" | sink {f.sink}: {f.lost} not sent (link down)"
    if st.sink_errors:
        extra += f" | {st.sink_errors} sink exceptions"
    if st.duplicates:
        extra += (" | id read on several codes, not tracked (give each brick its own ids): "
                  + ", ".join(sorted(st.duplicates)))
    return extra


def status_line(st: PipelineStatus, elapsed: float) -> str:
    """The status line printed every second (``elapsed``: seconds since the start)."""
    return (f"{elapsed:7.1f} s | {st.fps:5.1f} fps | detect {st.detect_ms:6.1f} ms | "
            f"latency {st.latency_ms:6.1f} ms | {st.bricks} bricks"
            + (f" ({st.held} held over, not sent)" if st.held else "")
            + f" | source {_source_words(st.source)} | "
            f"{_target_words(st)}{_trouble_words(st)}")


def new_notes(st: PipelineStatus | Mapping[str, Any], said: set[str]) -> str:
    """The sinks' notes not yet said (each is said once: the MAVLink link's missing
    streams), as `` | sink: note`` for the status line."""
    out = ""
    for s in _sinks_of(st):
        note = s.get("note")
        if note and note not in said:
            said.add(note)
            out += f" | {s.get('sink', '?')}: {note}"
    return out


def build_pipeline(args: argparse.Namespace | PipelineConfig, loop: bool = False,
                   default_sinks: tuple[str, ...] = ("jsonl:-",)) -> Pipeline:
    """The pipeline a ``drovisio run`` command line (or its configuration) describes: see
    :func:`drovisio.startup.build_pipeline`."""
    # deferred: the pipeline loads OpenCV and the detectors, which `drovisio --help` must not
    from drovisio.pipeline_config import PipelineConfig
    from drovisio.startup import build_pipeline as build

    config = args if isinstance(args, PipelineConfig) else PipelineConfig.from_args(args)
    return build(config, loop=loop, default_sinks=default_sinks)


def _started(config: PipelineConfig) -> Pipeline:
    """The pipeline, or one line saying why not (exit 2)."""
    from drovisio.sinks.base import SinkError  # deferred with build_pipeline's imports

    try:
        return build_pipeline(config)
    except SinkError as e:
        raise InputError(str(e)) from None
    except OSError as e:   # a recording folder that cannot be made
        raise InputError(f"--record: {e}") from None


def _say_start(config: PipelineConfig, pipeline: Pipeline) -> None:
    names = ", ".join(d.name for d in pipeline.detectors) or "chosen at the first frame"
    _err(f"source {config.source}; detectors {names}; sinks "
         f"{', '.join(s.name for s in pipeline.sinks)}; target {pipeline.target.spec}"
         + ("" if pipeline.mount is not None else "; no --mount: poses in the camera frame "
            "only (MAVLink assumes a camera looking straight down)"))


def _unfit_line(camera: object, why: object) -> str:
    """Frames that do not fit the camera file, and what to do."""
    return (f"{camera}: frames not measured: {why}; give the camera file of this camera at "
            "this resolution")


class Alarms:
    """Failures said on a line of their own as they happen, ``--quiet`` or not (quiet hides
    the status line, the progress, never a failure): a source lost (once each time it is
    lost: it is being retried), frames that do not fit the camera file (the first), a sink
    that stops delivering (once each time, and once when it delivers again)."""

    def __init__(self, camera: object) -> None:
        self.camera = camera
        self._lost = False
        self._unfit = False
        # per sink: its messages not delivered at the last status, and at the loss said
        self._sinks: dict[str, tuple[int, int | None]] = {}

    def new(self, st: PipelineStatus) -> list[str]:
        """The lines to say for this status (none when nothing new went wrong)."""
        out = []
        src = st.source
        if src.state == "lost" and not self._lost:
            self._lost = True
            out.append(f"source {src.label} lost ({src.error or 'no frame'}); retrying until "
                       "it comes back")
        elif src.state == "live":
            self._lost = False
        if st.unfit_frames and not self._unfit:
            self._unfit = True
            out.append(_unfit_line(self.camera, st.unfit))
        for s in _sinks_of(st):
            out += self._sink(s)
        return out

    def _sink(self, s: Mapping[str, Any]) -> list[str]:
        """A sink's loss (its ``down`` or more messages not delivered), and its return."""
        name = str(s.get("sink", "?"))
        failed = int(s.get("errors") or 0) + int(s.get("lost") or 0)
        down = s.get("down")
        before, since = self._sinks.get(name, (0, None))
        out = []
        if since is None and (down or failed > before):
            since = before
            why = str(down or s.get("last_error") or "messages not delivered")
            out.append(f"sink {name} lost ({why.removeprefix(name + ': ')}); its messages are "
                       "not sent until it comes back")
        if since is not None and not down:
            out.append(f"sink {name} back ({failed - since} messages not sent meanwhile)")
            since = None
        self._sinks[name] = (failed, since)
        return out


def _run_until_done(pipeline: Pipeline, max_frames: int | None, quiet: bool, t0: float,
                    alarms: Alarms) -> tuple[int, PipelineStatus]:
    """Run until the source ends, ``max_frames``, Ctrl+C or SIGTERM; (frames processed, the
    last status). The pipeline is closed after."""
    def _terminate(signum, _frame) -> None:
        pipeline.stop()

    old = signal.signal(signal.SIGTERM, _terminate) if hasattr(signal, "SIGTERM") else None
    said: set[str] = set()

    def on_status(st: PipelineStatus) -> None:
        for line in alarms.new(st):
            _err(line)
        if not quiet:
            print(status_line(st, time.monotonic() - t0) + new_notes(st, said), file=sys.stderr,
                  flush=True)

    n = 0
    try:
        n = pipeline.run(max_frames=max_frames, on_status=on_status)
    except KeyboardInterrupt:
        pass
    finally:
        st = pipeline.snapshot()
        pipeline.close()
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    return n, st


def _exit_code(config: PipelineConfig, n: int, st: PipelineStatus) -> int:
    """Say how the run ended: 2 when frames did not fit the camera file, 1 when nothing
    could be read or a sink failed, else 0.

    Raises:
        InputError: the source failed (exit 2).
    """
    src = st.source
    if src.state == "failed":
        raise InputError(f"{config.source}: --source: {src.error}")
    _err(f"done: {n} frames, source {src.state}, {src.dropped} frames dropped "
         "(newest-frame policy)"
         + (f", {src.frame_errors} frames could not be decoded" if src.frame_errors else ""))
    code = 0
    if src.finite and src.frames == src.frame_errors:   # none, or none that decoded
        _err(f"{config.source}: nothing could be read from the source"
             + (" (no frame of it decoded)" if src.frames else ""))
        code = 1
    failures = sink_failures(st)
    for f in failures:
        if f.errors:
            _err(f"sink {f.sink}: {f.errors} sends failed" + (f" (last: {f.last_error})"
                                                              if f.last_error else ""))
        if f.lost:
            _err(f"sink {f.sink}: {f.lost} messages not sent while its link was down "
                 f"({f.sent} sent)")
    if failures or st.sink_errors:
        code = 1
    if st.unfit_frames:   # the camera file is not this source's: bad input
        _err(_unfit_line(config.camera, f"{st.unfit_frames} of {n}, {st.unfit}"))
        code = 2
    return code


def run(args: argparse.Namespace) -> int:
    """``drovisio run`` (see the module doc): its exit status."""
    from drovisio.pipeline_config import PipelineConfig

    config = PipelineConfig.from_args(args)
    pipeline = _started(config)
    t0 = time.monotonic()
    quiet = getattr(args, "quiet", False)
    _say_start(config, pipeline)
    n, st = _run_until_done(pipeline, getattr(args, "frames", None), quiet, t0,
                            Alarms(config.camera))
    if not quiet:
        print(status_line(st, time.monotonic() - t0), file=sys.stderr, flush=True)
    for note in pipeline.notes:
        _err(f"{config.camera}: {note}")
    recording_failed = _say_recording(pipeline)
    return max(_exit_code(config, n, st), 1 if recording_failed else 0)


def _say_recording(pipeline: Pipeline) -> bool:
    """Say how the recording (closed with the pipeline) ended where it did not record every
    frame (:func:`drovisio.recording.end_lines`); whether writes failed (exit status 1)."""
    from drovisio.recording import end_lines

    if pipeline.recorder is None:
        return False
    rs = pipeline.recorder.status()
    for line in end_lines(rs):
        _err(line)
    return int(rs.get("errors") or 0) > 0


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_pipeline_arguments(p: argparse.ArgumentParser, serving: bool) -> None:
    """The pipeline's options (:class:`~drovisio.pipeline_config.PipelineConfig`), shared by
    ``run`` and ``serve`` (one process on the drone)."""
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
    p.add_argument("--max-age", type=bounded(0.0, 3600.0, above=True), default=0.5,
                   metavar="SECONDS",
                   help="drop a brick not seen for this long (default 0.5 s)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio run``'s arguments: the source and camera, the pipeline's, the run's own."""
    p.add_argument("--source", required=True, metavar="SOURCE",
                   help="camera index (0), video file, folder of images (name order) or stream URL")
    p.add_argument("--camera", required=True, metavar="CAMERA_FILE", help="camera file")
    add_pipeline_arguments(p, serving=False)
    p.add_argument("--pace", choices=("realtime", "max"), default="realtime",
                   help="files and recordings: play at their own frame rate like a camera "
                        "(realtime, default) or process every frame as fast as possible (max)")
    p.add_argument("--frames", type=positive_int, metavar="N",
                   help="stop after N processed frames")
    p.add_argument("--quiet", action="store_true", help="no status line every second")


COMMAND = Command(
    name="run",
    summary="run the positioning pipeline headless (on the drone)",
    description="Read frames from a source, detect bricks, estimate and track their "
                "poses, and send the results to one or more sinks. A finite source (a "
                "video, a folder) ends the run when it is exhausted.",
    example="drovisio run --source 0 --camera camera.yaml \\\n"
            "    --layout marker_layouts/drick-aruco-pyramids.json --mount mount.json \\\n"
            "    --sink jsonl:- --sink mavlink:udpout:127.0.0.1:14550",
    add_arguments=add_arguments,
)
