"""``drovisio bench real`` on photos of codes: tag photos (every id its own one-code brick)
and ChArUco photos (the board's codes as one brick), Drovisio beside OpenCV's plain
``ArucoDetector`` and AprilTag 3 (see :mod:`drovisio.bench.real` for what is measured)."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio.bench.real_folder import (
    PhotoSet,
    aruco_detector,
    best_dictionary,
    folder_camera,
    guess_charuco,
)
from drovisio.bench.real_measures import (
    angle_deg,
    apriltag,
    ippe_pose,
    match_corners,
    roll_like,
    stats,
    timed,
)
from drovisio.calibration.board import parse_board
from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.detect.corners.edges import EDGE_LINE_MAX_RMS_PX, outer_edge_corners
from drovisio.errors import InputError
from drovisio.layout import MarkerLayout, aruco_dictionary_id, aruco_dictionary_size, parse_layout
from drovisio.study.apriltag import APRILTAG_FAMILIES, AprilTagReader

__all__ = ["bench_charuco", "bench_tags", "charuco_layout", "tag_layout"]

Quads = list[tuple[int, np.ndarray]]
"""(code id, its (4, 2) corners in pixels) per code read."""


# --------------------------------------------------------------------------- layouts
def tag_layout(dictionary: str, size_m: float, name: str = "tags") -> MarkerLayout:
    """A layout whose every id of ``dictionary`` is its own one-code brick of ``size_m``."""
    return parse_layout({
        "schema": "drovisio/marker-layout@1", "name": name, "units": "m",
        "first_id": 0, "ids_per_instance": 1,
        "instances": aruco_dictionary_size(dictionary), "symmetry": "none",
        "markers": [{"kind": "aruco", "dictionary": dictionary, "id": 0, "size": size_m,
                     "center": [0, 0, 0], "normal": [0, 0, 1], "up": [0, 1, 0]}]},
        "<bench real tags>")


def charuco_layout(board: cv2.aruco.CharucoBoard, dictionary: str, name: str = "charuco"
                   ) -> MarkerLayout:
    """The codes of a ChArUco board as one brick; brick frame: the board's, y flipped (up
    in the printed image) so that z points out of the board toward the camera."""
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
    """(N, 3) board points in the brick frame of :func:`charuco_layout` (y flipped)."""
    q = np.asarray(p, np.float64).reshape(-1, 3).copy()
    q[:, 1] *= -1.0
    return q


def _ms_per_photo(times: dict[str, list[float]]) -> dict[str, float | None]:
    return {k: (1000.0 * float(np.median(v)) if v else None) for k, v in times.items()}


# --------------------------------------------------------------------------- tags
@dataclass
class _TagFigures:
    """What the tag photos give, gathered photo by photo."""

    n: dict[str, int] = field(default_factory=lambda: {
        "drovisio": 0, "opencv": 0, "apriltag": 0, "drovisio_bricks": 0,
        "opencv_kept": 0, "duplicate_bricks": 0, "false": 0})
    """Codes (and bricks) counted per method."""
    c_ours_at: list[float] = field(default_factory=list)
    """Corner RMS per code (px), Drovisio against AprilTag 3."""
    edges: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    """Per code whose outer edges are clean: (AprilTag's, Drovisio's) (4, 2) corners minus
    the edge lines' intersections, px (:mod:`drovisio.detect.corners.edges`)."""
    edges_unclean: int = 0
    """Codes read by both whose outer edges are not clean enough to judge by."""
    c_cv_at: list[float] = field(default_factory=list)
    c_ours_cv: list[float] = field(default_factory=list)
    rot_ours_at: list[float] = field(default_factory=list)
    """IPPE pose rotation differences (degrees) on each method's corners."""
    rot_cv_at: list[float] = field(default_factory=list)
    t_ours_at: list[float] = field(default_factory=list)
    """IPPE pose translation differences (mm)."""
    times: dict[str, list[float]] = field(default_factory=lambda: {
        "drovisio": [], "opencv": [], "apriltag": []})
    """Fastest time (s) per photo and method."""
    missed: list[str] = field(default_factory=list)
    """OpenCV's codes Drovisio does not keep, as ``photo:id``."""


