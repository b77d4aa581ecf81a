"""``drovisio detect``: bricks and their poses in images, folders and videos (JSON Lines).

Contract (DESIGN.md): one JSON object per frame on stdout (or ``--out``), in input order;
timings and summaries on stderr; a frame that cannot be read gives a line with ``"error"``
and the run goes on. Bad set-up (camera file, layouts, gravity file, output file) ends the
command with one line naming the file and the field, exit status 2. The exit status is 1
when some frame could not be read (its line says why), else 0.

``--method``: ``aruco`` (codes), ``dots`` (colour dots), ``auto`` (codes for layouts with
codes, dots for layouts with dots only).

``--out`` is written through a temporary file and renamed when the run ends (a run that
fails half-way leaves the previous file as it was); it may not be one of the inputs, the
camera file, a layout or the gravity file.

``--gravity-file``: JSON Lines ``{"file": ..., "gravity": [gx, gy, gz]}`` (unit vector
pointing down in the camera frame), optionally with ``"frame"`` for a video's frames. A line
matches a frame by ``file`` as given, else by the normalised path, else by the file's base
name when that is unique; a video line without ``frame`` applies to all its frames. A frame
given twice (the same path, normalised, and frame) is refused, naming both lines.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from drovisio.arguments import Command
from drovisio.errors import InputError, WriteError, one_line
from drovisio.fileio import atomic_write, check_output_path

if TYPE_CHECKING:
    import numpy as np

__all__ = ["COMMAND", "GravityTable", "add_arguments", "run"]

# The command's own modules (OpenCV, the detectors; numpy and YAML too) are imported inside the
# functions that run it: `drovisio --help` imports every command module and must stay light.

PROG = "drovisio detect"


def _err(msg: str) -> None:
    print(f"{PROG}: {msg}", file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- gravity
_GRAVITY_TOL = 0.05
"""How far from 1 a gravity vector's length may be (it is then made exactly 1)."""


def _gravity_line(line: str, where: str) -> tuple[str, int | None, tuple[float, float, float]]:
    """(file, frame or None, gravity as given) of one gravity-file line."""
    from drovisio.textfile import parse_json

    rec = parse_json(line, where)
    if not isinstance(rec, dict) or "file" not in rec or "gravity" not in rec:
        raise InputError(f'{where}: expected an object with "file" and "gravity"')
    f = rec["file"]
    if not isinstance(f, str) or not f:
        raise InputError(f'{where}: file: must be a non-empty string')
    g = _check_gravity(rec["gravity"], where)   # said before a bad frame, as always
    return f, _frame_of(rec.get("frame"), where), g


def _check_gravity(g: object, where: str) -> tuple[float, float, float]:
    """A gravity file's ``gravity``: 3 numbers, each within ±1.05 (checked before any
    arithmetic: 1e308 would overflow), of length 1 within 5 %."""
    if not (type(g) is list and len(g) == 3 and all(type(x) in (int, float) for x in g)):
        raise InputError(f'{where}: gravity: must be 3 numbers [gx, gy, gz]')
    gx, gy, gz = g
    big = 1.0 + _GRAVITY_TOL
    if not (-big <= gx <= big and -big <= gy <= big and -big <= gz <= big):
        shown = ", ".join(f"{x:.3g}" if isinstance(x, float) else one_line(x, 12) for x in g)
        raise InputError(f"{where}: gravity: [{shown}] is not a unit vector (each number "
                         f"from -{big:g} to {big:g}); give the direction of gravity, pointing "
                         "down, camera frame")
    gx, gy, gz = float(gx), float(gy), float(gz)
    n = math.sqrt(gx * gx + gy * gy + gz * gz)
    if n < 1e-9:
        raise InputError(f'{where}: gravity: must be a finite, non-zero vector')
    if abs(n - 1.0) > _GRAVITY_TOL:
        raise InputError(f'{where}: gravity: has length {n:.3g}; give a unit vector '
                         "(pointing down, camera frame)")
    return gx, gy, gz


def _frame_of(frame: object, where: str) -> int | None:
    """A gravity file's optional ``frame``: a whole number ≥ 0, or None."""
    if frame is not None and (not isinstance(frame, int) or isinstance(frame, bool)
                              or frame < 0):
        raise InputError(f'{where}: frame: must be a whole number >= 0')
    return frame


