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
  brick counts as found when one of its codes' ids is reported. ``--dictionary
  DICT_APRILTAG_36h11`` gives every layout's codes that dictionary (the same ids), so the
  two detectors read the same codes.
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
import pickle
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drovisio.bounds import MAX_SUPERSAMPLING, ArgumentParser, whole

FLIP_DEG = 20.0
MIN_CODE_PX = 14.0
#: recall is also reported by the size of a brick's largest countable code (px across)
SIZE_BINS = ((MIN_CODE_PX, 20.0, "14-20 px"), (20.0, 30.0, "20-30 px"), (30.0, math.inf, ">30 px"))


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
                        "DICT_APRILTAG_36h11 to compare with AprilTag 3")
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
    p.add_argument("--max-frames", type=int, default=300, metavar="N",
                   help="with --video: at most this many frames (default 300)")
    p.add_argument("--camera", type=Path, metavar="CAMERA_FILE",
                   help="with --video: the frames' camera file (default: a 60 deg pinhole "
                        "of their size)")
    return p


# ----------------------------------------------------------------------------- frames
@dataclass
class Frame:
    image: np.ndarray
    bricks: list  # BrickTruth
    gravity: np.ndarray
    visible: dict  # marker id -> fraction of sample points seen
    blur: float


def _visibility(scene) -> dict[int, float]:
    """Fraction of 9 points of each code (corners, half-way, centre) not hidden by a mesh."""
    import trimesh

    from drovisio.synth import brick_mesh_for

    meshes = []
    for b in scene.bricks:
        m = brick_mesh_for(b.layout).copy()
        m.apply_transform(b.world_from_brick)
        meshes.append(m)
    for pr in scene.props:
        m = pr.mesh.copy()
        m.apply_transform(pr.world_from_object)
        meshes.append(m)
    out: dict[int, float] = {}
    if not meshes:
        return out
    big = trimesh.util.concatenate(meshes)
    eye = np.linalg.inv(scene.camera_from_world)[:3, 3]
    for b in scene.bricks:
        if not b.layout.has_codes:
            continue
        for slot, c in b.layout.code_corners_m().items():
            mid = b.layout.marker_id(b.instance, slot)
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


def _frames(kind: str, n_bricks: int, count: int, seed0: int, layouts, ss: int,
            cache: Path | None):
    from drovisio.scenes import SceneSpec, gravity_in_camera, random_scene
    from drovisio.synth import render

    spec = SceneSpec(layouts=layouts, n_bricks=n_bricks, props=4 if n_bricks == 0 else 0)
    names = "+".join(lay.name for lay in layouts)
    for i in range(count):
        seed = seed0 + 100_000 * (n_bricks + 1) + i
        path = None
        if cache is not None:
            path = cache / f"{kind}-{names}-b{n_bricks}-s{seed}-ss{ss}.pkl"
            if path.exists():
                try:
                    with open(path, "rb") as fh:
                        yield pickle.load(fh)
                    continue
                except Exception:  # noqa: BLE001,S110 - unpickling a stale or cut file can
                    pass           # raise almost anything (a renamed class: ImportError): render again
        scene, fx = random_scene(seed, spec)
        r = render(scene, fx, ss=ss)
        fr = Frame(r.image, r.bricks, gravity_in_camera(r.camera_from_world),
                   _visibility(scene), float(fx.blur_sigma_px))
        if path is not None:
            from drovisio.fileio import atomic_write_bytes

            # beside and renamed: a run killed mid-write leaves no half pickle behind
            atomic_write_bytes(path, pickle.dumps(fr), make_parents=True)
        yield fr


# ----------------------------------------------------------------------------- metrics
def _size_px(c: np.ndarray) -> float:
    x, y = c[:, 0], c[:, 1]
    return math.sqrt(0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))))


def _countable(truth, fr: Frame, w: int, h: int) -> float | None:
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


