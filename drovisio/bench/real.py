"""``drovisio bench real DIR...``: Drovisio beside plain OpenCV and AprilTag 3 on real pictures.

Each folder is one data set of pictures nobody here rendered; its kind is found from what it
holds:

* **tags** — photos of AprilTag or ArUco codes with a camera file (``camera.yaml``): the
  dictionary is the one that reads most codes in the first photos; every id is its own
  one-code brick (``--tag-size`` metres). Drovisio's
  :class:`~drovisio.detect.aruco.ArucoBrickDetector` beside OpenCV's ``ArucoDetector``
  (default parameters) and AprilTag 3 (``pupil-apriltags``, decimate 1, one thread, any
  dictionary: :mod:`drovisio.study.apriltag`; the ``peers`` extra: said when absent): codes
  found, corners against AprilTag's (OpenCV's
  pixel convention: AprilTag's corners − 0.5 px), poses (the same IPPE on each method's
  corners; Drovisio's own pose), codes read more than once in a photo, time per photo. The
  reference is itself checked against a reading independent of both: the code's outer edges
  located on the gradient and fitted as lines (:mod:`~drovisio.detect.corners.edges`), where
  they are clean; AprilTag's mean offset from their intersections checks the half-pixel
  convention, and where the two methods differ the edges say which one is nearer.
* **charuco** — a ChArUco photo with its camera file: the board is guessed from the codes
  (contiguous ids from 0, the rows × columns that hold them, OpenCV's tutorial proportions:
  squares 0.04 m, codes 0.02 m; ``--board charuco:COLSxROWS`` with inner corners and
  ``--square``/``--marker`` override); the codes are one brick. Codes found by Drovisio and
  by ``ArucoDetector``, their corners against the board pose's prediction (the board posed
  from OpenCV's ``CharucoDetector`` corners), Drovisio's brick pose against the board pose.
  How good the prediction is, is reported beside it: the board pose's own reprojection RMS
  on those ChArUco corners, and Drovisio's corners against a prediction that trusts neither
  the focal length nor the pose (the board plane's homography fitted to the ChArUco corners
  in undistorted coordinates). On OpenCV's tutorial photo the pose reprojects its corners to
  0.22 px RMS (the homography 0.21 px) and the two predictions of the code corners agree
  within 0.06 px (median; 0.23 px at most). Yet both assume the nominal flat board, and
  where the codes lie outside the ChArUco corners' hull (the board's edge rows) the three
  readings, Drovisio's, OpenCV's and AprilTag 3's (the board's dictionary given to it as a
  family), put each code off the prediction by the same shift (0.3–1.1 px, outward): the
  sheet is not the nominal board there. So the codes are also compared with AprilTag 3's
  corners, a reading that assumes nothing of the board, and each code is counted within
  0.5 px RMS of AprilTag's, of the prediction, or of either.
* **chessboard** — a calibration set: expected corners (OpenCV's ``*.dat``) and/or a
  reference camera file. Corners of Drovisio's finder and of ``findChessboardCorners`` +
  ``cornerSubPix`` (11×11) against the expected ones; ``drovisio calibrate`` (the model of
  the reference file, and ``auto``) and plain OpenCV (``calibrateCamera``, or
  ``fisheye.calibrate`` for a fisheye reference) against the reference's fx, fy, cx, cy.

Modules: :mod:`~drovisio.bench.real_folder` (what a folder holds, its kind),
:mod:`~drovisio.bench.real_measures` (timing, corner distances, IPPE, summary figures),
:mod:`~drovisio.bench.real_codes` (tag and ChArUco photos), :mod:`~drovisio.detect.corners.edges`
(the outer-edge reading that checks the tag reference); chessboards, the printing and the
command are here.

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
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio.bench.real_codes import bench_charuco, bench_tags, charuco_layout, tag_layout
from drovisio.bench.real_folder import (
    CHESS_SIZES,
    PhotoSet,
    camera_files,
    detect_kind,
    folder_camera,
    read_photos,
    say,
)
from drovisio.bench.real_measures import stats, timed
from drovisio.bounds import check_number
from drovisio.calibration.board import BoardSpec, parse_board
from drovisio.calibration.board import detect as board_detect
from drovisio.camera import Camera
from drovisio.camera_file import parse_opencv_yaml
from drovisio.errors import InputError, one_line
from drovisio.fileio import atomic_write_text, check_output_path
from drovisio.textfile import missing_reason, read_text

__all__ = ["bench_charuco", "bench_chessboard", "bench_tags", "charuco_layout", "detect_kind",
           "main", "tag_layout"]

#: the square side given to chessboards (m): their figures are in pixels and intrinsics
CHESS_SQUARE_M = 0.025
#: most corners of an expected-corners file: the largest board a board spec takes (200x200)
MAX_EXPECTED_CORNERS = 200 * 200


# --------------------------------------------------------------------------- chessboard
def _expected_corners(path: Path) -> np.ndarray | None:
    """OpenCV's expected chessboard corners (N, 2) px from its ``*.dat`` file (FileStorage
    YAML, node ``corners``), or None when it has none. Read as a camera file is, within
    the text files' bounds, never by OpenCV's own parser (a pipe blocks it, a malformed
    file raises inside it, and it allocates whatever rows and cols a header announces).

    Raises:
        InputError: the file or its ``corners`` cannot be used: one line naming them.
    """
    fix = "fix the file or remove it from the folder"
    try:
        data = parse_opencv_yaml(read_text(path, "expected-corners file"), str(path))
    except InputError as e:
        raise InputError(f"{e}; {fix}") from None
    node = data.get("corners") if isinstance(data, dict) else None
    if node is None:
        return None
    values = node.get("data") if isinstance(node, dict) else node
    where = f"{path}: corners"
    if not isinstance(values, list) or not values or len(values) % 2 \
            or len(values) > 2 * MAX_EXPECTED_CORNERS:
        raise InputError(f"{where}: expected a list of x, y pixel pairs (at most "
                         f"{MAX_EXPECTED_CORNERS} corners); {fix}")
    pts = [check_number(v, f"{where}.data", -1e6, 1e6, unit="px") for v in values]
    return np.asarray(pts, np.float64).reshape(-1, 2)


def _chess_size(grays: list[np.ndarray], expected_n: int | None) -> tuple[int, int]:
    for size in CHESS_SIZES:
        if expected_n is not None and size[0] * size[1] != expected_n:
            continue
        for g in grays[:3]:
            found, _ = cv2.findChessboardCorners(g, size, None, cv2.CALIB_CB_ADAPTIVE_THRESH
                                                 | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if found:
                return size
    said = "" if expected_n is None else f" of the {expected_n} corners its *.dat files give"
    raise InputError(f"no chessboard size{said} found in the first images (give --board "
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


@dataclass
class _ChessFigures:
    """What the chessboard photos give, gathered photo by photo."""

    found: dict[str, int] = field(default_factory=lambda: {"drovisio": 0, "opencv": 0})
    e_ours: list[float] = field(default_factory=list)
    """Distances (px) of Drovisio's corners from the expected ones."""
    e_cv: list[float] = field(default_factory=list)
    """Distances (px) of OpenCV's (11x11 cornerSubPix) corners from the expected ones."""
    pts_obj: list[np.ndarray] = field(default_factory=list)
    """(N, 3) board points of each photo OpenCV found the board in (calibration input)."""
    pts_img: list[np.ndarray] = field(default_factory=list)
    """(N, 1, 2) OpenCV's corners of those photos, px."""
    times: dict[str, list[float]] = field(default_factory=lambda: {"drovisio": [],
                                                                   "opencv": []})