class GravityTable:
    """Gravity per frame from a ``--gravity-file``: one line per frame (a frame given twice
    is refused, naming both lines), at most :attr:`MAX_LINES` lines of at most
    :attr:`MAX_LINE_BYTES` (a line per frame of a 9-hour video at 30 fps), read in one pass.

    Attributes:
        unit: (N, 3) unit gravity vectors, one row per line of the file.
        exact, norm, base: row of ``unit`` by (file as given, frame), by (normalised path,
            frame), and by (base name, frame) (-1: that base name is on several lines).
    """

    MAX_LINES = 1_000_000
    MAX_LINE_BYTES = 64 * 1024
    MAX_BYTES = 128 * 1024 * 1024

    def __init__(self, unit: np.ndarray | None = None) -> None:
        import numpy as np

        self.unit = np.zeros((0, 3)) if unit is None else unit
        self.exact: dict[tuple[str, int | None], int] = {}
        self.norm: dict[tuple[str, int | None], int] = {}
        self.base: dict[tuple[str, int | None], int] = {}

    @classmethod
    def load(cls, path: str) -> GravityTable:
        """The table of a gravity file (JSON Lines ``{"file", "frame"?, "gravity"}``).

        Raises:
            InputError: a line that is not such an object, naming the line and the field; a
                frame given twice, naming both lines; a file, or a line, over its bound.
        """
        from array import array

        import numpy as np

        from drovisio.textfile import read_text

        text = read_text(path, "gravity file", max_bytes=cls.MAX_BYTES)
        if text.count("\n") > cls.MAX_LINES:
            raise InputError(f"{path}: more than {cls.MAX_LINES} lines; split the run")
        files: list[tuple[str, int | None]] = []
        first_line: dict[tuple[str, int | None], int] = {}   # by normalised path
        rows = array("d")
        for ln, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            where = f"{path}, line {ln}"
            if len(line) > cls.MAX_LINE_BYTES:
                raise InputError(f"{where}: longer than {cls.MAX_LINE_BYTES // 1024} KiB; a "
                                 'line is {"file", "frame", "gravity"}: is it the right file?')
            f, frame, g = _gravity_line(line, where)
            seen = first_line.setdefault((os.path.normpath(f), frame), ln)
            if seen != ln:
                what = f"{f!r}" + (f" frame {frame}" if frame is not None else "")
                raise InputError(f"{where}: file: {one_line(what, 120)} is given again (first "
                                 f"at line {seen}); give each frame's gravity once")
            files.append((f, frame))
            rows.extend(g)
        unit = np.frombuffer(rows, np.float64).reshape(-1, 3).copy()
        unit /= np.linalg.norm(unit, axis=1, keepdims=True)
        t = cls(unit)
        t.exact = {k: i for i, k in enumerate(files)}
        t.norm = {k: i for i, k in enumerate(first_line)}   # insertion order: the lines'
        for i, (f, frame) in enumerate(files):
            key = (os.path.basename(f), frame)
            t.base[key] = -1 if key in t.base else i   # a base name is used only if unique
        return t

    def lookup(self, file: str, frame: int, is_video: bool) -> np.ndarray | None:
        keys = [frame, None] if is_video else [None, frame]
        for k in keys:
            for table, name in ((self.exact, file), (self.norm, os.path.normpath(file))):
                i = table.get((name, k))
                if i is not None:
                    return self.unit[i]
        for k in keys:
            i = self.base.get((os.path.basename(file), k), -1)
            if i >= 0:
                return self.unit[i]
        return None


# ----------------------------------------------------------------------------- set-up
def _layouts_for(args: argparse.Namespace):
    """(camera, code layouts, dot layouts) the arguments ask for."""
    from drovisio.camera_file import load_camera
    from drovisio.layout import load_layouts

    camera = load_camera(args.camera)
    layouts = load_layouts(args.layout)
    coded = [lay for lay in layouts if lay.has_codes]
    dotted = [lay for lay in layouts if lay.has_dots]
    names = ", ".join(lay.name for lay in layouts)
    if args.method == "aruco" and not coded:
        raise InputError(f"--method aruco: none of the layouts has ArUco codes ({names})")
    if args.method == "dots" and not dotted:
        raise InputError(f"--method dots: none of the layouts has colour dots ({names})")
    if args.method == "aruco":
        return camera, coded, []
    if args.method == "dots":
        return camera, [], dotted
    return camera, coded, [lay for lay in dotted if not lay.has_codes]