def bench_tags(photos: PhotoSet, repeat: int, tag_size: float) -> dict[str, Any]:
    """The figures of a folder of tag photos (with its camera file)."""
    folder, images, grays = photos.folder, photos.paths, photos.grays
    cam_path, camera = folder_camera(photos, required=True)
    assert camera is not None   # required: folder_camera raised otherwise
    dictionary, _ = best_dictionary(grays[:3])
    if dictionary is None:
        raise InputError(f"{folder}: no codes of a known dictionary in its first photos")
    det = ArucoBrickDetector(camera, [tag_layout(dictionary, tag_size)])
    cv_det = aruco_detector(dictionary)
    at, why_not = apriltag(dictionary)
    det.detect(grays[0])      # warm-up: compiled kernels, tables
    rep: dict[str, Any] = {"kind": "tags", "folder": str(folder), "camera": str(cam_path),
                           "dictionary": dictionary, "tag_size_m": tag_size,
                           "photos": len(images), "apriltag": why_not or _apriltag_says(
                               dictionary)}
    fig = _TagFigures()
    for k, (path, g) in enumerate(zip(images, grays), 1):
        codes, cv, ats = _read_tags(g, det, cv_det, at, repeat, fig)
        _opencv_kept(path, codes, cv, fig)
        _against_apriltag(camera, tag_size, codes, cv, ats, at is not None, fig)
        _against_edges(g, codes, ats, fig)
        photos.done(k)
    rep.update(codes=fig.n, missed_opencv_codes=fig.missed,
               edge_reference=_edge_figures(fig),
               corners_rms_px={"drovisio_vs_apriltag": stats(fig.c_ours_at),
                               "opencv_vs_apriltag": stats(fig.c_cv_at),
                               "drovisio_vs_opencv": stats(fig.c_ours_cv)},
               pose_vs_apriltag={"drovisio_rot_deg": stats(fig.rot_ours_at),
                                 "drovisio_trans_mm": stats(fig.t_ours_at),
                                 "opencv_rot_deg": stats(fig.rot_cv_at)},
               ms_per_photo=_ms_per_photo(fig.times))
    return rep


def _apriltag_says(dictionary: str) -> str:
    """How AprilTag 3 reads ``dictionary``, for the report."""
    fam = APRILTAG_FAMILIES.get(dictionary)
    return (f"pupil-apriltags, decimate 1, 1 thread, {dictionary} as its family"
            + (f" (bit for bit its own {fam})" if fam else ""))


def _read_tags(g: np.ndarray, det: ArucoBrickDetector, cv_det: cv2.aruco.ArucoDetector,
               at: AprilTagReader | None, repeat: int, fig: _TagFigures
               ) -> tuple[list[Any], Quads, Quads]:
    """One photo read by each method, timed and counted: Drovisio's refined codes, OpenCV's
    and AprilTag 3's quads (AprilTag's in OpenCV's order and pixel convention)."""
    n, times = fig.n, fig.times
    poses, t = timed(partial(det.detect, g), repeat)
    times["drovisio"].append(t)
    (cq, ci, _), t = timed(partial(cv_det.detectMarkers, g), repeat)
    times["opencv"].append(t)
    codes: list[Any] = [c for c in det.last_codes
                       if c.refined is not None and c.refined.ok and not c.guided]
    n["drovisio"] += len(codes)
    n["drovisio_bricks"] += len(poses)
    n["duplicate_bricks"] += sum(bool(p.duplicate) for p in poses)
    cv = [(int(i), np.asarray(q, np.float64).reshape(4, 2))
          for q, i in zip(cq, np.ravel(ci))] if ci is not None else []
    n["opencv"] += len(cv)
    ats: Quads = []
    if at is not None:
        res, t = timed(partial(at.detect, g), repeat)
        times["apriltag"].append(t)
        ats = [(r.marker_id, r.corners) for r in res]
        n["apriltag"] += len(ats)
    return codes, cv, ats


