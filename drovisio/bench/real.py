"""``drovisio bench real DIR...``: Drovisio beside plain OpenCV and AprilTag 3 on real pictures.

Each folder is one data set of pictures nobody here rendered; its kind is found from what it
holds:

* **tags** — photos of AprilTag or ArUco codes with a camera file (``camera.yaml``): the
  dictionary is the one that reads most codes in the first photos; every id is its own
  one-code brick (``--tag-size`` metres). Drovisio's
  :class:`~drovisio.detect.aruco.ArucoBrickDetector` beside OpenCV's ``ArucoDetector``
  (default parameters) and AprilTag 3 (``pupil-apriltags``, decimate 1, one thread; the
  ``peers`` extra: said when absent): codes found, corners against AprilTag's (OpenCV's
  pixel convention: AprilTag's corners − 0.5 px), poses (the same IPPE on each method's
  corners; Drovisio's own pose), codes read more than once in a photo, time per photo.
* **charuco** — a ChArUco photo with its camera file: the board is guessed from the codes
  (contiguous ids from 0, the rows × columns that hold them, OpenCV's tutorial proportions:
  squares 0.04 m, codes 0.02 m; ``--board charuco:COLSxROWS`` with inner corners and
  ``--square``/``--marker`` override); the codes are one brick. Codes found by Drovisio and
  by ``ArucoDetector``, their corners against the board pose's prediction (the board posed
  from OpenCV's ``CharucoDetector`` corners), Drovisio's brick pose against the board pose.
* **chessboard** — a calibration set: expected corners (OpenCV's ``*.dat``) and/or a
  reference camera file. Corners of Drovisio's finder and of ``findChessboardCorners`` +
  ``cornerSubPix`` (11×11) against the expected ones; ``drovisio calibrate`` (the model of
  the reference file, and ``auto``) and plain OpenCV (``calibrateCamera``, or
  ``fisheye.calibrate`` for a fisheye reference) against the reference's fx, fy, cx, cy.

Times are medians per photo in one process, OpenCV on one thread (``--repeat`` runs, the
fastest kept). ``--json FILE`` writes the figures through the verified writer.

Example::

    drovisio bench real ../shared/datasets/real/apriltag-multi ../shared/datasets/real/charuco
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio.errors import InputError

__all__ = ["charuco_layout", "detect_kind", "main", "tag_layout"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: dictionaries tried on tag photos, most specific first
TAG_DICTIONARIES = ("DICT_APRILTAG_36h11", "DICT_APRILTAG_25h9", "DICT_APRILTAG_16h5",
                    "DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_250",
                    "DICT_ARUCO_ORIGINAL")
#: chessboard sizes (inner corners) tried when a set says none
CHESS_SIZES = ((9, 6), (8, 6), (7, 6), (7, 5), (5, 7), (6, 9), (6, 8), (10, 7), (11, 8),
               (6, 4), (8, 5), (4, 6), (5, 4))
MAX_IMAGES = 200
APRILTAG_PIXEL_OFFSET = 0.5
"""AprilTag's corners minus OpenCV's for the same pixels (AprilTag: pixel centres at +0.5)."""


# --------------------------------------------------------------------------- layouts
def tag_layout(dictionary: str, size_m: float, name: str = "tags"):
    """A layout whose every id of ``dictionary`` is its own one-code brick of ``size_m``."""
    from drovisio.layout import aruco_dictionary_size, parse_layout

    return parse_layout({
        "schema": "drovisio/marker-layout@1", "name": name, "units": "m",
        "first_id": 0, "ids_per_instance": 1,
        "instances": aruco_dictionary_size(dictionary), "symmetry": "none",
        "markers": [{"kind": "aruco", "dictionary": dictionary, "id": 0, "size": size_m,
                     "center": [0, 0, 0], "normal": [0, 0, 1], "up": [0, 1, 0]}]},
        "<bench real tags>")


def charuco_layout(board: cv2.aruco.CharucoBoard, dictionary: str, name: str = "charuco"):
    """The codes of a ChArUco board as one brick; brick frame: the board's, y flipped (up
    in the printed image) so that z points out of the board toward the camera."""
    from drovisio.layout import parse_layout

    ids = [int(i) for i in np.ravel(board.getIds())]
    size = float(board.getMarkerLength())
    markers = []
    for op, mid in zip(board.getObjPoints(), ids):
        pts = np.asarray(op, np.float64).reshape(4, 3)
        markers.append({"kind": "aruco", "dictionary": dictionary, "id": mid, "size": size,
                        "corners": [[float(p[0]), -float(p[1]), 0.0] for p in pts]})
    return parse_layout({"schema": "drovisio/marker-layout@1", "name": name, "units": "m",
                         "first_id": 0, "ids_per_instance": max(ids) + 1, "instances": 1,
                         "symmetry": "none", "markers": markers}, "<bench real charuco>")


def _board_pts_to_brick(p: Any) -> np.ndarray:
    q = np.asarray(p, np.float64).reshape(-1, 3).copy()
    q[:, 1] *= -1.0
    return q


# --------------------------------------------------------------------------- the folder
def _images(folder: Path) -> list[Path]:
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                   and not p.name.startswith("."))
    return files[:MAX_IMAGES]


def _camera_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file()
                  and p.suffix.lower() in (".yaml", ".yml", ".xml", ".json"))


def _read_gray(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: cannot be read as an image (remove it from the folder)")
    return img


def _aruco(dictionary: str) -> cv2.aruco.ArucoDetector:
    from drovisio.layout import aruco_dictionary_id

    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    return cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters())


def _best_dictionary(grays: list[np.ndarray]) -> tuple[str | None, int]:
    best, n_best = None, 0
    for name in TAG_DICTIONARIES:
        det = _aruco(name)
        n = 0
        for g in grays:
            _, ids, _ = det.detectMarkers(g)
            n += 0 if ids is None else len(ids)
        if n > n_best:
            best, n_best = name, n
    return best, n_best


def _guess_charuco(gray: np.ndarray, dictionary: str, ids: np.ndarray, square: float,
                   marker: float) -> cv2.aruco.CharucoBoard | None:
    """The board (squares cols × rows) whose codes are ids 0..m-1 and that gives the most
    ChArUco corners on the photo."""
    from drovisio.layout import aruco_dictionary_id

    m = int(ids.max()) + 1
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    best, n_best = None, 0
    for cols in range(3, 16):
        for rows in range(3, 16):
            if (cols * rows) // 2 != m:
                continue
            b = cv2.aruco.CharucoBoard((cols, rows), square, marker, d)
            cc, ci, _, _ = cv2.aruco.CharucoDetector(b).detectBoard(gray)
            n = 0 if ci is None else len(ci)
            if n > n_best:
                best, n_best = b, n
    return best if n_best >= 6 else None


def detect_kind(folder: Path) -> str:
    """``chessboard``, ``charuco`` or ``tags`` (module doc); InputError when none fits."""
    images = _images(folder)
    if not images:
        raise InputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
    if any(folder.glob("*.dat")):
        return "chessboard"
    grays = [_read_gray(p) for p in images[:3]]
    dictionary, n = _best_dictionary(grays)
    if dictionary is not None and n > 0:
        if "APRILTAG" not in dictionary:
            _, ids, _ = _aruco(dictionary).detectMarkers(grays[0])
            if ids is not None and _guess_charuco(grays[0], dictionary, np.ravel(ids),
                                                  0.04, 0.02) is not None:
                return "charuco"
        return "tags"
    for size in CHESS_SIZES:
        found, _ = cv2.findChessboardCorners(grays[0], size, None,
                                             cv2.CALIB_CB_ADAPTIVE_THRESH
                                             | cv2.CALIB_CB_NORMALIZE_IMAGE
                                             | cv2.CALIB_CB_FAST_CHECK)
        if found:
            return "chessboard"
    raise InputError(f"{folder}: neither codes nor a chessboard found in its first images "
                     "(give a folder of tag, ChArUco or chessboard photos)")


def _load_reference(folder: Path, required: bool):
    """The folder's camera file (the first one that loads), or None."""
    from drovisio.camera_file import load_camera

    errors = []
    for p in _camera_files(folder):
        try:
            return p, load_camera(p)
        except InputError as e:
            errors.append(str(e))
    if required:
        raise InputError(f"{folder}: no camera file that loads (camera.yaml, *.yml); "
                         + (errors[0] if errors else "add the camera file of these photos"))
    return None, None