def _output(args: argparse.Namespace) -> tuple[TextIO, Path | None, Path | None]:
    """(stream to write, temporary file, final path) for ``--out`` (stdout without it)."""
    if not args.out:
        return sys.stdout, None, None
    others: dict[str, str] = {"the camera file": args.camera}
    others.update({f"layout {lay}": lay for lay in args.layout})
    if args.gravity_file:
        others["the gravity file"] = args.gravity_file
    others.update({f"input {inp}": inp for inp in args.inputs})
    out = check_output_path(args.out, "--out", others)
    folder = out.parent if str(out.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}-", suffix=".tmp", dir=folder)
    except OSError as e:
        raise WriteError(f"{out}: --out: cannot write in {folder} ({e.strerror or e})") \
            from None
    return os.fdopen(fd, "w", encoding="utf-8"), Path(tmp), out


def _finish_output(stream: TextIO, tmp: Path, out: Path) -> None:
    try:
        stream.flush()
        os.fsync(stream.fileno())
        stream.close()

        def move(dest_tmp: Path) -> None:
            os.replace(tmp, dest_tmp)

        atomic_write(out, move, allow_empty=True)
    except OSError as e:
        raise WriteError(f"{out}: --out: not written ({e}); any previous file is kept") \
            from None
    finally:
        tmp.unlink(missing_ok=True)


class _Streams:
    """Detectors per input: a video or a folder is a stream (pose history, dot state), single
    images are not; a camera file without an image size takes each source's first image."""

    def __init__(self, camera_file: str, camera, aruco_layouts, dots_layouts) -> None:
        self.camera_file = camera_file
        self.camera = camera
        self.aruco_layouts = aruco_layouts
        self.dots_layouts = dots_layouts
        self._by_source: dict[tuple[str, bool], tuple[Any, list]] = {}
        self.noted: set[str] = set()

    def detectors(self, source: str, stream: bool, size: tuple[int, int]):
        from drovisio.detect.aruco import ArucoBrickDetector
        from drovisio.detect.dots import DotDetector

        key = (source if stream else "", stream)
        got = self._by_source.get(key)
        if got is None or got[0].size != size:
            camera, note = self.camera.for_image(*size)   # ValueError: another size
            if note and note not in self.noted:
                self.noted.add(note)
                _err(f"{self.camera_file}: {note}")
            dets: list = []
            if self.aruco_layouts:
                dets.append(ArucoBrickDetector(camera, self.aruco_layouts, stream=stream))
            if self.dots_layouts:
                dets.append(DotDetector(camera, self.dots_layouts, stream=stream))
            if len(self._by_source) > 8:
                self._by_source.pop(next(iter(self._by_source)))
            got = self._by_source[key] = (camera, dets)
        return got[1]


def run(args: argparse.Namespace) -> int:
    camera, aruco_layouts, dots_layouts = _layouts_for(args)
    gravity = GravityTable.load(args.gravity_file) if args.gravity_file else None
    stream, tmp, out = _output(args)
    try:
        code = _run_frames(args, _Streams(args.camera, camera, aruco_layouts, dots_layouts),
                           gravity, stream)
    except BaseException:
        if tmp is not None:
            stream.close()
            tmp.unlink(missing_ok=True)
        raise
    if tmp is not None and out is not None:
        _finish_output(stream, tmp, out)
    return code


@dataclass
class _Tally:
    """What the run counted, for its summary, and what it said once per input."""

    frames: int = 0
    bricks: int = 0
    errors: int = 0
    gravity: int = 0
    dup_frames: int = 0
    times: list[float] = field(default_factory=list)
    """Detection and pose time of each frame, seconds."""
    noted: set[str] = field(default_factory=set)

    def say_once(self, key: str, message: str) -> None:
        if key not in self.noted:
            self.noted.add(key)
            _err(message)


def _detect(item, res, streams: _Streams, gravity: GravityTable | None,
            tally: _Tally) -> None:
    """Detect the bricks of one readable frame into ``res`` (a failure is its error)."""
    for note in item.notes:
        tally.say_once(f"{item.source}: {note}", f"{item.file}: {note}")
    img = item.image
    assert img is not None
    stream = item.is_video or item.source != item.file   # a video or a folder
    try:
        dets = streams.detectors(item.source, stream, (img.shape[1], img.shape[0]))
    except InputError:   # a layout's mesh that cannot be read: the run's input, not the frame's
        raise
    except ValueError as e:
        res.error = str(e)
        dets = []
    g = gravity.lookup(item.file, item.frame, item.is_video) if gravity else None
    tally.gravity += g is not None
    t0 = time.perf_counter()
    for det in dets:
        try:
            res.bricks.extend(det.detect(img, gravity=g))
        except Exception as e:  # noqa: BLE001 - a frame must never stop the run
            res.bricks = []
            res.error = f"detection failed: {type(e).__name__}: {e}"
            break
    if dets:
        tally.times.append(time.perf_counter() - t0)


