"""``drovisio bench aruco``: speed and accuracy of the ArUco brick detector on rendered scenes.

Scenes are drawn by :func:`drovisio.scenes.random_scene` (640×480 60° lens with distortion,
0.4–2 m, tilt up to 40°, gravel/grass/clutter, blur, noise, JPEG; bricks alternate between
the given layouts, by default one centre code / two pyramid codes) with 1, 4 and 16 bricks,
plus frames of ground and clutter with no brick at all.

Per frame, in the same run and on the same image:

* **time** of the whole ``ArucoBrickDetector.detect`` (grey conversion, codes, corners, poses)
  against OpenCV's plain ``ArucoDetector(DetectorParameters()).detectMarkers`` (each timed
  ``--repeat`` times, interleaved, the fastest kept: other processes on the machine only ever
  add time). By default the clock is the calling thread's CPU time and OpenCV runs one
  thread (``--threads``), so the figure is the work done, not the machine's load; the plain
  detector's three threshold windows would run in parallel on more threads.
* **recall**: bricks with at least one code fully visible (ray-cast against every mesh),
  fully inside the image and ≥ 14 px across (square root of its projected area), that are
  reported with the right layout and instance; also by the size of the brick's largest such
  code (< 20, 20–30, > 30 px).
* **AprilTag 3** (``--apriltag``, needs ``pupil-apriltags``: ``pip install drovisio[peers]``)
  on the same grey frames (decimate 1, one thread, distortion left in: detection only): its
  recall by code size, false bricks and time against the same plain ``detectMarkers``. A
  brick counts as found when one of its codes' ids is reported. AprilTag 3 reads the
  layouts' own dictionaries (an ArUco one given to it as a family built from OpenCV's
  table: :mod:`drovisio.study.apriltag`); ``--dictionary DICT_APRILTAG_36h11`` gives every
  layout's codes that dictionary (the same ids).
* **errors** of every correctly identified brick: *lateral* = norm of the x/y error of tvec
  in the camera frame (mm); *depth* = |Δz| / z (%); *yaw* = rotation about the brick's z axis
  between truth and estimate (swing–twist, degrees); *flip* = total rotation error > 20°.
  Without gravity, flips that are not flagged ``ambiguous`` are counted apart (must be 0).
* **false bricks**: reported (layout, instance) not in the scene; on no-brick frames every
  report is false.
* **corners** (all frames): mean signed radial error (outward > 0) and RMS of our refined
  corners against the renderer's true projected corners, for fully visible codes, next to
  OpenCV's raw corners.

``--video PATH`` times the detector on real frames instead, beside plain ``detectMarkers``
and AprilTag 3 (:mod:`drovisio.bench.aruco_video`; e.g. OpenCV's ``vtest.avi`` from Debian's
``opencv-doc``).

Example::

    drovisio bench aruco --frames 80 --empty 200 --cache /tmp/aruco-frames
    drovisio bench aruco --dictionary DICT_APRILTAG_36h11 --apriltag --bricks 4 --frames 100
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np
import trimesh

from drovisio.bench import aruco_video
from drovisio.bench.aruco_report import FLIP_DEG, MIN_CODE_PX, SIZE_BINS, Rows, Stats, report
from drovisio.bench.cache import read_entry, write_entry
from drovisio.bounds import MAX_SUPERSAMPLING, ArgumentParser, whole
from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.detect.aruco import ArucoBrickDetector, CodeDetection, plain_detector
from drovisio.detect.corners import normalized_grid
from drovisio.detect.result import BrickPose
from drovisio.errors import InputError
from drovisio.fileio import atomic_write_text, check_output_path
from drovisio.layout import (
    LayoutError,
    MarkerLayout,
    aruco_dictionary_id,
    load_layouts,
    shipped_layouts_dir,
    with_dictionary,
)
from drovisio.pose import rotation_angle_deg, yaw_about_axis_deg
from drovisio.scenes import SceneSpec, gravity_in_camera, random_scene
from drovisio.study.apriltag import apriltag_reader
from drovisio.synth import BrickTruth, Scene, brick_mesh_for, render

__all__ = ["FLIP_DEG", "MIN_CODE_PX", "SIZE_BINS", "Frame", "Stats", "main"]


def _parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="drovisio bench aruco",
        description="Speed (vs plain cv2 ArucoDetector.detectMarkers) and accuracy (vs the "
                    "renderer's truth) of the ArUco brick detector on rendered drick scenes.",
        epilog="Example:\n  drovisio bench aruco --frames 80 --empty 200 --cache /tmp/aruco-frames"
               "\n  drovisio bench aruco --frames 5 --empty 10   # a quick look",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=whole(1, 100_000), default=80,
                   help="frames per brick count (default 80)")
    p.add_argument("--bricks", default="1,4,16",
                   help="brick counts, comma-separated (default 1,4,16)")
    p.add_argument("--empty", type=whole(0, 100_000), default=200,
                   help="frames with no brick (ground, clutter, props) for false positives "
                        "(default 200)")
    p.add_argument("--seed", type=whole(0, 2**32 - 1), default=0, help="first scene seed (default 0)")
    p.add_argument("--layout", action="append", metavar="LAYOUT.json",
                   help="layouts of the bricks (default: the shipped drick-aruco-centre and "
                        "drick-aruco-pyramids)")
    p.add_argument("--threads", type=whole(1, 256), default=1,
                   help="OpenCV threads for both detectors (default 1)")
    p.add_argument("--repeat", type=whole(1, 1000), default=3,
                   help="timed runs per frame and detector, fastest kept (default 3)")
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                   help="cpu: CPU time of the calling thread (default; with --threads 1 it "
                        "is all the work, and other processes on the machine do not count); "
                        "wall: elapsed time")
    p.add_argument("--ss", type=whole(1, MAX_SUPERSAMPLING), default=3,
                   help="renderer supersampling (default 3)")
    p.add_argument("--dictionary", metavar="DICT",
                   help="give every layout's codes this dictionary (same ids), e.g. "
                        "DICT_APRILTAG_36h11")
    p.add_argument("--apriltag", action="store_true",
                   help="also run AprilTag 3 (pupil-apriltags; pip install drovisio[peers]) "
                        "on the same frames: recall by code size, false bricks, time")
    p.add_argument("--cache", type=Path, metavar="DIR",
                   help="keep rendered frames here and reuse them on the next run")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON")
    p.add_argument("--video", type=Path, metavar="PATH",
                   help="time the detector on real frames instead (a video file or a folder "
                        "of images; no truth): drovisio vs plain detectMarkers vs AprilTag 3, "
                        "medians and p90, per dictionary (4x4, 6x6, tag36h11; --dictionary: "
                        "one). E.g. OpenCV's vtest.avi, Debian's opencv-doc: "
                        "/usr/share/doc/opencv-doc/examples/data/vtest.avi")
    p.add_argument("--max-frames", type=whole(1, 100_000), default=300, metavar="N",
                   help="with --video: at most this many frames (default 300)")
    p.add_argument("--camera", type=Path, metavar="CAMERA_FILE",
                   help="with --video: the frames' camera file (default: a 60 deg pinhole "
                        "of their size)")
    return p


# ----------------------------------------------------------------------------- frames
@dataclass
class Frame:
    image: np.ndarray
    """BGR uint8 (H, W, 3)."""
    bricks: list[BrickTruth]
    gravity: np.ndarray
    """(3,) gravity in the camera frame."""
    visible: dict[int, float]
    """marker id -> fraction of sample points seen"""
    blur: float
    """Blur sigma of the frame, px."""


def _placed(mesh: Any, world_from_object: np.ndarray) -> Any:
    """A copy of a trimesh mesh, moved into the world."""
    m = mesh.copy()
    m.apply_transform(world_from_object)
    return m


def _visibility(scene: Scene) -> dict[int, float]:
    """Fraction of 9 points of each code (corners, half-way, centre) not hidden by a mesh."""
    meshes = [_placed(brick_mesh_for(b.layout), b.world_from_brick) for b in scene.bricks]
    meshes += [_placed(pr.mesh, pr.world_from_object) for pr in scene.props]
    out: dict[int, float] = {}
    if not meshes:
        return out
    big: Any = trimesh.util.concatenate(meshes)
    eye = np.linalg.inv(scene.camera_from_world)[:3, 3]
    for b in scene.bricks:
        lay = b.layout
        if not lay.has_codes:
            continue
        for slot, c in lay.code_corners_m().items():
            mid = lay.marker_id(cast(int, b.instance), slot)  # a coded brick has one
            ctr = c.mean(axis=0)
            pts = np.concatenate([ctr + 0.97 * (c - ctr), ctr + 0.5 * (c - ctr), ctr[None]])
            pw = pts @ b.world_from_brick[:3, :3].T + b.world_from_brick[:3, 3]
            dirs = pw - eye
            dist = np.linalg.norm(dirs, axis=1)
            dirs /= dist[:, None]
            loc, ri, _ = big.ray.intersects_location(np.repeat(eye[None], len(pw), 0), dirs,
                                                     multiple_hits=True)
            ok = np.ones(len(pw), bool)
            for p_, r in zip(loc, ri):
                if np.linalg.norm(p_ - eye) < dist[r] - 2e-3:
                    ok[r] = False
            out[mid] = float(ok.mean())
    return out


CACHE_SCHEMA = "drovisio/bench-aruco-frame@1"
"""What a ``--cache`` entry's truth says it is: any other is stale, rendered again."""