def _near(q: np.ndarray, pool: Quads) -> tuple[int, np.ndarray] | None:
    """The first quad of ``pool`` whose centre is within 0.3 of ``q``'s side of its centre."""
    c = q.mean(axis=0)
    side = float(np.linalg.norm(q[1] - q[0]))
    for i, p in pool:
        if np.linalg.norm(p.mean(axis=0) - c) < 0.3 * side:
            return i, p
    return None


def _opencv_kept(path: Path, codes: list[Any], cv: Quads, fig: _TagFigures) -> None:
    """Every code OpenCV reads: kept by Drovisio (and how close its corners are)?"""
    for mid, q in cv:
        m = next((c for c in codes if c.marker_id == mid
                  and np.linalg.norm(c.refined.corners_px.mean(0) - q.mean(0))
                  < 0.3 * np.linalg.norm(q[1] - q[0])), None)
        if m is None:
            fig.missed.append(f"{path.name}:{mid}")
            continue
        fig.n["opencv_kept"] += 1
        fig.c_ours_cv.append(float(np.sqrt(np.mean(match_corners(m.refined.corners_px, q) ** 2))))


def _against_edges(g: np.ndarray, codes: list[Any], ats: Quads, fig: _TagFigures) -> None:
    """Drovisio's and AprilTag's corners against the code's outer edge lines, where the
    code is at least 15 px and its four edges are clean (a code Drovisio kept at those very
    lines is not judged by them)."""
    for c in codes:
        if c.refined.edge_lines:
            continue
        q = c.refined.corners_px
        other = _near(q, [(i, p) for i, p in ats if i == c.marker_id])
        if other is None or np.linalg.norm(q[1] - q[0]) < 15.0:
            continue
        ap = roll_like(other[1], q)
        e = outer_edge_corners(g, ap)
        if e is None or e.worst_rms_px > EDGE_LINE_MAX_RMS_PX:
            fig.edges_unclean += 1
            continue
        fig.edges.append((ap - e.corners_px, q - e.corners_px))


def _edge_figures(fig: _TagFigures) -> dict[str, Any]:
    """The edge reference's figures: each method's corner RMS per code against the edges,
    AprilTag's mean offset from them (the pixel convention), and of the codes where the
    two methods differ by over 0.5 px RMS, which one the edges side with."""
    rms = [(float(np.sqrt(np.mean((a * a).sum(1)))), float(np.sqrt(np.mean((o * o).sum(1)))))
           for a, o in fig.edges]
    apart = [(a, o) for (a, o), (ea, eo) in zip(fig.edges, rms)
             if np.sqrt(np.mean(((a - o) ** 2).sum(1))) > 0.5]
    off = np.concatenate([a for a, _ in fig.edges]).mean(0) if fig.edges else None
    return {"apriltag_vs_edges": stats(ea for ea, _ in rms),
            "drovisio_vs_edges": stats(eo for _, eo in rms),
            "apriltag_mean_offset_px": None if off is None else [float(v) for v in off],
            "unclean": fig.edges_unclean,
            "apart_over_half_px": len(apart),
            "apart_edges_side_with_apriltag": sum(
                float(np.sum(a * a)) < float(np.sum(o * o)) for a, o in apart)}