@dataclass
class Stats:
    frames: int = 0
    t_ours: list = field(default_factory=list)
    t_plain: list = field(default_factory=list)
    countable: int = 0
    found: int = 0
    false: int = 0
    lateral_mm: list = field(default_factory=list)
    depth_pct: list = field(default_factory=list)
    yaw_deg: list = field(default_factory=list)
    flips: int = 0
    unflagged_flips: int = 0
    ambiguous: int = 0
    poses: int = 0
    by_size: dict = field(default_factory=dict)
    """size bin -> [countable, found]"""
    t_peer: list = field(default_factory=list)
    """AprilTag 3's time per frame (the row with gravity holds AprilTag's figures)."""


def _pct(v: list, q: float) -> float:
    return float(np.percentile(v, q)) if v else float("nan")


def _errors(st: Stats, poses, fr: Frame, w: int, h: int) -> None:
    import cv2

    from drovisio.pose import rotation_angle_deg, yaw_about_axis_deg

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


def _recall(st: Stats, truth: dict, seen: set, fr: Frame, w: int, h: int) -> None:
    for key, t in truth.items():
        size = _countable(t, fr, w, h)
        if size is not None:
            st.countable += 1
            st.found += key in seen
            b = st.by_size.setdefault(_size_bin(size), [0, 0])
            b[0] += 1
            b[1] += key in seen


def _apriltag_detector(dictionaries: list[str]):
    """AprilTag 3 for the layouts' codes, or a one-line reason why it cannot run."""
    from drovisio.study.methods import APRILTAG_FAMILIES

    fams = sorted({APRILTAG_FAMILIES.get(d, "") for d in dictionaries})
    if "" in fams:
        return None, ("AprilTag 3 cannot read " + ", ".join(
            d for d in dictionaries if d not in APRILTAG_FAMILIES)
            + ": give --dictionary DICT_APRILTAG_36h11")
    try:
        import pupil_apriltags  # noqa: F401
    except ImportError:
        return None, "AprilTag 3 is not installed: pip install drovisio[peers]"
    from drovisio.study.methods import apriltag_detector

    return apriltag_detector(" ".join(fams)), None


def _peer_errors(st: Stats, tags, fr: Frame, owners: dict, w: int, h: int) -> None:
    """AprilTag's tags → bricks (one id is enough), false bricks and recall."""
    truth = {(b.layout, b.instance): b for b in fr.bricks}
    seen = set()
    for tag in tags:
        key = owners.get(int(tag.tag_id))
        if key is None or key not in truth:
            st.false += 1
        else:
            seen.add(key)
    st.poses += len(seen)
    _recall(st, truth, seen, fr, w, h)