def _truth_json(fr: Frame) -> dict[str, Any]:
    """A frame's truth as a cache entry writes it (JSON floats read back exactly)."""
    return {"schema": CACHE_SCHEMA, "gravity": fr.gravity.tolist(), "blur": fr.blur,
            "visible": {str(k): v for k, v in fr.visible.items()},
            "bricks": [{"layout": b.layout, "instance": b.instance,
                        "camera_from_brick": b.camera_from_brick.tolist(),
                        "code_ids": b.code_ids,
                        "code_corners_px": {str(k): c.tolist()
                                            for k, c in b.code_corners_px.items()},
                        "dot_centers_px": b.dot_centers_px.tolist()} for b in fr.bricks]}


def _array(v: object, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(v, np.float64).reshape(shape)
    if not np.all(np.isfinite(a)):
        raise ValueError("a number that is not finite")
    return a


def _frame_of(image: np.ndarray, truth: Any, size: tuple[int, int]) -> Frame:
    """A cached frame from its picture and truth (:func:`_truth_json`).

    Raises:
        ValueError, KeyError, TypeError: not an entry of this version (ValueError: why).
    """
    if not isinstance(truth, dict) or truth.get("schema") != CACHE_SCHEMA:
        raise ValueError(f"not a {CACHE_SCHEMA} entry")
    if image.shape != (size[1], size[0], 3):
        raise ValueError(f"its picture is not {size[0]}x{size[1]}")
    bricks = [BrickTruth(layout=str(b["layout"]),
                         instance=None if b["instance"] is None else int(b["instance"]),
                         camera_from_brick=_array(b["camera_from_brick"], (4, 4)),
                         code_ids=[int(i) for i in b["code_ids"]],
                         code_corners_px={int(k): _array(c, (4, 2))
                                          for k, c in b["code_corners_px"].items()},
                         dot_centers_px=_array(b["dot_centers_px"], (-1, 2)))
              for b in truth["bricks"]]
    return Frame(image, bricks, _array(truth["gravity"], (3,)),
                 {int(k): float(v) for k, v in truth["visible"].items()}, float(truth["blur"]))


def _cached(stem: Path, size: tuple[int, int], stale: list[str]) -> Frame | None:
    """The frame of cache entry ``stem`` (``stem.png`` + ``stem.json``), or None: not there, or
    stale (an older version's pickle, which is never read; an entry the readers or
    :func:`_frame_of` refuse), said in ``stale``."""
    png, js, pkl = (Path(f"{stem}{ext}") for ext in (".png", ".json", ".pkl"))
    try:
        got = read_entry(png, js)
    except ValueError as e:
        stale.append(str(e))
        return None
    if got is None:
        if pkl.exists():
            stale.append(f"{pkl}: a cache entry of an older version (a pickle: never read, "
                         "loading one can run code)")
        return None
    try:
        return _frame_of(*got, size)
    except ValueError as e:
        stale.append(f"{js}: {e}")
    except (KeyError, TypeError, AttributeError):   # a field missing or of another kind
        stale.append(f"{js}: not a {CACHE_SCHEMA} entry")
    return None


def _frames(kind: str, n_bricks: int, count: int, seed0: int,
            layouts: list[MarkerLayout], ss: int, cache: Path | None,
            stale: list[str] | None = None) -> Iterator[Frame]:
    """The frames of one scene kind, from ``cache`` where it holds them; a stale entry is
    rendered again and replaced (the first said in one line on stderr, all counted in
    ``stale``)."""
    stale = [] if stale is None else stale
    spec = SceneSpec(layouts=layouts, n_bricks=n_bricks, props=4 if n_bricks == 0 else 0)
    names = "+".join(lay.name for lay in layouts)
    cam = Camera.drone_webcam()   # random_scene's camera
    for i in range(count):
        seed = seed0 + 100_000 * (n_bricks + 1) + i
        stem = None
        if cache is not None:
            stem = cache / f"{kind}-{names}-b{n_bricks}-s{seed}-ss{ss}"
            said = len(stale)
            fr = _cached(stem, (cam.width, cam.height), stale)
            if fr is not None:
                yield fr
                continue
            if said == 0 and stale:
                print(f"bench aruco --cache: {stale[0]}; rendering the frame again (and any "
                      "other stale entry)", file=sys.stderr)
        scene, fx = random_scene(seed, spec)
        r = render(scene, fx, ss=ss)
        fr = Frame(r.image, r.bricks, gravity_in_camera(r.camera_from_world),
                   _visibility(scene), float(fx.blur_sigma_px))
        if stem is not None:
            write_entry(Path(f"{stem}.png"), Path(f"{stem}.json"), fr.image, _truth_json(fr))
        yield fr


# ----------------------------------------------------------------------------- metrics
def _size_px(c: np.ndarray) -> float:
    """Square root of the area of the (4, 2) polygon ``c``, px."""
    x, y = c[:, 0], c[:, 1]
    return math.sqrt(0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))))