def _against_apriltag(camera: Camera, tag_size: float, codes: list[Any], cv: Quads,
                      ats: Quads, have_apriltag: bool, fig: _TagFigures) -> None:
    """Drovisio's and OpenCV's corners and IPPE poses against AprilTag 3's on the same
    codes; Drovisio codes neither peer reads are counted as false."""
    for c in codes:
        q = c.refined.corners_px
        other = _near(q, [(i, p) for i, p in ats if i == c.marker_id])
        cvq = _near(q, [(i, p) for i, p in cv if i == c.marker_id])
        if other is None and cvq is None and have_apriltag:
            fig.n["false"] += 1   # neither peer reads a code there (a false code, or a hard one)
        if other is None:
            continue
        ap = other[1]
        fig.c_ours_at.append(float(np.sqrt(np.mean(match_corners(q, ap) ** 2))))
        po, pa = ippe_pose(camera, tag_size, q), ippe_pose(camera, tag_size, roll_like(ap, q))
        if po is not None and pa is not None:
            fig.rot_ours_at.append(angle_deg(po[0], pa[0]))
            fig.t_ours_at.append(1000.0 * float(np.linalg.norm(po[1] - pa[1])))
        if cvq is not None:
            fig.c_cv_at.append(float(np.sqrt(np.mean(match_corners(cvq[1], ap) ** 2))))
            pc = ippe_pose(camera, tag_size, roll_like(cvq[1], q))
            if pc is not None and pa is not None:
                fig.rot_cv_at.append(angle_deg(pc[0], pa[0]))


# --------------------------------------------------------------------------- charuco
def _charuco_board(folder: Path, gray: np.ndarray, dictionary: str, board_spec: str | None,
                   square: float, marker: float) -> cv2.aruco.CharucoBoard:
    """The board ``--board`` names, or the one guessed from the codes of the first photo.

    Raises:
        InputError: a ``--board`` that is no ChArUco size, or codes that form no board.
    """
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    if board_spec:
        m = re.fullmatch(r"charuco:(\d{1,6})x(\d{1,6})", board_spec)
        if not m:
            raise InputError(f"--board {board_spec}: give charuco:COLSxROWS (inner corners), "
                             "e.g. charuco:4x6")
        # the one board-spec check (its size bounds, its codes against the dictionary's):
        # OpenCV builds any board it is given, 10^10 squares included
        spec = parse_board(f"charuco:{m[1]}x{m[2]}:{dictionary}", square)
        return cv2.aruco.CharucoBoard((spec.cols + 1, spec.rows + 1), square, marker, d)
    _, ids, _ = aruco_detector(dictionary).detectMarkers(gray)
    guessed = guess_charuco(gray, dictionary, np.ravel(ids), square, marker)
    if guessed is None:
        raise InputError(f"{folder}: the codes form no ChArUco board it could guess; give "
                         "--board charuco:COLSxROWS")
    return guessed


def bench_charuco(photos: PhotoSet, repeat: int, board_spec: str | None, square: float,
                  marker: float) -> dict[str, Any]:
    """The figures of a folder of ChArUco photos (with its camera file)."""
    folder, images, grays = photos.folder, photos.paths, photos.grays
    cam_path, camera = folder_camera(photos, required=True)
    assert camera is not None   # required: folder_camera raised otherwise
    dictionary, _ = best_dictionary(grays[:3])
    if dictionary is None:
        raise InputError(f"{folder}: no codes in its first photos")
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    board = _charuco_board(folder, grays[0], dictionary, board_spec, square, marker)
    det = ArucoBrickDetector(camera, [charuco_layout(board, dictionary)])
    at, why_not = apriltag(dictionary)
    readers = _CharucoReaders(det, cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters()),
                              cv2.aruco.CharucoDetector(board), at)
    det.detect(grays[0])
    obj = {int(i): _board_pts_to_brick(o)
           for o, i in zip(board.getObjPoints(), np.ravel(board.getIds()))}
    chess = _board_pts_to_brick(board.getChessboardCorners())
    cols, rows = board.getChessboardSize()
    rep: dict[str, Any] = {"kind": "charuco", "folder": str(folder), "camera": str(cam_path),
                           "dictionary": dictionary, "board_squares": [int(cols), int(rows)],
                           "square_m": square, "marker_m": marker, "photos": len(images),
                           "apriltag": why_not or _apriltag_says(dictionary)}
    fig = _CharucoFigures()
    for k, g in enumerate(grays, 1):
        _charuco_photo(g, camera, readers, obj, chess, repeat, fig)
        photos.done(k)
    rep.update(codes=fig.n,
               corners_vs_board_px={"drovisio": stats(fig.e_ours), "opencv": stats(fig.e_cv),
                                    "apriltag": stats(fig.e_at),
                                    "drovisio_vs_homography": stats(fig.e_hom),
                                    "drovisio_shift_removed": stats(fig.e_shape)},
               corners_rms_px={"drovisio_vs_apriltag": stats(fig.c_ours_at),
                               "opencv_vs_apriltag": stats(fig.c_cv_at)},
               codes_within_half_px=fig.within,
               code_shift_px=_code_shifts(fig),
               board_pose_rms_px=stats(fig.ref_rms),
               pose_vs_board={"trans_mm": stats(fig.dt_mm), "rot_deg": stats(fig.dr_deg)},
               ms_per_photo=_ms_per_photo({k: v for k, v in fig.times.items()
                                           if at is not None or k != "apriltag"}))
    return rep


