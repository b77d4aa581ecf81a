"""The one start-up check of the pipeline's options, shared by ``drovisio run`` and
``drovisio serve`` (which runs it before the server starts): bad set-up is said in one line,
exit 2, before anything runs — never as a traceback from the server's lifespan, never only on
a page later.

It checks, in this order: the camera file, the layouts, the mount file, the source (opened as
``run`` opens it), the target, the recording folder, and every sink — each opened and closed
again (a file sink's folder, a UDP or WebSocket address, a MAVLink link: a ``tcp:`` peer must
answer within :attr:`~drovisio.errors.Limits.connect_timeout_s`).
"""

from __future__ import annotations

import argparse
import os
import stat
from pathlib import Path

from drovisio.errors import InputError, one_line

__all__ = ["check_pipeline_options", "check_record_folder", "check_source", "open_sinks_of"]


def check_record_folder(path: str | os.PathLike) -> Path:
    """``--record DIR``: a folder that exists or can be made, writable, not a file;
    ``--record FILE.mcap``: a file (new or regular) in a writable folder.

    Raises:
        InputError: one line naming ``--record`` and what to do.
    """
    from drovisio.errors import WriteError
    from drovisio.fileio import check_output_name

    try:
        p = check_output_name(path, "--record")
    except WriteError as e:
        raise InputError(str(e)) from None
    try:
        st = p.stat()
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise InputError(f"{p}: --record: {e.strerror or e}; choose another folder") from None
    mcap = p.suffix.lower() == ".mcap"
    if mcap and st is not None:
        raise InputError(f"{p}: --record: the file exists (a recording is never written "
                         "over); give a new FILE.mcap")
    if not mcap and st is not None and not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: --record is a file or a device; give a folder (made if "
                         "missing)")
    if not mcap and st is not None:
        from drovisio.recording import holds_recording

        if holds_recording(p):
            raise InputError(f"{p}: --record: the folder already holds a recording (a "
                             "recording is never written over); give a new folder")
    # the nearest folder that exists must be writable: the recording is made inside it
    q = p if (st is not None and not mcap) else p.absolute().parent
    while not q.exists() and q != q.parent:
        q = q.parent
    if not q.is_dir() or not os.access(q, os.W_OK | os.X_OK):
        raise InputError(f"{p}: --record: the folder {q} is not writable; choose another")
    return p


def check_source(source: str) -> None:
    """``--source``: a file, folder or recording is opened and closed again, as ``run`` opens
    it (an empty folder, a file that is no video: one line now, not once the server runs);
    cameras and stream URLs are not (``run`` keeps reconnecting to them).

    Raises:
        InputError: naming ``--source`` and what is wrong.
    """
    from drovisio.sources import reader_for

    reader = reader_for(source)
    if not getattr(reader, "finite", False):
        return
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


def _target(spec: str | None):
    from drovisio.sinks.target import TargetSelector

    try:
        return TargetSelector(spec or "nearest")
    except ValueError as e:
        raise InputError(f"--target {one_line(spec, 80)}: {e}") from None


def check_pipeline_options(args: argparse.Namespace, *, open_sinks: bool = True) -> None:
    """Check every pipeline option of ``args`` before anything runs (see the module doc).

    Args:
        args: The parsed ``run`` or ``serve`` command line (``camera``, ``layout``, ``mount``,
            ``source``, ``target``, ``record``, ``sink``, ``autopilot``).
        open_sinks: Open (and close) the sinks too; ``run`` opens them right after, through
            the same :func:`open_sinks_of`.

    Raises:
        InputError: one line naming the option (or file) and what to do.
    """
    camera = None
    if getattr(args, "camera", None):
        from drovisio.camera_file import load_camera

        camera = load_camera(args.camera)
    layouts = None
    if getattr(args, "layout", None):
        from drovisio.layout import load_layouts

        layouts = load_layouts(args.layout)
    mount = None
    if getattr(args, "mount", None):
        from drovisio.mount import load_mount

        mount = load_mount(args.mount)
    if getattr(args, "source", None):
        check_source(args.source)
    target = _target(getattr(args, "target", None))
    if getattr(args, "record", None):
        check_record_folder(args.record)
    if open_sinks:
        for sink in open_sinks_of(args, target, mount, layouts, camera=camera):
            try:
                sink.close()
            except Exception:  # noqa: BLE001,S110 - it opened: closing it is best effort
                pass


def open_sinks_of(args: argparse.Namespace, target, mount=None, layouts=None,
                  default_sinks: tuple[str, ...] = (), camera=None) -> list:
    """Open every ``--sink`` of ``args`` (``default_sinks`` when none); on a failure the ones
    opened are closed and one line names the sink and what to do.

    Raises:
        InputError: the sink that could not be opened, and why.
    """
    from drovisio.sinks import open_sink
    from drovisio.sinks.base import SinkError

    sinks: list = []
    for spec in (getattr(args, "sink", None) or list(default_sinks)):
        try:
            sinks.append(open_sink(spec, target=target,
                                   autopilot=getattr(args, "autopilot", "ardupilot"),
                                   mount=mount, layouts=layouts,
                                   send_held=getattr(args, "send_held_targets", False),
                                   camera=camera, drone_id=getattr(args, "drone_id", None)))
        except (SinkError, OSError, ValueError) as e:  # a spec's parts, parsed: one line too
            for s in sinks:
                s.close()
            why = (e.strerror or e) if isinstance(e, OSError) else e
            raise InputError(f"--sink {one_line(spec, 80)}: {one_line(why, 300)}") from None
        except BaseException:
            for s in sinks:
                s.close()
            raise
    return sinks