def _countable(truth: BrickTruth, fr: Frame, w: int, h: int) -> float | None:
    """The size (px across) of the brick's largest code that counts for recall, or None."""
    best = None
    for mid, c in truth.code_corners_px.items():
        if fr.visible.get(mid, 0.0) < 1.0:
            continue
        if c.min() < 2 or c[:, 0].max() > w - 3 or c[:, 1].max() > h - 3:
            continue
        size = _size_px(c)
        if size >= MIN_CODE_PX and (best is None or size > best):
            best = size
    return best


def _size_bin(size: float) -> str:
    return next(name for lo, hi, name in SIZE_BINS if lo <= size < hi)


def _errors(st: Stats, poses: Sequence[BrickPose], fr: Frame, w: int, h: int) -> None:
    """Pose errors of the bricks found, false bricks and recall of one frame."""
    truth = {(b.layout, b.instance): b for b in fr.bricks}
    seen = set()
    for bp in poses:
        t = truth.get((bp.layout, bp.instance))
        if t is None:
            st.false += 1
            continue
        seen.add((bp.layout, bp.instance))
        st.poses += 1
        R = cv2.Rodrigues(np.asarray(bp.rvec, np.float64).reshape(3, 1))[0]
        Rt = t.camera_from_brick[:3, :3]
        dt = np.ravel(bp.tvec) - t.tvec
        st.lateral_mm.append(1000 * float(np.hypot(dt[0], dt[1])))
        st.depth_pct.append(100 * abs(float(dt[2])) / float(t.tvec[2]))
        st.yaw_deg.append(abs(yaw_about_axis_deg(Rt, R)))
        flip = rotation_angle_deg(Rt, R) > FLIP_DEG
        st.flips += flip
        st.unflagged_flips += flip and not bp.ambiguous
        st.ambiguous += bool(bp.ambiguous)
    _recall(st, truth, seen, fr, w, h)