def _corner_errors(codes, fr: Frame, acc: dict) -> None:
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
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.json:
        from drovisio.fileio import check_output_path

        check_output_path(args.json, "--json", folder_must_exist=True)
    if args.video is not None:
        return _video_main(args)
    import cv2

    from drovisio.camera import Camera
    from drovisio.detect.aruco import ArucoBrickDetector, plain_detector
    from drovisio.detect.corners import normalized_grid
    from drovisio.layout import LayoutError, load_layouts, shipped_layouts_dir, with_dictionary

    cv2.setNumThreads(max(1, args.threads))
    clock = time.thread_time if args.clock == "cpu" else time.perf_counter
    paths = args.layout or [shipped_layouts_dir() / "drick-aruco-centre.json",
                            shipped_layouts_dir() / "drick-aruco-pyramids.json"]
    try:
        counts = [int(x) for x in args.bricks.split(",") if x.strip()]
    except ValueError:
        print(f"drovisio bench aruco: --bricks: {args.bricks!r} is not a list of whole "
              "numbers (e.g. 1,4,16)", file=sys.stderr)
        return 2
    try:
        layouts = load_layouts(paths)
    except (LayoutError, ValueError) as e:
        print(f"drovisio bench aruco: {e}", file=sys.stderr)
        return 2
    coded = [lay for lay in layouts if lay.has_codes]
    if not coded:
        print("drovisio bench aruco: no layout with ArUco codes given", file=sys.stderr)
        return 2
    if args.dictionary:
        try:
            coded = [with_dictionary(lay, args.dictionary) for lay in coded]
        except (LayoutError, ValueError) as e:
            print(f"drovisio bench aruco: --dictionary: {e}", file=sys.stderr)
            return 2
    peer, why_not = (None, None)
    if args.apriltag:
        peer, why_not = _apriltag_detector(sorted({d for lay in coded
                                                   for d in lay.dictionaries()}))
        if peer is None:
            print(f"drovisio bench aruco: --apriltag: {why_not}", file=sys.stderr)
            return 2
    owners = {lay.marker_id(k, slot): (lay.name, k) for lay in coded
              for k in range(lay.instances or 0) for slot in lay.code_dictionaries()}
    cam = Camera.drone_webcam()
    normalized_grid(cam)  # one-off per camera, not part of a frame's time
    det_g = ArucoBrickDetector(cam, coded)
    det_n = ArucoBrickDetector(cam, coded)
    plain = plain_detector(coded[0].dictionaries()[0])
    W, H = cam.width, cam.height
    corner_acc: dict = {}
    rows: dict = {}
    plan = [("bricks", n, args.frames) for n in counts] + (
        [("empty", 0, args.empty)] if args.empty > 0 else [])
    t_start = time.perf_counter()
    for kind, n_b, count in plan:
        st_g, st_n, st_p = Stats(), Stats(), Stats()
        for fr in _frames(kind, n_b, count, args.seed, coded, args.ss, args.cache):
            gray = cv2.cvtColor(fr.image, cv2.COLOR_BGR2GRAY)
            tp, to = [], []
            poses_g = []
            for rep in range(max(1, args.repeat)):
                order = (0, 1) if rep % 2 == 0 else (1, 0)
                for which in order:
                    if which == 0:
                        t0 = clock()
                        plain.detectMarkers(fr.image)
                        tp.append(clock() - t0)
                    else:
                        t0 = clock()
                        poses_g = det_g.detect(fr.image, gravity=fr.gravity)
                        to.append(clock() - t0)
            st_g.t_plain.append(min(tp))
            st_g.t_ours.append(min(to))
            st_g.frames += 1
            _errors(st_g, poses_g, fr, W, H)
            poses_n = det_n.detect(fr.image)
            st_n.frames += 1
            _errors(st_n, poses_n, fr, W, H)
            _corner_errors(det_g.detect_codes(gray), fr, corner_acc)
            if peer is not None:
                tp = []
                for _ in range(max(1, args.repeat)):
                    t0 = clock()
                    tags = peer.detect(gray)
                    tp.append(clock() - t0)
                st_p.t_peer.append(min(tp))
                st_p.frames += 1
                _peer_errors(st_p, tags, fr, owners, W, H)
        rows[(kind, n_b)] = (st_g, st_n, st_p)
        print(f"  ... {kind} {n_b}: {count} frames done ({time.perf_counter() - t_start:.0f} s)",
              file=sys.stderr)
    report = _report(rows, corner_acc, args)
    print(report["text"])
    if args.json:
        from drovisio.fileio import atomic_write_text

        atomic_write_text(args.json, json.dumps(report["data"], indent=2) + "\n")
    return 0


def _video_main(args) -> int:
    """``--video``: timing on real frames (:mod:`drovisio.bench.aruco_video`)."""
    from drovisio.bench import aruco_video
    from drovisio.errors import InputError
    from drovisio.layout import aruco_dictionary_id

    if args.max_frames < 1:
        raise InputError(f"--max-frames {args.max_frames}: give a positive number of frames")
    dicts = (args.dictionary,) if args.dictionary else aruco_video.DEFAULT_DICTIONARIES
    for d in dicts:
        try:
            aruco_dictionary_id(d)
        except ValueError as e:
            raise InputError(f"--dictionary: {e}") from None
    camera = None
    if args.camera is not None:
        from drovisio.camera_file import load_camera

        camera = load_camera(args.camera)
    data = aruco_video.run(args.video, dicts, max_frames=args.max_frames, repeat=args.repeat,
                           threads=args.threads, clock=args.clock, camera=camera,
                           apriltag=True)
    print(aruco_video.report(data))
    if args.json:
        from drovisio.fileio import atomic_write_text

        atomic_write_text(args.json, json.dumps(data, indent=2) + "\n")
    return 0


def _fmt(x: float, nd: int = 1) -> str:
    return "  -  " if not np.isfinite(x) else f"{x:.{nd}f}"