@dataclass
class _CharucoReaders:
    """The readings compared on each ChArUco photo."""

    drovisio: ArucoBrickDetector
    opencv: cv2.aruco.ArucoDetector
    charuco: cv2.aruco.CharucoDetector
    apriltag: AprilTagReader | None
    """AprilTag 3 with the board's dictionary as its family; None when not installed."""


@dataclass
class _CharucoFigures:
    """What the ChArUco photos give, gathered photo by photo."""

    n: dict[str, int] = field(default_factory=lambda: {
        "drovisio": 0, "opencv": 0, "apriltag": 0, "charuco_corners": 0, "photos_posed": 0,
        "ambiguous": 0})
    e_ours: list[float] = field(default_factory=list)
    """Distances (px) of Drovisio's code corners from the board pose's prediction."""
    e_cv: list[float] = field(default_factory=list)
    e_at: list[float] = field(default_factory=list)
    e_hom: list[float] = field(default_factory=list)
    """Distances (px) of Drovisio's code corners from the board plane's homography."""
    e_shape: list[float] = field(default_factory=list)
    """The same as ``e_ours`` once each code's own shift (its corners' mean error) is
    removed: the code's shape and size against the prediction."""
    c_ours_at: list[float] = field(default_factory=list)
    """Corner RMS per code (px), Drovisio against AprilTag 3: a reference that assumes
    nothing of the board (its flatness, its print)."""
    c_cv_at: list[float] = field(default_factory=list)
    within: dict[str, int] = field(default_factory=lambda: {
        "codes": 0, "of_apriltag": 0, "of_board": 0, "of_either": 0})
    """Drovisio's codes (also read by AprilTag 3) whose corners lie within 0.5 px RMS of
    AprilTag 3's, of the board pose's prediction, of either."""
    shifts: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = field(
        default_factory=list)
    """Per code Drovisio and OpenCV both read, the mean error (px, (2,)) of Drovisio's
    corners, of OpenCV's and of AprilTag 3's (None where it did not read it) from the
    prediction."""
    ref_rms: list[float] = field(default_factory=list)
    """The board pose's own reprojection RMS (px) on the ChArUco corners it was posed from."""
    dt_mm: list[float] = field(default_factory=list)
    """The brick pose's translation from the board pose's, mm."""
    dr_deg: list[float] = field(default_factory=list)
    times: dict[str, list[float]] = field(default_factory=lambda: {
        "drovisio": [], "opencv": [], "charuco": [], "apriltag": []})