# --------------------------------------------------------------------------- helpers
def _timed(fn: Callable[[], Any], repeat: int) -> tuple[Any, float]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def _match_corners(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-corner distances (4,) between two quads of one code, b's corners rolled (and
    mirrored: AprilTag turns the other way) to fit a's best."""
    best = None
    for cand in (b, b[::-1]):
        for k in range(4):
            d = np.linalg.norm(np.roll(cand, k, axis=0) - a, axis=1)
            if best is None or d.max() < best.max():
                best = d
    assert best is not None
    return best


def _ippe_pose(camera, size: float, corners: np.ndarray):
    obj = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]], np.float64) * size / 2
    xn = camera.normalize(np.asarray(corners, np.float64).reshape(4, 2))
    if not np.all(np.isfinite(xn)):
        return None
    ok, rv, tv = cv2.solvePnP(obj, xn.reshape(-1, 1, 2), np.eye(3), None,
                              flags=cv2.SOLVEPNP_IPPE_SQUARE)
    return (cv2.Rodrigues(rv)[0], tv.ravel()) if ok else None


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _stats(x) -> dict:
    a = np.asarray(list(x), np.float64)
    if a.size == 0:
        return {"n": 0, "median": None, "p90": None, "max": None}
    return {"n": int(a.size), "median": float(np.median(a)),
            "p90": float(np.percentile(a, 90)), "max": float(a.max())}