def _recall(st: Stats, truth: dict[tuple[str, int | None], BrickTruth],
            seen: set[tuple[str, int | None]], fr: Frame, w: int, h: int) -> None:
    for key, t in truth.items():
        size = _countable(t, fr, w, h)
        if size is not None:
            st.countable += 1
            st.found += key in seen
            b = st.by_size.setdefault(_size_bin(size), [0, 0])
            b[0] += 1
            b[1] += key in seen


def _apriltag_detector(dictionaries: list[str]) -> tuple[Any, str | None]:
    """AprilTag 3 for the layouts' codes (any dictionary: :mod:`drovisio.study.apriltag`),
    or a one-line reason why it cannot run."""
    try:
        import pupil_apriltags  # noqa: F401 - an optional dependency, only asked whether present
    except ImportError:
        return None, "AprilTag 3 is not installed: pip install drovisio[peers]"
    return apriltag_reader(dictionaries), None


def _peer_errors(st: Stats, tags: Sequence[Any], fr: Frame,
                 owners: dict[int, tuple[str, int]], w: int, h: int) -> None:
    """AprilTag's tags → bricks (one id is enough), false bricks and recall."""
    truth = {(b.layout, b.instance): b for b in fr.bricks}
    seen: set[tuple[str, int | None]] = set()
    for tag in tags:
        key = owners.get(tag.marker_id)
        if key is None or key not in truth:
            st.false += 1
        else:
            seen.add(key)
    st.poses += len(seen)
    _recall(st, truth, seen, fr, w, h)


