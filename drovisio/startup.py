"""From a :class:`~drovisio.pipeline_config.PipelineConfig` to a running pipeline: the one
start-up check of the pipeline's options, shared by ``drovisio run`` and ``drovisio serve``
(which runs it before the server starts), the sinks, and the assembly (:func:`build_pipeline`,
also used by the web tool's live page and the benchmarks).

Bad set-up is said in one line, exit 2, before anything runs — never as a traceback from the
server's lifespan, never only on a page later. The check takes, in this order: the camera
file, the layouts, the detectors the layouts need (built once: what only they read of a
layout, its mesh, is refused here even when the camera file gives no image size and the real
detectors wait for the first frame), the mount file, the source (opened as ``run`` opens it),
the target, the recording folder, and every sink — each opened and closed again (a file
sink's folder, a UDP or WebSocket address, a MAVLink link: a ``tcp:`` peer must answer within
:attr:`~drovisio.errors.Limits.connect_timeout_s`). Nothing is written until all of the
inputs were read: bad input leaves no output file and no recording behind.
"""

from __future__ import annotations

import argparse
import os
import stat
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drovisio.autopilot.blind import blind_height
from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.errors import InputError, WriteError, one_line
from drovisio.fileio import check_output_name
from drovisio.layout import MarkerLayout, load_layouts
from drovisio.mount import Mount, load_mount
from drovisio.pipeline import Detector, Pipeline, detectors_for
from drovisio.pipeline_config import PipelineConfig
from drovisio.recording import Recorder, holds_recording
from drovisio.ros.mcap_recorder import McapRecorder
from drovisio.ros.messages import RosMessages, namespace_for
from drovisio.sinks import Sink, open_sink
from drovisio.sinks.base import SinkError
from drovisio.sinks.mavlink import MavlinkSink
from drovisio.sinks.target import TargetSelector
from drovisio.sources import FrameSource, Reader, reader_for

__all__ = ["build_pipeline", "check_pipeline_options", "check_record_folder", "check_source",
           "open_sinks_of"]


def _stat(p: Path) -> os.stat_result | None:
    """``p``'s status, None when it does not exist yet."""
    try:
        return p.stat()
    except FileNotFoundError:
        return None
    except OSError as e:
        raise InputError(f"{p}: --record: {e.strerror or e}; choose another folder") from None


def _check_existing(p: Path, st: os.stat_result, mcap: bool) -> None:
    """A recording is never written over: an existing ``.mcap``, a file or device given as
    the folder, a folder that holds a recording are refused."""
    if mcap:
        raise InputError(f"{p}: --record: the file exists (a recording is never written "
                         "over); give a new FILE.mcap")
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: --record is a file or a device; give a folder (made if "
                         "missing)")
    if holds_recording(p):
        raise InputError(f"{p}: --record: the folder already holds a recording (a "
                         "recording is never written over); give a new folder")


def check_record_folder(path: str | os.PathLike) -> Path:
    """``--record DIR``: a folder that exists or can be made, writable, not a file;
    ``--record FILE.mcap``: a file (new or regular) in a writable folder.

    Raises:
        InputError: one line naming ``--record`` and what to do.
    """
    try:
        p = check_output_name(path, "--record")
    except WriteError as e:
        raise InputError(str(e)) from None
    st = _stat(p)
    mcap = p.suffix.lower() == ".mcap"
    if st is not None:
        _check_existing(p, st, mcap)
    # the nearest folder that exists must be writable: the recording is made inside it
    q = p if (st is not None and not mcap) else p.absolute().parent
    while not q.exists() and q != q.parent:
        q = q.parent
    if not q.is_dir() or not os.access(q, os.W_OK | os.X_OK):
        raise InputError(f"{p}: --record: the folder {q} is not writable; choose another")
    return p


def check_source(source: str) -> Reader:
    """``--source``: a file, folder or recording is opened and closed again, as ``run`` opens
    it (an empty folder, a file that is no video, a recording's bad index: one line now, not
    once the server runs); cameras and stream URLs are not (``run`` keeps reconnecting to
    them).

    Returns:
        The reader, checked: the run plays it (a recording's index is not read again).

    Raises:
        InputError: naming ``--source`` and what is wrong.
    """
    reader = reader_for(source)
    if not getattr(reader, "finite", False):
        return reader
    try:
        reader.open()
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - a reader's own words, one line
        why = str(e)
        for said in (f"{source}: ", f"{getattr(reader, 'label', source)}: "):
            why = why.removeprefix(said)  # the path is said once
        raise InputError(f"{source}: --source: {one_line(why, 300)}") from None
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001,S110 - closing what may not have opened
            pass
    return reader