def _fmt(s: dict, unit: str = "", nd: int = 2) -> str:
    if not s["n"]:
        return "-"
    return (f"{s['median']:.{nd}f} / {s['p90']:.{nd}f} / {s['max']:.{nd}f}{unit} "
            f"(n {s['n']})")


def _apriltag(family: str):
    """AprilTag 3 for a family, or (None, why)."""
    try:
        from drovisio.study.methods import apriltag_detector

        return apriltag_detector(family), None
    except ImportError:
        return None, ("AprilTag 3 not installed (pip install drovisio[peers], i.e. "
                      "pupil-apriltags): its columns are left out")


# --------------------------------------------------------------------------- tags
def bench_tags(folder: Path, repeat: int, tag_size: float) -> dict:
    from drovisio.detect.aruco import ArucoBrickDetector
    from drovisio.study.methods import APRILTAG_FAMILIES

    cam_path, camera = _load_reference(folder, required=True)
    images = _images(folder)
    grays = [_read_gray(p) for p in images]
    dictionary, _ = _best_dictionary(grays[:3])
    if dictionary is None:
        raise InputError(f"{folder}: no codes of a known dictionary in its first photos")
    w, h = grays[0].shape[1], grays[0].shape[0]
    camera = camera.for_image(w, h)[0]
    det = ArucoBrickDetector(camera, [tag_layout(dictionary, tag_size)])
    cv_det = _aruco(dictionary)
    fam = APRILTAG_FAMILIES.get(dictionary)
    at, why_not = _apriltag(fam) if fam else (None, "AprilTag 3 reads no ArUco dictionary")
    det.detect(grays[0])      # warm-up: compiled kernels, tables
    rep: dict = {"kind": "tags", "folder": str(folder), "camera": str(cam_path),
                 "dictionary": dictionary, "tag_size_m": tag_size, "photos": len(images),
                 "apriltag": why_not or "pupil-apriltags, decimate 1, 1 thread"}
    n = {"drovisio": 0, "opencv": 0, "apriltag": 0, "drovisio_bricks": 0,
         "opencv_kept": 0, "duplicate_bricks": 0, "false": 0}
    c_ours_at, c_cv_at, c_ours_cv, rot_ours_at, rot_cv_at, t_ours_at = [], [], [], [], [], []
    times: dict[str, list[float]] = {"drovisio": [], "opencv": [], "apriltag": []}
    missed: list[str] = []
    for path, g in zip(images, grays):
        if g.shape != grays[0].shape:
            raise InputError(f"{path}: {g.shape[1]}x{g.shape[0]}, the others "
                             f"{w}x{h} (one camera file is for one size)")
        poses, t = _timed(partial(det.detect, g), repeat)
        times["drovisio"].append(t)
        (cq, ci, _), t = _timed(partial(cv_det.detectMarkers, g), repeat)
        times["opencv"].append(t)
        codes: list[Any] = [c for c in det.last_codes if c.refined is not None and c.refined.ok]
        n["drovisio"] += len(codes)
        n["drovisio_bricks"] += len(poses)
        n["duplicate_bricks"] += sum(bool(p.duplicate) for p in poses)
        cv = [(int(i), np.asarray(q, np.float64).reshape(4, 2))
              for q, i in zip(cq, np.ravel(ci))] if ci is not None else []
        n["opencv"] += len(cv)
        ats = []
        if at is not None:
            res, t = _timed(partial(at.detect, g), repeat)
            times["apriltag"].append(t)
            ats = [(int(r.tag_id), np.asarray(r.corners, np.float64) - APRILTAG_PIXEL_OFFSET)
                   for r in res]
            n["apriltag"] += len(ats)

        def near(q, pool):
            c = q.mean(axis=0)
            side = float(np.linalg.norm(q[1] - q[0]))
            for i, p in pool:
                if np.linalg.norm(p.mean(axis=0) - c) < 0.3 * side:
                    return i, p
            return None

        for mid, q in cv:   # every code OpenCV reads: kept by Drovisio?
            m = next((c for c in codes if c.marker_id == mid
                      and np.linalg.norm(c.refined.corners_px.mean(0) - q.mean(0))
                      < 0.3 * np.linalg.norm(q[1] - q[0])), None)
            if m is None:
                missed.append(f"{path.name}:{mid}")
                continue
            n["opencv_kept"] += 1
            c_ours_cv.append(float(np.sqrt(np.mean(_match_corners(m.refined.corners_px, q) ** 2))))
        for c in codes:
            q = c.refined.corners_px
            other = near(q, [(i, p) for i, p in ats if i == c.marker_id])
            cvq = near(q, [(i, p) for i, p in cv if i == c.marker_id])
            if other is None and cvq is None and at is not None:
                n["false"] += 1   # neither peer reads a code there (a false code, or a hard one)
            if other is None:
                continue
            ap = other[1]
            c_ours_at.append(float(np.sqrt(np.mean(_match_corners(q, ap) ** 2))))
            po, pa = _ippe_pose(camera, tag_size, q), _ippe_pose(camera, tag_size,
                                                                 _roll_like(ap, q))
            if po is not None and pa is not None:
                rot_ours_at.append(_angle_deg(po[0], pa[0]))
                t_ours_at.append(1000.0 * float(np.linalg.norm(po[1] - pa[1])))
            if cvq is not None:
                c_cv_at.append(float(np.sqrt(np.mean(_match_corners(cvq[1], ap) ** 2))))
                pc = _ippe_pose(camera, tag_size, _roll_like(cvq[1], q))
                if pc is not None and pa is not None:
                    rot_cv_at.append(_angle_deg(pc[0], pa[0]))
    rep.update(codes=n, missed_opencv_codes=missed,
               corners_rms_px={"drovisio_vs_apriltag": _stats(c_ours_at),
                               "opencv_vs_apriltag": _stats(c_cv_at),
                               "drovisio_vs_opencv": _stats(c_ours_cv)},
               pose_vs_apriltag={"drovisio_rot_deg": _stats(rot_ours_at),
                                 "drovisio_trans_mm": _stats(t_ours_at),
                                 "opencv_rot_deg": _stats(rot_cv_at)},
               ms_per_photo={k: (1000.0 * float(np.median(v)) if v else None)
                             for k, v in times.items()})
    return rep