def _corner_errors(codes: Sequence[CodeDetection], fr: Frame,
                   acc: dict[str, list[float]]) -> None:
    """Signed radial and squared errors (px) of the raw and refined corners of every fully
    visible code of a sharp frame, against the renderer's true corners."""
    truth = {mid: c for b in fr.bricks for mid, c in b.code_corners_px.items()}
    for c in codes:
        tc = truth.get(c.marker_id)
        if tc is None or fr.visible.get(c.marker_id, 0.0) < 1.0 or fr.blur > 1.0:
            continue
        ctr = tc.mean(axis=0)
        rad = (tc - ctr) / np.linalg.norm(tc - ctr, axis=1)[:, None]
        for name, est in (("raw", c.raw_corners), ("ours", None if c.refined is None or
                                                   not c.refined.ok else c.refined.corners_px)):
            if est is None:
                continue
            e = est - tc
            acc.setdefault(name + "_radial", []).extend((e * rad).sum(axis=1).tolist())
            acc.setdefault(name + "_sq", []).extend((e ** 2).sum(axis=1).tolist())


# ----------------------------------------------------------------------------- main
class _Refused(Exception):
    """An option the benchmark cannot run with (one line, exit 2)."""


@dataclass
class _Bench:
    """What every frame is measured with."""

    counts: list[int]
    """Brick counts of the scenes."""
    coded: list[MarkerLayout]
    det_g: ArucoBrickDetector
    """The detector given gravity (timed)."""
    det_n: ArucoBrickDetector
    """The detector without gravity."""
    plain: Any
    """OpenCV's plain ``ArucoDetector`` (the time reference)."""
    peer: Any
    """AprilTag 3, or None."""
    owners: dict[int, tuple[str, int]]
    """Marker id → (layout, instance)."""
    clock: Callable[[], float]
    repeat: int
    width: int
    height: int


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.json:
        check_output_path(args.json, "--json", folder_must_exist=True)
    if args.video is not None:
        return _video_main(args)
    cv2.setNumThreads(max(1, args.threads))
    try:
        bench = _setup(args)
    except _Refused as e:
        print(f"drovisio bench aruco: {e}", file=sys.stderr)
        return 2
    corner_acc: dict[str, list[float]] = {}
    rows = _run(bench, args, corner_acc)
    out = report(rows, corner_acc, args)
    print(out["text"])
    if args.json:
        atomic_write_text(args.json, json.dumps(out["data"], indent=2) + "\n")
    return 0


def _setup(args: argparse.Namespace) -> _Bench:
    """Layouts, detectors and clock from the options.

    Raises:
        _Refused: brick counts that are not numbers, layouts that cannot be read or have no
            codes, an unknown dictionary, AprilTag 3 asked for but unable to run.
    """
    clock = time.thread_time if args.clock == "cpu" else time.perf_counter
    paths = args.layout or [shipped_layouts_dir() / "drick-aruco-centre.json",
                            shipped_layouts_dir() / "drick-aruco-pyramids.json"]
    try:
        counts = [int(x) for x in args.bricks.split(",") if x.strip()]
    except ValueError:
        raise _Refused(f"--bricks: {args.bricks!r} is not a list of whole numbers (e.g. "
                       "1,4,16)") from None
    coded = _coded_layouts(paths, args.dictionary)
    peer = None
    if args.apriltag:
        peer, why_not = _apriltag_detector(sorted({d for lay in coded
                                                   for d in lay.dictionaries()}))
        if peer is None:
            raise _Refused(f"--apriltag: {why_not}")
    owners = {lay.marker_id(k, slot): (lay.name, k) for lay in coded
              for k in range(lay.instances or 0) for slot in lay.code_dictionaries()}
    cam = Camera.drone_webcam()
    normalized_grid(cam)  # one-off per camera, not part of a frame's time
    return _Bench(counts, coded, ArucoBrickDetector(cam, coded), ArucoBrickDetector(cam, coded),
                  plain_detector(coded[0].dictionaries()[0]), peer, owners, clock,
                  max(1, args.repeat), cam.width, cam.height)


