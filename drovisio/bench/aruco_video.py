"""``drovisio bench aruco --video PATH``: the code detector's time on real frames, against
plain OpenCV and AprilTag 3 in the same process, on the same frames.

Frames come from a video file or a folder of images (any size: the camera is a 60° pinhole
of the frames' size unless ``--camera`` gives one). Per dictionary (by default 4×4, 6×6 and
tag36h11: the shipped drick layouts with every code in that dictionary, same ids), each frame
is timed ``--repeat`` times per detector, interleaved, the fastest kept (other processes only
ever add time):

* **drovisio**: the whole ``ArucoBrickDetector.detect`` (grey conversion, codes, the
  small-code rescue, corners, poses);
* **plain**: ``cv2.aruco.ArucoDetector(dictionary, DetectorParameters()).detectMarkers`` on
  the same BGR frame, the full dictionary, default parameters;
* **AprilTag 3** (tag36h11 only, when pupil-apriltags is installed): ``Detector`` at its
  default settings (``quad_decimate=2``, one thread) on the grey frame.

Reported: median and p90 per detector, the ratios of those (drovisio / plain, drovisio /
AprilTag 3) and the median of per-frame ratios; bricks and codes found (a clip with no code
must give none). One OpenCV thread by default (``--threads``), the calling thread's CPU time
(``--clock``).

Data: OpenCV's ``vtest.avi`` (a hall with walking people, no code, 768×576, 795 frames) is
in Debian's ``opencv-doc`` package (``apt-get install opencv-doc``:
``/usr/share/doc/opencv-doc/examples/data/vtest.avi``) and in OpenCV's source tree
(``samples/data/vtest.avi``)::

    drovisio bench aruco --video /usr/share/doc/opencv-doc/examples/data/vtest.avi
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector, plain_detector
from drovisio.detect.corners import normalized_grid
from drovisio.errors import LIMITS, InputError
from drovisio.layout import load_layouts, shipped_layouts_dir, with_dictionary
from drovisio.raw_frame import EndOfStream
from drovisio.sources import ImageFolderReader, VideoFileReader
from drovisio.study.methods import apriltag_detector

DEFAULT_DICTIONARIES = ("DICT_4X4_50", "DICT_6X6_250", "DICT_APRILTAG_36h11")


def read_frames(path: Path, max_frames: int) -> list[np.ndarray]:
    """Up to ``max_frames`` BGR frames of a video file or of a folder's images (name order),
    read by the sources' readers (:class:`~drovisio.sources.VideoFileReader`,
    :class:`~drovisio.sources.ImageFolderReader`), so the bench gets their bounds: the frame
    size refused from the header before anything is decoded, a file that is no video (or a
    pipe, a device) refused in one line. A folder's unreadable pictures, and pictures of
    another size than the first, are skipped; a video that cannot be decoded further (cut
    short, damaged) ends there, said in one line on stderr, and its frames before are timed.

    Raises:
        InputError: The path is missing, not a video, holds no readable frame, or the frames
            asked for would take more memory than the work cap.
    """
    if not path.exists():
        raise InputError(f"{path}: --video: no such file or folder; give a video file or a "
                         "folder of images")
    reader = ImageFolderReader(path) if path.is_dir() else VideoFileReader(path)
    try:
        reader.open()
    except OSError as e:   # the reader's own reason, said with the option
        raise InputError(f"{path}: --video: {str(e).removeprefix(f'{path}: ')}") from None
    frames: list[np.ndarray] = []
    try:
        while len(frames) < max_frames:
            try:
                fr = reader.read()
            except EndOfStream:
                break
            if fr is None:
                break
            if fr.image is None:
                if isinstance(reader, ImageFolderReader):
                    continue     # the bench runs on the pictures that can be read
                print(f"drovisio bench: {path} frame {fr.index}: {fr.error}; timing the "
                      f"{len(frames)} frame(s) before it", file=sys.stderr)
                break
            if not frames:
                _check_memory(path, fr.image, max_frames, reader)
            if not frames or fr.image.shape == frames[0].shape:
                frames.append(fr.image)
    finally:
        reader.close()
    if not frames:
        raise InputError(f"{path}: --video: no frame could be read; give a video OpenCV can "
                         "decode or a folder of images of one size")
    return frames


def _check_memory(path: Path, first: np.ndarray, max_frames: int,
                  reader: ImageFolderReader | VideoFileReader) -> None:
    """Refuse frames that, all held at once (colour and grey), would pass the work cap.

    Raises:
        InputError: naming the frames' size, their count and what to do.
    """
    count = len(reader.files) if isinstance(reader, ImageFolderReader) else reader.count
    n = min(max_frames, count) if count else max_frames
    need = n * first.shape[0] * first.shape[1] * 4   # BGR and grey, one byte a sample
    if need > LIMITS.max_work_bytes:
        raise InputError(f"{path}: --max-frames: {n} frames of {first.shape[1]}x"
                         f"{first.shape[0]} held at once need {need / 2**30:.1f} GiB, more "
                         f"than the {LIMITS.max_work_bytes / 2**30:.1f} GiB cap; give fewer "
                         "--max-frames (DROVISIO_MAX_WORK_MIB raises the cap)")


def _apriltag_default():
    """AprilTag 3 for tag36h11 at its default settings, or None when not installed."""
    try:
        import pupil_apriltags  # noqa: F401 - an optional dependency, only asked whether present
    except ImportError:
        return None
    return apriltag_detector("tag36h11", defaults=True)


def _stats(v: list[float]) -> tuple[float, float]:
    return float(statistics.median(v)), float(np.percentile(v, 90))


def run(path: Path, dictionaries=DEFAULT_DICTIONARIES, max_frames: int = 300,
        repeat: int = 3, threads: int = 1, clock: str = "cpu", camera=None,
        apriltag: bool = True) -> dict:
    """Time the detectors on the frames of ``path``; the figures as a dict (seconds).

    Args:
        path: A video file or a folder of images.
        dictionaries: OpenCV dictionary names; each gets the shipped drick layouts with every
            code in it.
        max_frames: At most this many frames (from the start).
        repeat: Timed runs per frame and detector, the fastest kept.
        threads: OpenCV threads (1: one core, as on the drone's board).
        clock: ``cpu`` (the calling thread's CPU time) or ``wall``.
        camera: The :class:`~drovisio.camera.Camera` of the frames; None: a 60° pinhole of
            their size.
        apriltag: Also time AprilTag 3 on tag36h11 (when installed).
    """
    frames = read_frames(path, max_frames)
    H, W = frames[0].shape[:2]
    if camera is None:
        camera = Camera.from_fov(W, H, 60.0)
    elif (camera.width, camera.height) != (W, H):
        raise InputError(f"{path}: frames are {W}x{H} but --camera is for {camera.width}x"
                         f"{camera.height}; give the camera file of this video")
    normalized_grid(camera)  # once per camera, not a frame's work
    cv2.setNumThreads(max(1, int(threads)))
    tick = time.thread_time if clock == "cpu" else time.perf_counter
    base = [lay for lay in load_layouts([shipped_layouts_dir() / "drick-aruco-centre.json",
                                         shipped_layouts_dir() / "drick-aruco-pyramids.json"])
            if lay.has_codes]
    grays = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
    out: dict = {"source": str(path), "frames": len(frames), "size": [W, H],
                 "threads": threads, "clock": clock, "repeat": repeat, "dictionaries": {}}
    for dname in dictionaries:
        layouts = [with_dictionary(lay, dname) for lay in base]
        ours = ArucoBrickDetector(camera, layouts)
        plain = plain_detector(dname)
        peer = _apriltag_default() if apriltag and dname == "DICT_APRILTAG_36h11" else None
        ours.detect(frames[0])  # first call: lazy set-up, not a frame's work
        out["dictionaries"][dname] = _dictionary_row(frames, grays, ours, plain, peer,
                                                     repeat, tick)
        print(f"  ... {dname}: {len(frames)} frames timed", file=sys.stderr, flush=True)
    return out


def _dictionary_row(frames: list[np.ndarray], grays: list[np.ndarray],
                    ours: ArucoBrickDetector, plain: Any, peer: Any, repeat: int,
                    tick: Callable[[], float]) -> dict:
    """One dictionary's figures: each detector's fastest time per frame, summarised, and
    what each found."""
    t_o: list[float] = []
    t_p: list[float] = []
    t_a: list[float] = []
    bricks = codes_plain = tags = 0
    for f, g in zip(frames, grays):
        best, poses, ids, found = _time_frame(f, g, ours, plain, peer, repeat, tick)
        bricks += len(poses)
        codes_plain += 0 if ids is None else len(ids)
        t_o.append(best[0])
        t_p.append(best[1])
        if peer is not None:
            tags += len(found)
            t_a.append(best[2])
    row: dict = {"ours_s": _stats(t_o), "plain_s": _stats(t_p),
                 "ratio_plain": (_stats(t_o)[0] / _stats(t_p)[0],
                                 _stats(t_o)[1] / _stats(t_p)[1]),
                 "ratio_plain_per_frame_median": float(statistics.median(
                     o / p for o, p in zip(t_o, t_p))),
                 "bricks": bricks, "plain_codes": codes_plain}
    if t_a:
        row.update({"apriltag_s": _stats(t_a),
                    "ratio_apriltag": (_stats(t_o)[0] / _stats(t_a)[0],
                                       _stats(t_o)[1] / _stats(t_a)[1]),
                    "apriltag_tags": tags})
    return row


def _time_frame(f: np.ndarray, g: np.ndarray, ours: ArucoBrickDetector, plain: Any,
                peer: Any, repeat: int, tick: Callable[[], float]
                ) -> tuple[list[float], Any, Any, Any]:
    """Each detector ``repeat`` times on one frame (BGR ``f``, grey ``g``), their order
    alternating; (fastest times (s): ours, plain, AprilTag 3; the last results of each)."""
    best = [np.inf, np.inf, np.inf]
    poses = ids = found = None
    for rep in range(max(1, repeat)):
        order = (0, 1, 2) if rep % 2 == 0 else (2, 1, 0)
        for which in order:
            if which == 0:
                t0 = tick()
                poses = ours.detect(f)
                best[0] = min(best[0], tick() - t0)
            elif which == 1:
                t0 = tick()
                _, ids, _ = plain.detectMarkers(f)
                best[1] = min(best[1], tick() - t0)
            elif peer is not None:
                t0 = tick()
                found = peer.detect(g)
                best[2] = min(best[2], tick() - t0)
    return best, poses, ids, found


def report(data: dict) -> str:
    """The figures of :func:`run` as a table (milliseconds and ratios)."""
    lines = [f"{data['source']}: {data['frames']} frames {data['size'][0]}x{data['size'][1]}, "
             f"OpenCV threads {data['threads']}, {data['clock']} clock, fastest of "
             f"{data['repeat']} runs per frame",
             f"{'dictionary':<22}{'drovisio ms':>16}{'plain ms':>16}{'ratio':>13}"
             f"{'AprilTag3 ms':>16}{'ratio':>13}{'bricks':>8}",
             f"{'':<22}{'median / p90':>16}{'median / p90':>16}{'median / p90':>13}"
             f"{'median / p90':>16}{'median / p90':>13}"]
    for dname, r in data["dictionaries"].items():
        def ms(v):
            return f"{v[0] * 1e3:.2f} / {v[1] * 1e3:.2f}"

        def rt(v):
            return f"{v[0]:.2f} / {v[1]:.2f}"
        at = (f"{ms(r['apriltag_s']):>16}{rt(r['ratio_apriltag']):>13}" if "apriltag_s" in r
              else f"{'-':>16}{'-':>13}")
        lines.append(f"{dname:<22}{ms(r['ours_s']):>16}{ms(r['plain_s']):>16}"
                     f"{rt(r['ratio_plain']):>13}{at}{r['bricks']:>8}")
    lines.append("ratio: drovisio's median (p90) over plain detectMarkers' (default parameters, "
                 "the full dictionary) or AprilTag 3's (default settings: decimate 2) median "
                 "(p90), same frames, same process.")
    return "\n".join(lines)
