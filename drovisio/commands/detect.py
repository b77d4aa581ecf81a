"""``drovisio detect``: bricks and their poses in images, folders and videos (JSON Lines).

Contract (DESIGN.md): one JSON object per frame on stdout (or ``--out``), in input order;
timings and summaries on stderr; a frame that cannot be read gives a line with ``"error"``
and the run goes on. Bad set-up (camera file, layouts, gravity file, output file) is reported
in one clear line on stderr with exit status 2, never a traceback. The exit status is 1 when
some input could not be read (its lines say which), else 0.

``--method``: ``aruco`` (codes), ``dots`` (colour dots: ``drovisio.detect.dots``, when that
module exists), ``auto`` (codes for layouts with codes, dots for layouts with dots only, when
the dots detector exists).

``--gravity-file``: JSON Lines ``{"file": ..., "gravity": [gx, gy, gz]}`` (unit vector
pointing down in the camera frame), optionally with ``"frame"`` for a video's frames. A line
matches a frame by ``file`` as given, else by the normalised path, else by the file's base
name when that is unique; a video line without ``frame`` applies to all its frames.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

PROG = "drovisio detect"


class _SetupError(Exception):
    pass


def _err(msg: str) -> None:
    print(f"{PROG}: {msg}", file=sys.stderr)


# ----------------------------------------------------------------------------- gravity
class GravityTable:
    """Gravity per frame from a ``--gravity-file``."""

    def __init__(self) -> None:
        self.exact: dict[tuple[str, int | None], np.ndarray] = {}
        self.norm: dict[tuple[str, int | None], np.ndarray] = {}
        self.base: dict[tuple[str, int | None], list[np.ndarray]] = {}

    @classmethod
    def load(cls, path: str) -> GravityTable:
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise _SetupError(f"{path}: gravity file not found") from None
        except IsADirectoryError:
            raise _SetupError(f"{path}: is a folder; give the gravity JSON Lines file") from None
        except (OSError, UnicodeDecodeError) as e:
            raise _SetupError(f"{path}: cannot read the gravity file ({e})") from None
        t = cls()
        for ln, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            where = f"{path}, line {ln}"
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as e:
                raise _SetupError(f"{where}: not valid JSON ({e.msg}); expected "
                                  '{"file": ..., "gravity": [gx, gy, gz]}') from None
            if not isinstance(rec, dict) or "file" not in rec or "gravity" not in rec:
                raise _SetupError(f'{where}: expected an object with "file" and "gravity"')
            f = rec["file"]
            if not isinstance(f, str) or not f:
                raise _SetupError(f'{where}: "file" must be a non-empty string')
            g = rec["gravity"]
            try:
                gv = np.asarray(g, np.float64).reshape(3)
            except (TypeError, ValueError):
                raise _SetupError(f'{where}: "gravity" must be 3 numbers [gx, gy, gz]') from None
            n = float(np.linalg.norm(gv))
            if not np.all(np.isfinite(gv)) or n < 1e-9:
                raise _SetupError(f'{where}: "gravity" must be a finite, non-zero vector')
            if abs(n - 1.0) > 0.05:
                raise _SetupError(f'{where}: "gravity" has length {n:.3g}; give a unit vector '
                                  "(pointing down, camera frame)")
            frame = rec.get("frame")
            if frame is not None and (not isinstance(frame, int) or isinstance(frame, bool)):
                raise _SetupError(f'{where}: "frame" must be an integer')
            t.add(f, frame, gv / n)
        return t

    def add(self, file: str, frame: int | None, g: np.ndarray) -> None:
        self.exact[(file, frame)] = g
        self.norm[(os.path.normpath(file), frame)] = g
        self.base.setdefault((os.path.basename(file), frame), []).append(g)

    def lookup(self, file: str, frame: int, is_video: bool) -> np.ndarray | None:
        keys = [frame, None] if is_video else [None, frame]
        for k in keys:
            for table, name in ((self.exact, file), (self.norm, os.path.normpath(file))):
                g = table.get((name, k))
                if g is not None:
                    return g
        for k in keys:
            cands = self.base.get((os.path.basename(file), k))
            if cands and len(cands) == 1:
                return cands[0]
        return None


# ----------------------------------------------------------------------------- detectors
def _load_dots():
    try:
        from drovisio.detect import dots
    except ModuleNotFoundError as e:
        if e.name in ("drovisio.detect.dots",):
            return None
        raise
    return getattr(dots, "detect_dots", None)


def _setup(args: argparse.Namespace):
    import cv2

    from drovisio.camera import CameraFileError, load_camera
    from drovisio.layout import LayoutError, load_layouts

    try:
        camera = load_camera(args.camera)
    except CameraFileError as e:
        raise _SetupError(str(e)) from None
    except cv2.error as e:  # a malformed matrix OpenCV's reader chokes on
        last = str(e).strip().splitlines()[-1] if str(e).strip() else "unreadable"
        raise _SetupError(f"{args.camera}: malformed camera file: OpenCV cannot read a "
                          f"matrix in it ({last}); check rows, cols and the number of values "
                          "in data") from None
    try:
        layouts = load_layouts(args.layout)
    except LayoutError as e:
        raise _SetupError(str(e)) from None
    coded = [lay for lay in layouts if lay.has_codes]
    dotted = [lay for lay in layouts if lay.has_dots]
    method = args.method
    aruco_layouts: list = []
    dots_layouts: list = []
    notes: list[str] = []
    if method in ("aruco", "auto"):
        aruco_layouts = coded
    if method == "aruco" and not coded:
        raise _SetupError("--method aruco: none of the layouts has ArUco codes (" +
                          ", ".join(lay.name for lay in layouts) + ")")
    detect_dots = None
    if method == "dots" or (method == "auto" and any(not lay.has_codes for lay in dotted)):
        detect_dots = _load_dots()
        if detect_dots is None:
            if method == "dots":
                raise _SetupError("the dots detector is not available yet (drovisio.detect.dots,"
                                  " issue #4); use --method aruco for layouts with codes")
            notes.append("the dots detector is not available yet; layouts with dots only (" +
                          ", ".join(lay.name for lay in dotted if not lay.has_codes) +
                          ") are skipped")
        else:
            dots_layouts = dotted if method == "dots" else [lay for lay in dotted
                                                              if not lay.has_codes]
    if method == "dots" and not dotted:
        raise _SetupError("--method dots: none of the layouts has colour dots")
    if not aruco_layouts and not dots_layouts:
        raise _SetupError("nothing to detect: no layout with codes, and the dots detector is "
                          "not available yet")
    return camera, aruco_layouts, dots_layouts, detect_dots, notes


def run(args: argparse.Namespace) -> int:
    try:
        camera, aruco_layouts, dots_layouts, detect_dots, notes = _setup(args)
        gravity = GravityTable.load(args.gravity_file) if args.gravity_file else None
        out = sys.stdout
        close = False
        if args.out:
            try:
                out = open(args.out, "w", encoding="utf-8")  # noqa: SIM115
                close = True
            except OSError as e:
                raise _SetupError(f"{args.out}: cannot write the output ({e.strerror or e})"
                                  ) from None
    except _SetupError as e:
        _err(str(e))
        return 2
    for n in notes:
        _err(n)
    try:
        return _run_frames(args, camera, aruco_layouts, dots_layouts, detect_dots, gravity, out)
    finally:
        if close:
            out.close()


def _run_frames(args, camera, aruco_layouts, dots_layouts, detect_dots, gravity, out) -> int:
    from drovisio.detect.aruco import ArucoBrickDetector
    from drovisio.detect.result import FrameResult
    from drovisio.io_frames import VIDEO_EXTS, iter_frames
    from drovisio.pose import PoseHistory

    detectors: dict[str, ArucoBrickDetector] = {}  # one per source (a stream's history)
    if aruco_layouts:  # the per-camera undistortion table, once, outside the frames' time
        from drovisio.detect.corners import normalized_grid

        normalized_grid(camera)

    def aruco_for(source: str, stream: bool) -> ArucoBrickDetector | None:
        if not aruco_layouts:
            return None
        key = source if stream else ""
        det = detectors.get(key)
        if det is None:
            det = ArucoBrickDetector(camera, aruco_layouts,
                                     history=PoseHistory() if stream else None)
            if len(detectors) > 8:
                detectors.pop(next(iter(detectors)))
            detectors[key] = det
        return det

    dots_states: dict[str, object] = {}  # one per stream, if the dots detector keeps state

    def dots_state_for(source: str):
        if source not in dots_states:
            try:
                from drovisio.detect.dots import DotsState
            except ImportError:
                return None
            if len(dots_states) > 8:
                dots_states.pop(next(iter(dots_states)))
            dots_states[source] = DotsState()
        return dots_states[source]

    messages: list[str] = []
    n_frames = n_bricks = n_errors = n_gravity = 0
    times: list[float] = []   # detection + pose time of each frame
    noted: set[str] = set()
    for item in iter_frames(args.inputs, messages):
        for m in messages:
            _err(m)
        n_errors += len(messages)
        messages.clear()
        n_frames += 1
        res = FrameResult(file=item.file, frame=item.frame)
        if item.error is not None:
            res.error = item.error
            n_errors += 1
            _err(f"{item.file}" + (f" frame {item.frame}" if item.source != item.file or
                                   Path(item.file).suffix.lower() in VIDEO_EXTS else "") +
                 f": {item.error}")
        else:
            for note in item.notes:
                key = f"{item.source}: {note}"
                if key not in noted:
                    noted.add(key)
                    _err(f"{item.file}: {note}")
            img = item.image
            if img.shape[:2] != (camera.height, camera.width):
                res.error = (f"image is {img.shape[1]}x{img.shape[0]} but the camera file is "
                             f"for {camera.width}x{camera.height}")
                n_errors += 1
                _err(f"{item.file}: {res.error}")
            else:
                is_video = Path(item.file).suffix.lower() in VIDEO_EXTS
                g = gravity.lookup(item.file, item.frame, is_video) if gravity else None
                n_gravity += g is not None
                stream = is_video or item.source != item.file  # a video or a folder
                t0 = time.perf_counter()
                try:
                    det = aruco_for(item.source, stream)
                    if det is not None:
                        res.bricks.extend(det.detect(img, gravity=g))
                    if detect_dots is not None and dots_layouts:
                        state = dots_state_for(item.source) if stream else None
                        kw = {"state": state} if state is not None else {}
                        res.bricks.extend(detect_dots(img, camera, dots_layouts, gravity=g,
                                                      **kw))
                except Exception as e:  # noqa: BLE001 - a frame must never stop the run
                    res.bricks = []
                    res.error = f"detection failed: {type(e).__name__}: {e}"
                    n_errors += 1
                    _err(f"{item.file}: {res.error}")
                times.append(time.perf_counter() - t0)
        n_bricks += len(res.bricks)
        out.write(json.dumps(res.to_json(), allow_nan=False) + "\n")
        out.flush()
    for m in messages:
        _err(m)
    n_errors += len(messages)
    if n_frames == 0:
        _err("no frames to process")
        return 1
    ms = 1000.0 * sum(times) / max(1, n_frames)
    grav = f", gravity for {n_gravity}" if gravity is not None else ""
    # the first frame also loads the detectors (compiled kernels, dictionaries): the median
    # is what a stream costs per frame
    med = 1000.0 * float(np.median(times)) if times else ms
    timing = f"{ms:.1f} ms per frame (detection and pose)" if len(times) < 3 else \
        f"median {med:.1f} ms per frame (detection and pose; mean {ms:.1f} ms, the first " \
        f"frame {1000.0 * times[0]:.0f} ms with the detectors' set-up)"
    _err(f"{n_frames} frame{'s' if n_frames != 1 else ''}, {n_bricks} brick"
         f"{'s' if n_bricks != 1 else ''}, {n_errors} error{'s' if n_errors != 1 else ''}"
         f"{grav}; {timing}")
    if gravity is not None and n_gravity == 0:
        _err("warning: no frame matched a line of the gravity file (match is by the file "
             "name as given)")
    return 1 if n_errors else 0