def _coded_layouts(paths: list[Path], dictionary: str | None) -> list[MarkerLayout]:
    """The layouts that have codes, with ``dictionary`` given to every code when set.

    Raises:
        _Refused: a layout that cannot be read, none with codes, an unknown dictionary.
    """
    try:
        layouts = load_layouts(paths)
    except (LayoutError, ValueError) as e:
        raise _Refused(str(e)) from None
    coded = [lay for lay in layouts if lay.has_codes]
    if not coded:
        raise _Refused("no layout with ArUco codes given")
    if dictionary:
        try:
            coded = [with_dictionary(lay, dictionary) for lay in coded]
        except (LayoutError, ValueError) as e:
            raise _Refused(f"--dictionary: {e}") from None
    return coded


def _run(bench: _Bench, args: argparse.Namespace, corner_acc: dict[str, list[float]]) -> Rows:
    """Every scene kind and brick count, frame by frame; progress on stderr."""
    rows: Rows = {}
    plan = [("bricks", n, args.frames) for n in bench.counts] + (
        [("empty", 0, args.empty)] if args.empty > 0 else [])
    t_start = time.perf_counter()
    stale: list[str] = []   # the cache's stale entries, the first said once
    for kind, n_b, count in plan:
        st_g, st_n, st_p = Stats(), Stats(), Stats()
        for fr in _frames(kind, n_b, count, args.seed, bench.coded, args.ss, args.cache,
                          stale):
            _measure(bench, fr, (st_g, st_n, st_p), corner_acc)
        rows[(kind, n_b)] = (st_g, st_n, st_p)
        print(f"  ... {kind} {n_b}: {count} frames done ({time.perf_counter() - t_start:.0f} s)",
              file=sys.stderr)
    return rows


def _measure(bench: _Bench, fr: Frame, stats: tuple[Stats, Stats, Stats],
             corner_acc: dict[str, list[float]]) -> None:
    """One frame: timed with gravity against plain OpenCV, again without gravity, the
    corners, and AprilTag 3 when it runs."""
    st_g, st_n, st_p = stats
    w, h = bench.width, bench.height
    gray = cv2.cvtColor(fr.image, cv2.COLOR_BGR2GRAY)
    poses_g = _timed_against_plain(bench, fr, st_g)
    st_g.frames += 1
    _errors(st_g, poses_g, fr, w, h)
    poses_n = bench.det_n.detect(fr.image)
    st_n.frames += 1
    _errors(st_n, poses_n, fr, w, h)
    _corner_errors(bench.det_g.detect_codes(gray), fr, corner_acc)
    if bench.peer is not None:
        tp = []
        for _ in range(bench.repeat):
            t0 = bench.clock()
            tags = bench.peer.detect(gray)
            tp.append(bench.clock() - t0)
        st_p.t_peer.append(min(tp))
        st_p.frames += 1
        _peer_errors(st_p, tags, fr, bench.owners, w, h)


def _timed_against_plain(bench: _Bench, fr: Frame, st: Stats) -> list[BrickPose]:
    """The detector given gravity and plain ``detectMarkers``, each run ``repeat`` times,
    interleaved (their order alternates), the fastest of each kept in ``st``."""
    tp, to = [], []
    poses: list[BrickPose] = []
    for rep in range(bench.repeat):
        order = (0, 1) if rep % 2 == 0 else (1, 0)
        for which in order:
            t0 = bench.clock()
            if which == 0:
                bench.plain.detectMarkers(fr.image)
                tp.append(bench.clock() - t0)
            else:
                poses = bench.det_g.detect(fr.image, gravity=fr.gravity)
                to.append(bench.clock() - t0)
    st.t_plain.append(min(tp))
    st.t_ours.append(min(to))
    return poses


def _video_main(args: argparse.Namespace) -> int:
    """``--video``: timing on real frames (:mod:`drovisio.bench.aruco_video`)."""
    dicts = (args.dictionary,) if args.dictionary else aruco_video.DEFAULT_DICTIONARIES
    for d in dicts:
        try:
            aruco_dictionary_id(d)
        except ValueError as e:
            raise InputError(f"--dictionary: {e}") from None
    camera = None
    if args.camera is not None:
        camera = load_camera(args.camera)
    data = aruco_video.run(args.video, dicts, max_frames=args.max_frames, repeat=args.repeat,
                           threads=args.threads, clock=args.clock, camera=camera,
                           apriltag=True)
    print(aruco_video.report(data))
    if args.json:
        atomic_write_text(args.json, json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