def _target(spec: str | None, layouts: Sequence[MarkerLayout] | None) -> TargetSelector:
    try:
        return TargetSelector(spec or "nearest", layouts=layouts)
    except ValueError as e:
        raise InputError(f"--target {one_line(spec, 80)}: {e}") from None


def _config(options: PipelineConfig | argparse.Namespace) -> PipelineConfig:
    """A parsed command line as the typed configuration (the check takes either)."""
    if isinstance(options, PipelineConfig):
        return options
    return PipelineConfig.from_args(options)


class _Checked(NamedTuple):
    """What the start-up check read, for :func:`build_pipeline` to use as read."""

    camera: Camera | None
    layouts: list[MarkerLayout] | None
    detectors: list[Detector]
    """Built for ``camera`` (for its guessed size when the file gives none), or for a
    stand-in camera without one: built to check the layouts."""
    mount: Mount | None
    reader: Reader | None
    target: TargetSelector


def _checked_detectors(camera: Camera | None, layouts: Sequence[MarkerLayout]
                       ) -> list[Detector]:
    """The detectors the layouts need, built to check what only they read of a layout (a
    mesh named beside ``dimensions``, dots they cannot use): before any sink or recording is
    opened, whatever the camera file says of the image size (without one they are built
    again for the first frame's size; without a camera, serve's sample, for the drone's
    webcam).

    Raises:
        InputError: ``LAYOUT: mesh: ...`` or ``LAYOUT: markers: ...``, in one line.
    """
    from drovisio.detect.dots import LayoutNotSupported  # deferred with the detectors

    try:
        return detectors_for(camera or Camera.drone_webcam(), layouts)
    except LayoutNotSupported as e:
        why = str(e)
        for lay in layouts:
            said = f"layout {lay.name!r}: "
            if why.startswith(said):
                raise InputError(f"{lay.source or lay.name}: markers: "
                                 f"{why.removeprefix(said)}; put at least 4 dots on one flat "
                                 "face, or remove them") from None
        raise InputError(f"--layout: {why}") from None


def _check(config: PipelineConfig, open_sinks: bool) -> _Checked:
    """The start-up check (see the module doc): every input is read before any output is
    opened."""
    camera = load_camera(config.camera) if config.camera else None
    layouts = load_layouts(config.layouts) if config.layouts else None
    detectors = _checked_detectors(camera, layouts) if layouts else []
    mount = load_mount(config.mount) if config.mount else None
    reader = check_source(config.source) if config.source else None
    target = _target(config.target, layouts)
    if config.record:
        check_record_folder(config.record)
    if open_sinks:
        _close_all(open_sinks_of(config, target, mount, layouts, camera=camera))
    return _Checked(camera, layouts, detectors, mount, reader, target)


def _close_all(sinks: Sequence[Sink]) -> None:
    """Close sinks that will not run (best effort: they opened, and what failed is said by
    whoever stops the start)."""
    for sink in sinks:
        try:
            sink.close()
        except Exception:  # noqa: BLE001,S110 - closing after a check or a failure
            pass


def check_pipeline_options(options: PipelineConfig | argparse.Namespace, *,
                           open_sinks: bool = True) -> Reader | None:
    """Check every pipeline option before anything runs (see the module doc).

    Args:
        options: The configuration, or the parsed ``run`` or ``serve`` command line.
        open_sinks: Open (and close) the sinks too; ``run`` opens them right after, through
            the same :func:`open_sinks_of`.

    Returns:
        The source's reader, checked (:func:`check_source`); None without a source.

    Raises:
        InputError: one line naming the option (or file) and what to do.
    """
    return _check(_config(options), open_sinks).reader


def open_sinks_of(config: PipelineConfig, target: TargetSelector, mount: Mount | None = None,
                  layouts: Sequence[MarkerLayout] | None = None,
                  default_sinks: tuple[str, ...] = (), camera: Camera | None = None
                  ) -> list[Sink]:
    """Open every sink of ``config`` (``default_sinks`` when none); on a failure the ones
    opened are closed and one line names the sink and what to do.

    Raises:
        InputError: the sink that could not be opened, and why, in
            :func:`~drovisio.sinks.open_sink`'s line.
    """
    sinks: list[Sink] = []
    for spec in (config.sinks or list(default_sinks)):
        try:
            sinks.append(open_sink(spec, target=target, autopilot=config.autopilot,
                                   mount=mount, layouts=layouts,
                                   send_held=config.send_held_targets,
                                   camera=camera, drone_id=config.drone_id))
        except SinkError as e:   # already the one line (open_sink): said as it is
            _close_all(sinks)
            raise InputError(str(e)) from None
        except BaseException:
            _close_all(sinks)
            raise
    return sinks