def _quads(corners: Any, ids: Any) -> dict[int, np.ndarray]:
    """OpenCV's ``detectMarkers`` answer as {id: (4, 2) corners px}."""
    if ids is None:
        return {}
    return {int(i): np.asarray(q, np.float64).reshape(4, 2) for q, i in zip(corners,
                                                                            np.ravel(ids))}


def _charuco_photo(g: np.ndarray, camera: Camera, rd: _CharucoReaders,
                   obj: dict[int, np.ndarray], chess: np.ndarray, repeat: int,
                   fig: _CharucoFigures) -> None:
    """One photo: each method timed; Drovisio's and OpenCV's code corners against AprilTag
    3's; with at least 6 ChArUco corners, the board posed from them and every method's code
    corners and Drovisio's brick pose against it."""
    n, times = fig.n, fig.times
    poses, t = timed(partial(rd.drovisio.detect, g), repeat)
    times["drovisio"].append(t)
    (cq, ci, _), t = timed(partial(rd.opencv.detectMarkers, g), repeat)
    times["opencv"].append(t)
    (cc, cid, _, _), t = timed(partial(rd.charuco.detectBoard, g), repeat)
    times["charuco"].append(t)
    at_q: dict[int, np.ndarray] = {}
    if rd.apriltag is not None:
        res, t = timed(partial(rd.apriltag.detect, g), repeat)
        times["apriltag"].append(t)
        at_q = {r.marker_id: r.corners for r in res if r.marker_id in obj}
    codes: list[Any] = [c for c in rd.drovisio.last_codes
                        if c.refined is not None and c.refined.ok and not c.guided]
    cv_q = _quads(cq, ci)
    n["drovisio"] += len(codes)
    n["opencv"] += len(cv_q)
    n["apriltag"] += len(at_q)
    rms = {c.marker_id: float(np.sqrt(np.mean(match_corners(c.refined.corners_px,
                                                            at_q[c.marker_id]) ** 2)))
           for c in codes if c.marker_id in at_q}
    fig.c_ours_at.extend(rms.values())
    fig.c_cv_at.extend(float(np.sqrt(np.mean(match_corners(q, at_q[i]) ** 2)))
                       for i, q in cv_q.items() if i in at_q)
    if cid is None or len(cid) < 6:
        return
    n["charuco_corners"] += len(cid)
    cc = np.asarray(cc, np.float64).reshape(-1, 2)
    ok, rv, tv = cv2.solvePnP(chess[np.ravel(cid)], cc, camera.K, camera.dist)
    if not ok:
        return
    p, _ = cv2.projectPoints(chess[np.ravel(cid)], rv, tv, camera.K, camera.dist)
    fig.ref_rms.append(float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - cc) ** 2, axis=1)))))
    plane = _board_homography(camera, chess[np.ravel(cid)], cc)

    def predicted(mid: int) -> np.ndarray:
        p, _ = cv2.projectPoints(obj[mid], rv, tv, camera.K, camera.dist)
        return p.reshape(4, 2)

    for c in codes:
        _code_vs_board(c, predicted(c.marker_id), plane(obj[c.marker_id]), cv_q, at_q,
                       rms.get(c.marker_id), fig)
    for i, q in cv_q.items():
        if i in obj:
            fig.e_cv.extend(np.linalg.norm(q - predicted(i), axis=1))
    for i, q in at_q.items():
        pred = predicted(i)
        fig.e_at.extend(np.linalg.norm(roll_like(q, pred) - pred, axis=1))
    if poses:
        b = poses[0]
        n["photos_posed"] += 1
        n["ambiguous"] += bool(b.ambiguous)
        fig.dt_mm.append(1000.0 * float(np.linalg.norm(np.ravel(b.tvec) - tv.ravel())))
        fig.dr_deg.append(angle_deg(cv2.Rodrigues(np.ravel(b.rvec))[0], cv2.Rodrigues(rv)[0]))