def _report(rows: dict, corner_acc: dict, args) -> dict:
    lines = []
    data: dict = {"threads": args.threads, "repeat": args.repeat, "clock": args.clock,
                  "rows": []}
    hdr = (f"{'scene':<10}{'grav':>5}{'frames':>7}{'ours ms':>9}{'plain ms':>9}{'ratio':>7}"
           f"{'recall':>13}{'lat p50/p95 mm':>16}{'depth p50/p95 %':>17}"
           f"{'yaw p50/p95 deg':>17}{'flips':>7}{'unflag':>7}{'ambig':>7}{'false':>7}")
    lines.append(hdr)
    lines.append("-" * len(hdr))
    for (kind, n_b), triple in rows.items():
        pair = triple[:2]
        for grav, st in zip(("yes", "no"), pair):
            name = f"{n_b} brick" + ("s" if n_b != 1 else "") if kind == "bricks" else "no brick"
            t_o = statistics.median(pair[0].t_ours) * 1e3 if pair[0].t_ours else float("nan")
            t_p = statistics.median(pair[0].t_plain) * 1e3 if pair[0].t_plain else float("nan")
            # the median of per-frame ratios (both timed on the same frame, interleaved: the
            # machine's load cancels better than in a ratio of medians)
            ratio = (statistics.median(o / p for o, p in zip(pair[0].t_ours, pair[0].t_plain))
                     if pair[0].t_ours else float("nan"))
            timing = (f"{_fmt(t_o, 2):>9}{_fmt(t_p, 2):>9}{_fmt(ratio, 2):>7}"
                      if grav == "yes" else f"{'':>9}{'':>9}{'':>7}")
            rec = (f"{st.found}/{st.countable} {100 * st.found / st.countable:.1f}%"
                   if st.countable else "-")
            lines.append(
                f"{name:<10}{grav:>5}{st.frames:>7}{timing}{rec:>13}"
                f"{_fmt(_pct(st.lateral_mm, 50)):>7}/{_fmt(_pct(st.lateral_mm, 95)):<8}"
                f"{_fmt(_pct(st.depth_pct, 50), 2):>8}/{_fmt(_pct(st.depth_pct, 95), 2):<8}"
                f"{_fmt(_pct(st.yaw_deg, 50), 2):>8}/{_fmt(_pct(st.yaw_deg, 95), 2):<8}"
                f"{st.flips:>7}{st.unflagged_flips:>7}{st.ambiguous:>7}{st.false:>7}")
            data["rows"].append({
                "scene": kind, "bricks": n_b, "gravity": grav == "yes", "frames": st.frames,
                "ours_ms_median": t_o, "plain_ms_median": t_p, "ratio_per_frame_median": ratio,
                "ratio_of_medians": t_o / t_p,
                "countable": st.countable, "found": st.found, "poses": st.poses,
                "lateral_mm_p50": _pct(st.lateral_mm, 50), "lateral_mm_p95": _pct(st.lateral_mm, 95),
                "depth_pct_p50": _pct(st.depth_pct, 50), "depth_pct_p95": _pct(st.depth_pct, 95),
                "yaw_deg_p50": _pct(st.yaw_deg, 50), "yaw_deg_p95": _pct(st.yaw_deg, 95),
                "flips": st.flips, "unflagged_flips": st.unflagged_flips,
                "ambiguous": st.ambiguous, "false_bricks": st.false})
    # AprilTag 3 on the same frames
    for (kind, n_b), triple in rows.items():
        st = triple[2]
        if not st.frames:
            continue
        name = f"{n_b} brick" + ("s" if n_b != 1 else "") if kind == "bricks" else "no brick"
        t_a = statistics.median(st.t_peer) * 1e3
        ratio = statistics.median(a / p for a, p in zip(st.t_peer, triple[0].t_plain))
        rec = f"{st.found}/{st.countable} {100 * st.found / st.countable:.1f}%" \
            if st.countable else "-"
        lines.append(f"{name:<10}{'AT3':>5}{st.frames:>7}{_fmt(t_a, 2):>9}"
                     f"{_fmt(statistics.median(triple[0].t_plain) * 1e3, 2):>9}"
                     f"{_fmt(ratio, 2):>7}{rec:>13}{'':>67}{st.false:>7}")
        data["rows"].append({"scene": kind, "bricks": n_b, "method": "apriltag3",
                             "frames": st.frames, "apriltag_ms_median": t_a,
                             "ratio_per_frame_median": ratio, "countable": st.countable,
                             "found": st.found, "false_bricks": st.false})
    # totals over brick scenes
    for gi, grav in enumerate(("yes", "no")):
        sts = [t[gi] for (kind, _), t in rows.items() if kind == "bricks"]
        if not sts:
            continue
        cnt = sum(s.countable for s in sts)
        fnd = sum(s.found for s in sts)
        lat = [x for s in sts for x in s.lateral_mm]
        dep = [x for s in sts for x in s.depth_pct]
        yaw = [x for s in sts for x in s.yaw_deg]
        lines.append(
            f"{'all':<10}{grav:>5}{sum(s.frames for s in sts):>7}{'':>25}"
            f"{(f'{fnd}/{cnt} {100 * fnd / cnt:.1f}%' if cnt else '-'):>13}"
            f"{_fmt(_pct(lat, 50)):>7}/{_fmt(_pct(lat, 95)):<8}"
            f"{_fmt(_pct(dep, 50), 2):>8}/{_fmt(_pct(dep, 95), 2):<8}"
            f"{_fmt(_pct(yaw, 50), 2):>8}/{_fmt(_pct(yaw, 95), 2):<8}"
            f"{sum(s.flips for s in sts):>7}{sum(s.unflagged_flips for s in sts):>7}"
            f"{sum(s.ambiguous for s in sts):>7}{sum(s.false for s in sts):>7}")
    # recall by code size, over brick scenes (with gravity; AprilTag 3 when run)
    methods = [("drovisio", 0)] + ([("apriltag3", 2)] if any(
        t[2].frames for t in rows.values()) else [])
    data["recall_by_size"] = {}
    for mname, i in methods:
        sts = [t[i] for (kind, _), t in rows.items() if kind == "bricks"]
        cells = []
        data["recall_by_size"][mname] = {}
        for _, _, bname in SIZE_BINS:
            c = sum(s.by_size.get(bname, [0, 0])[0] for s in sts)
            f = sum(s.by_size.get(bname, [0, 0])[1] for s in sts)
            data["recall_by_size"][mname][bname] = {"countable": c, "found": f,
                                                    "recall": f / c if c else None}
            cells.append(f"{bname} {f}/{c} {100 * f / c:.1f}%" if c else f"{bname} -")
        lines.append(f"recall by code size, {mname}: " + ", ".join(cells))
    lines.append("")
    clock = ("CPU time of the thread" if args.clock == "cpu" else "wall-clock time")
    lines.append(f"times: {clock}, median over frames of the fastest of {args.repeat} runs, "
                 f"OpenCV threads = {args.threads}; ratio: median over frames of ours (whole "
                 "detect + pose, gravity given) / plain detectMarkers (default parameters) "
                 "on the same frame.")
    lines.append("lateral: x/y error of tvec in the camera frame; depth: |dz|/z; yaw: rotation "
                 "about the brick's z axis; flip: rotation error > 20 deg;")
    lines.append("unflag: flips not flagged ambiguous; recall: bricks with a fully visible code "
                 f">= {MIN_CODE_PX:g} px across (sqrt of its area) reported with the right id; AT3: "
                 "AprilTag 3 (pupil-apriltags, decimate 1) on the same frames.")
    for name in ("raw", "ours"):
        rad = corner_acc.get(name + "_radial", [])
        sq = corner_acc.get(name + "_sq", [])
        if rad:
            lines.append(f"corners {name:<5} (blur <= 1 px, {len(rad)} corners): mean signed "
                         f"radial {np.mean(rad):+.3f} px, RMS {math.sqrt(np.mean(sq)):.3f} px")
            data[f"corners_{name}"] = {"n": len(rad), "mean_radial_px": float(np.mean(rad)),
                                       "rms_px": math.sqrt(float(np.mean(sq)))}
    return {"text": "\n".join(lines), "data": data}


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