def _roll_like(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``q``'s corners in ``ref``'s order (rolled or mirrored to fit best)."""
    best, out = np.inf, q
    for cand in (q, q[::-1]):
        for k in range(4):
            r = np.roll(cand, k, axis=0)
            e = float(np.abs(r - ref).max())
            if e < best:
                best, out = e, r
    return out


# --------------------------------------------------------------------------- charuco
def bench_charuco(folder: Path, repeat: int, board_spec: str | None, square: float,
                  marker: float) -> dict:
    from drovisio.detect.aruco import ArucoBrickDetector
    from drovisio.layout import aruco_dictionary_id

    cam_path, camera = _load_reference(folder, required=True)
    images = _images(folder)
    grays = [_read_gray(p) for p in images]
    dictionary, _ = _best_dictionary(grays[:3])
    if dictionary is None:
        raise InputError(f"{folder}: no codes in its first photos")
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    if board_spec:
        m = re.fullmatch(r"charuco:(\d+)x(\d+)", board_spec)
        if not m:
            raise InputError(f"--board {board_spec}: give charuco:COLSxROWS (inner corners), "
                             "e.g. charuco:4x6")
        board = cv2.aruco.CharucoBoard((int(m[1]) + 1, int(m[2]) + 1), square, marker, d)
    else:
        _, ids, _ = _aruco(dictionary).detectMarkers(grays[0])
        guessed = _guess_charuco(grays[0], dictionary, np.ravel(ids), square, marker)
        if guessed is None:
            raise InputError(f"{folder}: the codes form no ChArUco board it could guess; give "
                             "--board charuco:COLSxROWS")
        board = guessed
    w, h = grays[0].shape[1], grays[0].shape[0]
    camera = camera.for_image(w, h)[0]
    det = ArucoBrickDetector(camera, [charuco_layout(board, dictionary)])
    cv_det = cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters())
    ch_det = cv2.aruco.CharucoDetector(board)
    det.detect(grays[0])
    obj = {int(i): _board_pts_to_brick(o)
           for o, i in zip(board.getObjPoints(), np.ravel(board.getIds()))}
    chess = _board_pts_to_brick(board.getChessboardCorners())
    cols, rows = board.getChessboardSize()
    rep: dict = {"kind": "charuco", "folder": str(folder), "camera": str(cam_path),
                 "dictionary": dictionary, "board_squares": [int(cols), int(rows)],
                 "square_m": square, "marker_m": marker, "photos": len(images)}
    n = {"drovisio": 0, "opencv": 0, "charuco_corners": 0, "photos_posed": 0,
         "ambiguous": 0}
    e_ours, e_cv, dt_mm, dr_deg = [], [], [], []
    times: dict[str, list[float]] = {"drovisio": [], "opencv": [], "charuco": []}
    for g in grays:
        poses, t = _timed(partial(det.detect, g), repeat)
        times["drovisio"].append(t)
        (cq, ci, _), t = _timed(partial(cv_det.detectMarkers, g), repeat)
        times["opencv"].append(t)
        (cc, cid, _, _), t = _timed(partial(ch_det.detectBoard, g), repeat)
        times["charuco"].append(t)
        codes: list[Any] = [c for c in det.last_codes if c.refined is not None and c.refined.ok]
        n["drovisio"] += len(codes)
        n["opencv"] += 0 if ci is None else len(ci)
        if cid is None or len(cid) < 6:
            continue
        n["charuco_corners"] += len(cid)
        ok, rv, tv = cv2.solvePnP(chess[np.ravel(cid)], np.asarray(cc, np.float64).reshape(-1, 2),
                                  camera.K, camera.dist)
        if not ok:
            continue
        for c in codes:
            p, _ = cv2.projectPoints(obj[c.marker_id], rv, tv, camera.K, camera.dist)
            e_ours.extend(np.linalg.norm(p.reshape(4, 2) - c.refined.corners_px, axis=1))
        if ci is not None:
            for q, i in zip(cq, np.ravel(ci)):
                if int(i) in obj:
                    p, _ = cv2.projectPoints(obj[int(i)], rv, tv, camera.K, camera.dist)
                    e_cv.extend(np.linalg.norm(p.reshape(4, 2) - np.asarray(q).reshape(4, 2),
                                               axis=1))
        if poses:
            b = poses[0]
            n["photos_posed"] += 1
            n["ambiguous"] += bool(b.ambiguous)
            dt_mm.append(1000.0 * float(np.linalg.norm(np.ravel(b.tvec) - tv.ravel())))
            dr_deg.append(_angle_deg(cv2.Rodrigues(np.ravel(b.rvec))[0], cv2.Rodrigues(rv)[0]))
    rep.update(codes=n, corners_vs_board_px={"drovisio": _stats(e_ours), "opencv": _stats(e_cv)},
               pose_vs_board={"trans_mm": _stats(dt_mm), "rot_deg": _stats(dr_deg)},
               ms_per_photo={k: (1000.0 * float(np.median(v)) if v else None)
                             for k, v in times.items()})
    return rep


# --------------------------------------------------------------------------- chessboard
def _expected_corners(path: Path) -> np.ndarray | None:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        node = fs.getNode("corners")
        m = None if node.empty() else node.mat()
    finally:
        fs.release()
    return None if m is None else np.asarray(m, np.float64).reshape(-1, 2)


def _chess_size(grays: list[np.ndarray], expected_n: int | None) -> tuple[int, int]:
    for size in CHESS_SIZES:
        if expected_n is not None and size[0] * size[1] != expected_n:
            continue
        for g in grays[:3]:
            found, _ = cv2.findChessboardCorners(g, size, None, cv2.CALIB_CB_ADAPTIVE_THRESH
                                                 | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if found:
                return size
    raise InputError("no chessboard size found in the first images (give --board "
                     "chessboard:COLSxROWS)")


def _calibrate_cli(images: list[Path], board: str, model: str) -> tuple[dict | None, str]:
    """``drovisio calibrate`` in this process; (fx, fy, cx, cy and RMS, or None; its last
    stderr line)."""
    from drovisio.camera_file import load_camera
    from drovisio.cli import main as cli_main

    with tempfile.TemporaryDirectory() as td:
        out = Path(td) / "camera.yaml"
        rep = Path(td) / "report.json"
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = cli_main(["calibrate", "--board", board, "--square", "0.025", "--model",
                             model, "--report", str(rep), "--out", str(out)]
                            + [str(p) for p in images])
        lines = [x for x in err.getvalue().splitlines()
                 if x.strip() and "report written" not in x]
        if code != 0 or not out.exists():
            return None, (lines[-1] if lines else f"exit {code}")[:240]
        cam = load_camera(out)
        r = json.loads(rep.read_text()) if rep.exists() else {}
        rms = r.get("rms_px", r.get("rms"))
        return {"fx": float(cam.K[0, 0]), "fy": float(cam.K[1, 1]), "cx": float(cam.K[0, 2]),
                "cy": float(cam.K[1, 2]), "model": cam.model,
                "rms_px": rms if isinstance(rms, (int, float)) else None}, ""


def bench_chessboard(folder: Path, repeat: int, board_spec: str | None, models: list[str]
                     ) -> dict:
    from drovisio.calibration.board import detect as board_detect
    from drovisio.calibration.board import parse_board

    images = _images(folder)
    grays = [_read_gray(p) for p in images]
    dats = {p.stem: _expected_corners(p) for p in sorted(folder.glob("*.dat"))}
    expected_n = next((len(v) for v in dats.values() if v is not None), None)
    if board_spec:
        m = re.fullmatch(r"chessboard:(\d+)x(\d+)", board_spec)
        if not m:
            raise InputError(f"--board {board_spec}: give chessboard:COLSxROWS (inner corners)")
        size = (int(m[1]), int(m[2]))
    else:
        size = _chess_size(grays, expected_n)
    board = parse_board(f"chessboard:{size[0]}x{size[1]}", 0.025)
    ref_path, ref = _load_reference(folder, required=False)
    rep: dict = {"kind": "chessboard", "folder": str(folder), "board": list(size),
                 "photos": len(images), "reference": str(ref_path) if ref_path else None}
    e_ours: list[float] = []
    e_cv: list[float] = []
    found = {"drovisio": 0, "opencv": 0}
    pts_obj, pts_img = [], []
    times: dict[str, list[float]] = {"drovisio": [], "opencv": []}
    objp = np.zeros((size[0] * size[1], 3), np.float32)
    objp[:, :2] = np.mgrid[0:size[0], 0:size[1]].T.reshape(-1, 2) * 0.025
    for path, g in zip(images, grays):
        d, t = _timed(partial(board_detect, g, board), repeat)
        times["drovisio"].append(t)

        def plain(g=g):
            ok, c = cv2.findChessboardCorners(g, size, None, cv2.CALIB_CB_ADAPTIVE_THRESH
                                              | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if ok:
                c = cv2.cornerSubPix(g, c, (11, 11), (-1, -1), (cv2.TERM_CRITERIA_EPS
                                                               + cv2.TERM_CRITERIA_COUNT, 30,
                                                               0.01))
            return ok, c
        (ok, c), t = _timed(partial(plain, g), repeat)
        times["opencv"].append(t)
        found["drovisio"] += d is not None
        found["opencv"] += bool(ok)
        if ok:
            pts_obj.append(objp)
            pts_img.append(c.reshape(-1, 1, 2))
        exp = dats.get(path.stem.replace("chess", "chess_corners"))
        if exp is None:
            continue
        for pts, sink in ((None if d is None else d.corners, e_ours),
                          (c.reshape(-1, 2) if ok else None, e_cv)):
            if pts is None:
                continue
            dist = np.linalg.norm(np.asarray(pts, np.float64)[:, None] - exp[None], axis=2)
            sink.extend(dist.min(axis=1))
    rep["found"] = found
    if dats:
        rep["corners_vs_expected_px"] = {"drovisio": _stats(e_ours), "opencv_11x11": _stats(e_cv)}
    rep["ms_per_photo"] = {k: 1000.0 * float(np.median(v)) for k, v in times.items() if v}
    # calibration against the reference
    fisheye = bool(ref is not None and (ref.model == "fisheye" or len(np.ravel(ref.dist)) == 4))
    calib: dict = {}
    if len(pts_obj) >= 3:
        wh = (grays[0].shape[1], grays[0].shape[0])
        try:
            K: Any = np.eye(3)
            D: Any = np.zeros(4)
            if fisheye:
                rms, K, D, _, _ = cv2.fisheye.calibrate(
                    [o.reshape(-1, 1, 3).astype(np.float64) for o in pts_obj],
                    [i.astype(np.float64) for i in pts_img], wh, K, D,
                    flags=cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW)
            else:
                rms, K, D, _, _ = cv2.calibrateCamera(pts_obj, pts_img, wh, K, np.zeros(5))
            calib["opencv"] = {"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                               "cx": float(K[0, 2]), "cy": float(K[1, 2]),
                               "model": "fisheye" if fisheye else "plumb_bob",
                               "rms_px": float(rms)}
        except cv2.error as e:
            calib["opencv"] = {"failed": str(e).strip().splitlines()[-1][:160]}
        # no published camera file: plain OpenCV's solve of the same corners is the reference
        refd = ({"fx": float(ref.K[0, 0]), "fy": float(ref.K[1, 1]), "cx": float(ref.K[0, 2]),
                 "cy": float(ref.K[1, 2]), "source": str(ref_path)} if ref is not None else
                {**{k: v for k, v in calib["opencv"].items() if k in ("fx", "fy", "cx", "cy")},
                 "source": "plain OpenCV (no camera file in the folder)"})
        calib["reference"] = refd
        for model in models:
            model = ("fisheye" if fisheye else "plumb_bob") if model == "reference" else model
            got, why = _calibrate_cli(images, f"chessboard:{size[0]}x{size[1]}", model)
            calib[f"drovisio_{model}"] = got if got is not None else {"failed": why}
        for v in calib.values():
            if "fx" in v and "fx" in refd and v is not refd:
                v["error_pct"] = {k: 100.0 * (v[k] - refd[k]) / refd[k]
                                  for k in ("fx", "fy", "cx", "cy")}
    rep["calibration"] = calib
    return rep


# --------------------------------------------------------------------------- printing
def _print(rep: dict) -> None:
    print(f"\n== {rep['folder']} ({rep['kind']}, {rep['photos']} photos)")
    ms = rep.get("ms_per_photo", {})
    if rep["kind"] == "tags":
        n = rep["codes"]
        print(f"   dictionary {rep['dictionary']}, camera {rep['camera']}; AprilTag 3: "
              f"{rep['apriltag']}")
        print(f"   codes found: Drovisio {n['drovisio']} ({n['drovisio_bricks']} bricks, "
              f"{n['duplicate_bricks']} flagged duplicate), OpenCV {n['opencv']}, AprilTag 3 "
              f"{n['apriltag']}; of OpenCV's codes Drovisio keeps {n['opencv_kept']}"
              + (f" (not: {', '.join(rep['missed_opencv_codes'])})"
                 if rep["missed_opencv_codes"] else "")
              + f"; Drovisio codes neither peer reads: {n['false']}")
        c = rep["corners_rms_px"]
        print("   corner RMS per code, px (median / p90 / max):")
        print(f"     Drovisio vs AprilTag 3  {_fmt(c['drovisio_vs_apriltag'])}")
        print(f"     OpenCV   vs AprilTag 3  {_fmt(c['opencv_vs_apriltag'])}")
        print(f"     Drovisio vs OpenCV      {_fmt(c['drovisio_vs_opencv'])}")
        p = rep["pose_vs_apriltag"]
        print(f"   pose vs AprilTag 3's corners (IPPE): Drovisio {_fmt(p['drovisio_rot_deg'], '°')}"
              f", {_fmt(p['drovisio_trans_mm'], ' mm', 1)}; OpenCV "
              f"{_fmt(p['opencv_rot_deg'], '°')}")
    elif rep["kind"] == "charuco":
        n = rep["codes"]
        print(f"   board {rep['board_squares'][0]}x{rep['board_squares'][1]} squares, "
              f"{rep['dictionary']}, camera {rep['camera']}")
        print(f"   codes found: Drovisio {n['drovisio']}, OpenCV {n['opencv']}; ChArUco corners "
              f"{n['charuco_corners']}; bricks posed {n['photos_posed']}, ambiguous "
              f"{n['ambiguous']}")
        c = rep["corners_vs_board_px"]
        print(f"   code corners vs the board pose's prediction, px (median / p90 / max): "
              f"Drovisio {_fmt(c['drovisio'])}; OpenCV {_fmt(c['opencv'])}")
        p = rep["pose_vs_board"]
        print(f"   brick pose vs ChArUco board pose: {_fmt(p['trans_mm'], ' mm', 2)}, "
              f"{_fmt(p['rot_deg'], '°', 3)}")
    else:
        f = rep["found"]
        print(f"   board {rep['board'][0]}x{rep['board'][1]}; found: Drovisio "
              f"{f['drovisio']}, OpenCV {f['opencv']}; reference {rep['reference']}")
        if "corners_vs_expected_px" in rep:
            c = rep["corners_vs_expected_px"]
            print(f"   corners vs OpenCV's expected, px (median / p90 / max): Drovisio "
                  f"{_fmt(c['drovisio'], '', 3)}; OpenCV 11x11 {_fmt(c['opencv_11x11'], '', 3)}")
        for name, v in rep.get("calibration", {}).items():
            if "failed" in v:
                print(f"   calibration {name:22s} failed: {v['failed']}")
            elif name == "reference":
                if "fx" in v:
                    print(f"   calibration {name:22s} fx {v['fx']:.2f} fy {v['fy']:.2f} "
                          f"cx {v['cx']:.2f} cy {v['cy']:.2f} ({v['source']})")
            else:
                e = v.get("error_pct", {})
                rms = v.get("rms_px")
                print(f"   calibration {name:22s} fx {v['fx']:.2f} fy {v['fy']:.2f} "
                      f"cx {v['cx']:.2f} cy {v['cy']:.2f} ({v.get('model')}"
                      + (f", RMS {rms:.3f} px" if isinstance(rms, float) else "") + "); vs "
                      "reference " + " ".join(f"{k} {x:+.2f}%" for k, x in e.items()))
    if ms:
        print("   ms per photo (median): " + ", ".join(
            f"{k} {v:.1f}" for k, v in ms.items() if v is not None))


def main(argv: list[str]) -> int:
    from drovisio.arguments import positive_float
    from drovisio.bounds import ArgumentParser

    p = ArgumentParser(prog="drovisio bench real", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folders", nargs="+", metavar="DIR", help="folders of real photos")
    p.add_argument("--repeat", type=int, default=1,
                   help="timed runs per photo and method, the fastest kept (1-20; default 1)")
    p.add_argument("--tag-size", type=positive_float, default=0.065,
                   help="side of the tags' black square, m (default 0.065)")
    p.add_argument("--board", default=None,
                   help="charuco:COLSxROWS or chessboard:COLSxROWS (inner corners; default: "
                        "guessed)")
    p.add_argument("--square", type=positive_float, default=0.04,
                   help="ChArUco square side, m (default 0.04)")
    p.add_argument("--marker", type=positive_float, default=0.02,
                   help="ChArUco code side, m (default 0.02)")
    p.add_argument("--calibrate", default="reference,auto",
                   help="drovisio calibrate models to run on chessboard sets: reference (the "
                        "reference file's model), auto, plumb_bob, rational, fisheye, none "
                        "(default reference,auto)")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON")
    args = p.parse_args(argv)
    if not 1 <= args.repeat <= 20:
        raise InputError(f"--repeat {args.repeat}: give 1 to 20")
    models = [m.strip() for m in args.calibrate.split(",") if m.strip()]
    bad = [m for m in models if m not in ("reference", "auto", "plumb_bob", "rational",
                                          "fisheye", "none")]
    if bad:
        raise InputError(f"--calibrate: {bad[0]!r} is no model; give reference, auto, "
                         "plumb_bob, rational, fisheye or none")
    models = [m for m in models if m != "none"]
    if args.marker >= args.square:
        raise InputError(f"--marker {args.marker}: the code must be smaller than the square "
                         f"({args.square})")
    if args.json:
        from drovisio.fileio import check_output_path

        check_output_path(args.json, "--json", folder_must_exist=True)
    folders = []
    for f in args.folders:
        path = Path(f)
        if not path.is_dir():
            raise InputError(f"{f}: not a folder (give folders of real photos)")
        folders.append(path)
    cv2.setNumThreads(1)
    reports = []
    for folder in folders:
        kind = detect_kind(folder)
        if kind == "tags":
            rep = bench_tags(folder, args.repeat, args.tag_size)
        elif kind == "charuco":
            rep = bench_charuco(folder, args.repeat, args.board, args.square, args.marker)
        else:
            rep = bench_chessboard(folder, args.repeat, args.board, models)
        _print(rep)
        reports.append(rep)
    if args.json:
        from drovisio.fileio import atomic_write_text

        atomic_write_text(args.json, json.dumps({"folders": reports}, indent=1,
                                                allow_nan=False, default=float))
    return 0