def _code_vs_board(c: Any, pred: np.ndarray, homography: np.ndarray,
                   cv_q: dict[int, np.ndarray], at_q: dict[int, np.ndarray],
                   rms_at: float | None, fig: _CharucoFigures) -> None:
    """One Drovisio code against the board pose's prediction ``pred`` and the board plane's
    homography (each (4, 2) px): its corners' distances, its shift beside OpenCV's and
    AprilTag's, and whether it lies within 0.5 px RMS of AprilTag's (``rms_at``) or of the
    prediction."""
    e = c.refined.corners_px - pred
    fig.e_ours.extend(np.linalg.norm(e, axis=1))
    fig.e_shape.extend(np.linalg.norm(e - e.mean(axis=0), axis=1))
    fig.e_hom.extend(np.linalg.norm(homography - c.refined.corners_px, axis=1))
    if c.marker_id in cv_q:
        a = at_q.get(c.marker_id)
        fig.shifts.append((e.mean(axis=0), (cv_q[c.marker_id] - pred).mean(0),
                           None if a is None else (roll_like(a, pred) - pred).mean(0)))
    if rms_at is not None:
        near = (rms_at <= 0.5, float(np.sqrt(np.mean((e * e).sum(1)))) <= 0.5)
        for k, v in zip(("codes", "of_apriltag", "of_board", "of_either"),
                        (True, near[0], near[1], near[0] or near[1])):
            fig.within[k] += int(v)


def _code_shifts(fig: _CharucoFigures) -> dict[str, Any]:
    """How far each code as a whole lies from the board pose's prediction, by Drovisio, by
    OpenCV and by AprilTag 3, and how much they agree: where detectors that share no code put
    a code away from the prediction by the same shift (correlation near 1, difference
    small), the code is there in the photo (the print or the sheet is not the flat board),
    not a detector's error."""
    def corr(a: np.ndarray, b: np.ndarray) -> list[float] | None:
        if len(a) < 3 or not (np.all(a.std(axis=0) > 0) and np.all(b.std(axis=0) > 0)):
            return None
        return [float(np.corrcoef(a[:, k], b[:, k])[0, 1]) for k in (0, 1)]

    a = np.array([s[0] for s in fig.shifts]).reshape(-1, 2)
    b = np.array([s[1] for s in fig.shifts]).reshape(-1, 2)
    with_at = [s for s in fig.shifts if s[2] is not None]
    a2 = np.array([s[0] for s in with_at]).reshape(-1, 2)
    c = np.array([s[2] for s in with_at]).reshape(-1, 2)
    return {"drovisio": stats(np.linalg.norm(a, axis=1)), "opencv": stats(np.linalg.norm(b, axis=1)),
            "apriltag": stats(np.linalg.norm(c, axis=1)),
            "difference": stats(np.linalg.norm(a - b, axis=1)), "correlation_xy": corr(a, b),
            "difference_apriltag": stats(np.linalg.norm(a2 - c, axis=1)),
            "correlation_xy_apriltag": corr(a2, c)}


def _board_homography(camera: Camera, board_pts: np.ndarray, px: np.ndarray
                      ) -> Callable[[np.ndarray], np.ndarray]:
    """A prediction of board points that trusts neither the camera's focal length nor the
    board pose: the homography of the board plane fitted to the ChArUco corners in
    undistorted normalised coordinates (only the lens distortion is the camera file's).

    Args:
        board_pts: (N, 3) ChArUco corners in the brick frame, m (z = 0).
        px: (N, 2) their detected pixels.

    Returns:
        A function of (K, 3) board points (z = 0) giving their (K, 2) predicted pixels.
    """
    H, _ = cv2.findHomography(board_pts[:, :2], camera.normalize(px), 0)

    def predict(pts: np.ndarray) -> np.ndarray:
        xn = cv2.perspectiveTransform(np.asarray(pts, np.float64)[None, :, :2], H)[0]
        return camera.project(np.concatenate([xn, np.ones((len(xn), 1))], axis=1))
    return predict