def bench_chessboard(photos: PhotoSet, repeat: int, board_spec: str | None,
                     models: list[str]) -> dict[str, Any]:
    """The figures of a calibration set: corners against the expected ones, and the
    calibrations against the reference camera."""
    folder, images, grays = photos.folder, photos.paths, photos.grays
    dats = {p.stem: _expected_corners(p) for p in sorted(folder.glob("*.dat"))}
    expected_n = next((len(v) for v in dats.values() if v is not None), None)
    if board_spec:
        m = re.fullmatch(r"chessboard:(\d+)x(\d+)", board_spec)
        if not m:
            raise InputError(f"--board {board_spec}: give chessboard:COLSxROWS (inner corners)")
        size = (int(m[1]), int(m[2]))
    else:
        size = _chess_size(grays, expected_n)
    board = parse_board(f"chessboard:{size[0]}x{size[1]}", CHESS_SQUARE_M)
    ref_path, ref = folder_camera(photos, required=False)
    rep: dict[str, Any] = {"kind": "chessboard", "folder": str(folder), "board": list(size),
                           "photos": len(images),
                           "reference": str(ref_path) if ref_path else None}
    fig = _ChessFigures()
    objp = np.zeros((size[0] * size[1], 3), np.float32)
    objp[:, :2] = np.mgrid[0:size[0], 0:size[1]].T.reshape(-1, 2) * CHESS_SQUARE_M
    for k, (path, g) in enumerate(zip(images, grays), 1):
        _chess_photo(path, g, board, size, objp, dats, repeat, fig)
        photos.done(k)
    rep["found"] = fig.found
    if dats:
        rep["corners_vs_expected_px"] = {"drovisio": stats(fig.e_ours),
                                         "opencv_11x11": stats(fig.e_cv)}
    rep["ms_per_photo"] = {k: 1000.0 * float(np.median(v)) for k, v in fig.times.items() if v}
    rep["calibration"] = _calibrations(images, grays, size, fig, ref_path, ref, models)
    return rep