def _say_duplicates(item, res, where: str, tally: _Tally) -> None:
    """Codes of one brick whose id was read several times: said once per input."""
    dup = sorted({(b.layout, b.instance) for b in res.bricks if b.duplicate}, key=str)
    tally.dup_frames += bool(dup)
    for lay_name, inst in dup:
        n = sum(1 for b in res.bricks if b.duplicate and b.layout == lay_name
                and b.instance == inst)
        tally.say_once(f"{item.source}: {lay_name}:{inst}",
                       f"{where}: {n} codes of {lay_name} instance {inst} share their id: each "
                       "is posed on its own and flagged \"duplicate\" (give each brick its own "
                       "ids: the layout's first_id, ids_per_instance, instances)")


def _say_messages(messages: list[str], tally: _Tally) -> None:
    """The inputs' own messages (a file that could not be read), counted as errors."""
    for m in messages:
        _err(m)
    tally.errors += len(messages)
    messages.clear()


def _run_frames(args, streams: _Streams, gravity: GravityTable | None, out: TextIO) -> int:
    # deferred: the detectors and the readers load OpenCV, which `drovisio --help` must not
    from drovisio.detect.corners import normalized_grid
    from drovisio.detect.result import FrameRecord
    from drovisio.sources import iter_inputs

    if streams.aruco_layouts and streams.camera.size_known:
        normalized_grid(streams.camera)  # the undistortion table, once, outside the timing
    messages: list[str] = []
    tally = _Tally()
    for item in iter_inputs(args.inputs, messages):
        _say_messages(messages, tally)
        tally.frames += 1
        res = FrameRecord(file=item.file, frame=item.frame)
        where = f"{item.file}" + (f" frame {item.frame}" if item.is_video else "")
        if item.error is not None:
            res.error = item.error
        else:
            _detect(item, res, streams, gravity, tally)
        _say_duplicates(item, res, where, tally)
        if res.error is not None:
            tally.errors += 1
            _err(f"{where}: {res.error}")
        tally.bricks += len(res.bricks)
        out.write(json.dumps(res.to_json(), allow_nan=False) + "\n")
        out.flush()
    _say_messages(messages, tally)
    if tally.frames == 0:
        _err("no frames to process")
        return 1
    _summary(tally.frames, tally.bricks, tally.errors, gravity, tally.gravity, tally.times)
    if tally.dup_frames:
        _err(f"{tally.dup_frames} of {tally.frames} frames had codes sharing one id (flagged "
             "\"duplicate\")")
    return 1 if tally.errors else 0


def _summary(n_frames: int, n_bricks: int, n_errors: int, gravity, n_gravity: int,
             times: list[float]) -> None:
    import numpy as np

    def plural(n: int, word: str) -> str:
        return f"{n} {word}{'s' if n != 1 else ''}"

    ms = 1000.0 * sum(times) / max(1, len(times))
    grav = f", gravity for {n_gravity}" if gravity is not None else ""
    # the first frame also loads the detectors (compiled kernels, dictionaries): the median
    # is what a stream costs per frame
    med = 1000.0 * float(np.median(times)) if times else ms
    timing = f"{ms:.1f} ms per frame (detection and pose)" if len(times) < 3 else \
        f"median {med:.1f} ms per frame (detection and pose; mean {ms:.1f} ms, the first " \
        f"frame {1000.0 * times[0]:.0f} ms with the detectors' set-up)"
    _err(f"{plural(n_frames, 'frame')}, {plural(n_bricks, 'brick')}, "
         f"{plural(n_errors, 'error')}{grav}; {timing}")
    if gravity is not None and n_gravity == 0:
        _err("warning: no frame matched a line of the gravity file (match is by the file "
             "name as given)")



# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio detect``'s arguments (the contract of DESIGN.md)."""
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


COMMAND = Command(
    name="detect",
    summary="find bricks in images or videos and print their poses (JSON Lines)",
    description="Detect bricks by their ArUco codes or colour dots and estimate each "
                "brick's pose relative to the camera (camera_from_brick: rvec, tvec in "
                "metres). One JSON object per frame, in input order, on stdout unless "
                "--out is given; timings and summaries go to stderr.",
    example="drovisio detect --camera camera.yaml \\\n"
            "    --layout marker_layouts/drick-aruco-pyramids.json frames/ > poses.jsonl",
    add_arguments=add_arguments,
)