def _blind_height(mav: MavlinkSink | None, camera: Camera, mount: Mount | None,
                  layouts: Sequence[MarkerLayout]) -> None:
    """Tell a MAVLink sink the height below which the bricks leave the picture: the highest
    over the layouts (PX4's final-approach altitude must cover it)."""
    if mav is None or mount is None or not camera.size_known:
        return
    heights = [b.leaves_at_m for b in (blind_height(camera, mount, lay) for lay in layouts)
               if b.leaves_at_m is not None]
    mav.blind_height_m = max(heights) if heights else None


def _gravity(mav: MavlinkSink | None, mount: Mount | None
             ) -> Callable[[float], np.ndarray | None] | None:
    """``t_mono -> gravity in the camera frame``: the autopilot's roll and pitch when the link
    gives them, else level flight; None without a mount."""
    if mount is None:
        return None
    level = mount.gravity_in_camera()

    def attitude_gravity(t_mono: float) -> np.ndarray | None:
        if mav is not None:
            att = mav.attitude_at(t_mono)
            if att is not None:
                return mount.gravity_in_camera(att[0], att[1])
        return level

    return attitude_gravity


def _recorder(config: PipelineConfig, source: str, camera: Camera, mount: Mount | None,
              layouts: Sequence[MarkerLayout]) -> Recorder | McapRecorder | None:
    """The recording ``config.record`` asks for: an ``.mcap`` file (ROS 2 messages) or a
    folder (Drovisio's own form); None without one."""
    if not config.record:
        return None
    if config.record.lower().endswith(".mcap"):
        ns, prefix = namespace_for(config.drone_id)
        return McapRecorder(config.record, RosMessages(camera, mount, layouts, namespace=ns,
                                                       frame_prefix=prefix),
                            source=source, image_format=config.record_images)
    return Recorder(config.record, source=source, camera_file=config.camera,
                    mount_file=config.mount)


def build_pipeline(config: PipelineConfig, loop: bool = False,
                   default_sinks: tuple[str, ...] = ("jsonl:-",)) -> Pipeline:
    """The pipeline ``config`` describes, warmed up (``drovisio run``, the web tool's live
    page, the benchmarks).

    Args:
        config: Its ``source`` and ``camera`` must be given.
        loop: Play a file source in a loop (the web tool's sample session).
        default_sinks: The sinks when ``config.sinks`` is empty.

    Raises:
        InputError: a bad option, in one line (the check of :func:`check_pipeline_options`,
            sinks aside: they are opened here).
    """
    checked = _check(config, open_sinks=False)   # the same check as `serve`'s
    camera, layouts, mount = checked.camera, checked.layouts or [], checked.mount
    if config.source is None or camera is None:
        raise InputError("the pipeline needs a --source and a --camera")
    if not any(lay.has_codes or lay.has_dots for lay in layouts):
        raise InputError("the layouts have neither codes nor dots: nothing to detect")
    # the checked reader, unless the source plays in a loop (checked as played once)
    reader = (checked.reader if checked.reader is not None and not loop
              else reader_for(config.source, loop=loop))

    def make_detectors(cam: Camera) -> list[Detector]:
        return detectors_for(cam, layouts)

    # a camera file without an image size: the detectors are made for the first frame's
    detectors = checked.detectors if camera.size_known else []
    sinks = open_sinks_of(config, checked.target, mount, layouts, default_sinks,
                          camera=camera)
    recorder = None
    try:
        mav = next((s for s in sinks if isinstance(s, MavlinkSink)), None)
        _blind_height(mav, camera, mount, layouts)
        source = FrameSource(reader, pace=config.pace)
        recorder = _recorder(config, config.source, camera, mount, layouts)
        pipeline = Pipeline(source, detectors, sinks=sinks, mount=mount,
                            target=checked.target, gravity=_gravity(mav, mount),
                            recorder=recorder, max_age=config.max_age,
                            layouts=layouts, camera=camera, detector_factory=make_detectors)
    except BaseException:   # nothing runs: the sinks opened (a link's thread) are closed
        _close_all(sinks)
        if recorder is not None:
            recorder.close()
        raise
    if camera.size_known:
        pipeline.warm_up(camera.width, camera.height)
    return pipeline