def _plain_chessboard(g: np.ndarray, size: tuple[int, int]) -> tuple[bool, Any]:
    """OpenCV's ``findChessboardCorners`` refined by ``cornerSubPix`` (11x11)."""
    ok, c = cv2.findChessboardCorners(g, size, None, cv2.CALIB_CB_ADAPTIVE_THRESH
                                      | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if ok:
        c = cv2.cornerSubPix(g, c, (11, 11), (-1, -1), (cv2.TERM_CRITERIA_EPS
                                                       + cv2.TERM_CRITERIA_COUNT, 30,
                                                       0.01))
    return ok, c


def _chess_photo(path: Path, g: np.ndarray, board: BoardSpec, size: tuple[int, int],
                 objp: np.ndarray, dats: dict[str, np.ndarray | None], repeat: int,
                 fig: _ChessFigures) -> None:
    """One photo: both finders timed, OpenCV's corners kept for its calibration, both
    against the photo's expected corners when the set has them."""
    d, t = timed(partial(board_detect, g, board, still=True), repeat)
    fig.times["drovisio"].append(t)
    (ok, c), t = timed(partial(_plain_chessboard, g, size), repeat)
    fig.times["opencv"].append(t)
    fig.found["drovisio"] += d is not None
    fig.found["opencv"] += bool(ok)
    if ok:
        fig.pts_obj.append(objp)
        fig.pts_img.append(c.reshape(-1, 1, 2))
    exp = dats.get(path.stem.replace("chess", "chess_corners"))
    if exp is None:
        return
    for pts, sink in ((None if d is None else d.corners, fig.e_ours),
                      (c.reshape(-1, 2) if ok else None, fig.e_cv)):
        if pts is None:
            continue
        dist = np.linalg.norm(np.asarray(pts, np.float64)[:, None] - exp[None], axis=2)
        sink.extend(dist.min(axis=1))


def _calibrations(images: list[Path], grays: list[np.ndarray], size: tuple[int, int],
                  fig: _ChessFigures, ref_path: Path | None, ref: Camera | None,
                  models: list[str]) -> dict[str, Any]:
    """Plain OpenCV's and ``drovisio calibrate``'s intrinsics on the photos OpenCV found the
    board in, each against the reference (the folder's camera file, else plain OpenCV)."""
    fisheye = bool(ref is not None and (ref.model == "fisheye" or len(np.ravel(ref.dist)) == 4))
    calib: dict[str, Any] = {}
    if len(fig.pts_obj) < 3:
        return calib
    wh = (grays[0].shape[1], grays[0].shape[0])
    calib["opencv"] = _opencv_calibration(fig.pts_obj, fig.pts_img, wh, fisheye)
    # no published camera file: plain OpenCV's solve of the same corners is the reference
    refd = ({"fx": float(ref.K[0, 0]), "fy": float(ref.K[1, 1]), "cx": float(ref.K[0, 2]),
             "cy": float(ref.K[1, 2]), "source": str(ref_path)} if ref is not None else
            {**{k: v for k, v in calib["opencv"].items() if k in ("fx", "fy", "cx", "cy")},
             "source": "plain OpenCV (no camera file in the folder)"})
    calib["reference"] = refd
    for model in models:
        model = ("fisheye" if fisheye else "plumb_bob") if model == "reference" else model
        say(f"  ... {images[0].parent}: drovisio calibrate --model {model} on "
            f"{len(images)} photos")
        got, why = _calibrate_cli(images, f"chessboard:{size[0]}x{size[1]}", model)
        calib[f"drovisio_{model}"] = got if got is not None else {"failed": why}
    _errors_vs_reference(calib, refd)
    return calib


def _errors_vs_reference(calib: dict[str, Any], refd: dict[str, Any]) -> None:
    """Each calibration's fx, fy, cx, cy against the reference's, in percent."""
    for v in calib.values():
        if "fx" in v and "fx" in refd and v is not refd:
            v["error_pct"] = {k: 100.0 * (v[k] - refd[k]) / refd[k]
                              for k in ("fx", "fy", "cx", "cy")}


def _opencv_calibration(pts_obj: list[np.ndarray], pts_img: list[np.ndarray],
                        wh: tuple[int, int], fisheye: bool) -> dict[str, Any]:
    """``cv2.calibrateCamera`` (or ``cv2.fisheye.calibrate``) on the corners; the failure
    in one line when it fails."""
    try:
        K: Any = np.eye(3)
        D: Any = np.zeros(4)
        if fisheye:
            # OpenCV 5's fisheye solve takes each view as one row of points (1, N, 3) and
            # (1, N, 2); another shape fails in its argument checks, not in the solve
            rms, K, D, _, _ = cv2.fisheye.calibrate(
                [o.reshape(1, -1, 3).astype(np.float64) for o in pts_obj],
                [i.reshape(1, -1, 2).astype(np.float64) for i in pts_img], wh, K, D,
                flags=cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW)
        else:
            rms, K, D, _, _ = cv2.calibrateCamera(pts_obj, pts_img, wh, K, np.zeros(5))
        return {"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                "cx": float(K[0, 2]), "cy": float(K[1, 2]),
                "model": "fisheye" if fisheye else "plumb_bob",
                "rms_px": float(rms)}
    except cv2.error as e:   # said by its function and check, not OpenCV's source path
        what = "fisheye.calibrate" if fisheye else "calibrateCamera"
        why = one_line(f"in {e.func}: {e.err}" if getattr(e, "func", "") else e, 160)
        return {"failed": f"OpenCV's {what} failed {why}"}


# --------------------------------------------------------------------------- printing
def _fmt(s: dict, unit: str = "", nd: int = 2) -> str:
    if not s["n"]:
        return "-"
    return (f"{s['median']:.{nd}f} / {s['p90']:.{nd}f} / {s['max']:.{nd}f}{unit} "
            f"(n {s['n']})")


def _print(rep: dict[str, Any]) -> None:
    """One folder's figures as a few lines on stdout."""
    print(f"\n== {rep['folder']} ({rep['kind']}, {rep['photos']} photos)")
    ms = rep.get("ms_per_photo", {})
    if rep["kind"] == "tags":
        _print_tags(rep)
    elif rep["kind"] == "charuco":
        _print_charuco(rep)
    else:
        _print_chessboard(rep)
    if ms:
        print("   ms per photo (median): " + ", ".join(
            f"{k} {v:.1f}" for k, v in ms.items() if v is not None))


def _print_tags(rep: dict[str, Any]) -> None:
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
    e = rep["edge_reference"]
    if e["apriltag_vs_edges"]["n"]:
        off = e["apriltag_mean_offset_px"]
        print(f"   against the outer edge lines (codes >= 15 px, clean edges; {e['unclean']} "
              f"not clean), corner RMS per code, px: AprilTag 3 {_fmt(e['apriltag_vs_edges'])},"
              f" Drovisio {_fmt(e['drovisio_vs_edges'])}; AprilTag's mean offset "
              f"({off[0]:+.3f}, {off[1]:+.3f}) px; of {e['apart_over_half_px']} codes where "
              f"they differ by > 0.5 px the edges side with AprilTag on "
              f"{e['apart_edges_side_with_apriltag']}")


def _print_charuco(rep: dict[str, Any]) -> None:
    n = rep["codes"]
    print(f"   board {rep['board_squares'][0]}x{rep['board_squares'][1]} squares, "
          f"{rep['dictionary']}, camera {rep['camera']}; AprilTag 3: {rep['apriltag']}")
    print(f"   codes found: Drovisio {n['drovisio']}, OpenCV {n['opencv']}, AprilTag 3 "
          f"{n['apriltag']}; ChArUco corners {n['charuco_corners']}; bricks posed "
          f"{n['photos_posed']}, ambiguous {n['ambiguous']}")
    a = rep["corners_rms_px"]
    print(f"   corner RMS per code vs AprilTag 3, px (median / p90 / max): Drovisio "
          f"{_fmt(a['drovisio_vs_apriltag'])}; OpenCV {_fmt(a['opencv_vs_apriltag'])}")
    w = rep["codes_within_half_px"]
    print(f"   Drovisio's codes within 0.5 px RMS of AprilTag 3's corners {w['of_apriltag']}, "
          f"of the board pose's prediction {w['of_board']}, of either {w['of_either']}, of "
          f"{w['codes']} both read")
    c = rep["corners_vs_board_px"]
    print(f"   code corners vs the board pose's prediction, px (median / p90 / max): "
          f"Drovisio {_fmt(c['drovisio'])}; OpenCV {_fmt(c['opencv'])}; AprilTag 3 "
          f"{_fmt(c['apriltag'])}")
    print(f"   the prediction itself: board pose RMS on its ChArUco corners "
          f"{_fmt(rep['board_pose_rms_px'], ' px', 3)}; Drovisio vs the board plane's "
          f"homography {_fmt(c['drovisio_vs_homography'])}")
    s = rep["code_shift_px"]
    r = s["correlation_xy"]
    corr = "" if r is None else f" (correlation x {r[0]:.2f}, y {r[1]:.2f})"
    print(f"   each code's shift from the prediction (its corners' mean error), px: Drovisio "
          f"{_fmt(s['drovisio'])}; OpenCV {_fmt(s['opencv'])}; the two shifts differ by "
          f"{_fmt(s['difference'])}{corr}")
    r = s["correlation_xy_apriltag"]
    if s["apriltag"]["n"]:
        corr = "" if r is None else f" (correlation x {r[0]:.2f}, y {r[1]:.2f})"
        print(f"     AprilTag 3's shifts {_fmt(s['apriltag'])}, differing from Drovisio's by "
              f"{_fmt(s['difference_apriltag'])}{corr}")
    print(f"   Drovisio's code corners with each code's own shift removed: "
          f"{_fmt(c['drovisio_shift_removed'])}")
    p = rep["pose_vs_board"]
    print(f"   brick pose vs ChArUco board pose: {_fmt(p['trans_mm'], ' mm', 2)}, "
          f"{_fmt(p['rot_deg'], '°', 3)}")


def _print_chessboard(rep: dict[str, Any]) -> None:
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


def main(argv: list[str]) -> int:
    from drovisio.bounds import ArgumentParser, number

    p = ArgumentParser(prog="drovisio bench real", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folders", nargs="+", metavar="DIR", help="folders of real photos")
    p.add_argument("--repeat", type=int, default=1,
                   help="timed runs per photo and method, the fastest kept (1-20; default 1)")
    p.add_argument("--tag-size", type=number(0.001, 10.0, unit="m"), default=0.065,
                   help="side of the tags' black square, m (0.001-10; default 0.065)")
    p.add_argument("--board", default=None,
                   help="charuco:COLSxROWS or chessboard:COLSxROWS (inner corners; default: "
                        "guessed)")
    # the sides a board spec and a layout take (1 mm to 1 m): OpenCV builds a board of
    # any side, 1e-300 m included, and fails inside
    p.add_argument("--square", type=number(0.001, 1.0, unit="m"), default=0.04,
                   help="ChArUco square side, m (0.001-1; default 0.04)")
    p.add_argument("--marker", type=number(0.001, 1.0, unit="m"), default=0.02,
                   help="ChArUco code side, m (0.001-1; default 0.02)")
    p.add_argument("--calibrate", default="reference,auto",
                   help="drovisio calibrate models to run on chessboard sets: reference (the "
                        "reference file's model), auto, plumb_bob, rational, fisheye, none "
                        "(default reference,auto)")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON")
    args = p.parse_args(argv)
    folders = []
    for f in args.folders:
        path = Path(f)
        if not path.is_dir():
            raise InputError(f"{f}: {missing_reason(path) or 'not a folder'}; give folders of "
                             "real photos")
        folders.append(path)
    models = _checked(args, folders)
    cv2.setNumThreads(1)
    reports = []
    for folder in folders:
        photos = read_photos(folder)
        kind = detect_kind(photos)
        say(f"  ... {folder}: {kind}, {len(photos.paths)} photos read")
        if kind == "tags":
            rep = bench_tags(photos, args.repeat, args.tag_size)
        elif kind == "charuco":
            rep = bench_charuco(photos, args.repeat, args.board, args.square, args.marker)
        else:
            rep = bench_chessboard(photos, args.repeat, args.board, models)
        _print(rep)
        reports.append(rep)
    if args.json:
        atomic_write_text(args.json, json.dumps({"folders": reports}, indent=1,
                                                allow_nan=False, default=float))
    return 0


def _checked(args: argparse.Namespace, folders: list[Path]) -> list[str]:
    """The options checked together (and the ``--json`` path, by the one output guard,
    against every file the folders are read for: their photos, camera files and expected
    corners); the calibration models to run.

    Raises:
        InputError: in one line, naming the option.
    """
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
        inputs: dict[str, Path] = {}
        for folder in folders:
            inputs[f"DIR {folder}"] = folder
            for f in [*camera_files(folder), *folder.glob("*.dat")]:
                inputs[f"{f.name} of DIR {folder}"] = f
        check_output_path(args.json, "--json", inputs, folder_must_exist=True)
    return models
