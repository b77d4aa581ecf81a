"""``drovisio calibrate``: calibrate a camera from chessboard images (DESIGN.md contract).

::

    drovisio calibrate --board chessboard:9x6 --square 0.025 [--report REPORT.json]
                       --out CAMERA.yaml IMAGE_OR_FOLDER...

Writes CAMERA.yaml (OpenCV FileStorage; ``.json``/``.xml`` suffixes give those OpenCV forms) and
a ROS ``camera_info`` file beside it (``CAMERA.ros.yaml``), and with ``--report`` the report
JSON of :mod:`drovisio.calibration.report`. Progress goes to stderr, one line per image.

Exit codes: 0 calibrated (even when the verdict is "not ok": the verdict is in the report and
on stderr); 1 nothing could be calibrated (no board found, too few usable views, degenerate
views, or a solve that did not converge or that the views do not determine: one line says
the cause and the fix, and no camera file is written); 2 bad arguments (board spec, missing path, no images, an output that is an input or
another output, a full disk: nothing already saved is replaced).

The same picture given twice (the board within 0.5 px of a kept view) is refused, as on the
calibration page: it adds no information and makes the intrinsics look certain.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

from drovisio.arguments import Command, board_square, mount_offset
from drovisio.errors import InputError
from drovisio.fileio import atomic_write_text, check_output_path

__all__ = ["BOARD_COMMAND", "COMMAND", "MOUNT_COMMAND", "add_arguments", "add_board_arguments",
           "add_mount_arguments", "collect_images", "measure_mount_command", "print_board",
           "run"]

# The command's own modules (OpenCV, the calibration; numpy too) are imported inside the
# functions that run it: `drovisio --help` imports every command module and must stay light.

PROG = "drovisio calibrate"


def _err(msg: str) -> None:
    print(f"{PROG}: {msg}", file=sys.stderr, flush=True)


def collect_images(inputs: list[str]) -> list[Path]:
    """Image files from the arguments (folders: their image files in name order).

    Raises:
        InputError: a path is missing, or no image at all.
    """
    from drovisio.images import IMAGE_SUFFIXES
    from drovisio.textfile import missing_reason

    files: list[Path] = []
    for raw in inputs:
        p = Path(raw)
        why = missing_reason(p)
        if why:
            raise InputError(f"{raw}: {why}")
        if p.is_dir():
            found = sorted(f for f in p.iterdir()
                           if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise InputError(f"{raw}: folder contains no images ("
                                 + ", ".join(sorted(IMAGE_SUFFIXES)) + ")")
            files.extend(found)
        else:
            files.append(p)
    seen, unique = set(), []
    for f in files:
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(f)
    if not unique:
        raise InputError("no images given")
    return unique


def _ros_path(out: Path) -> Path:
    return out.with_name(out.stem + ".ros.yaml")


def _write_json_atomic(path: Path, data: dict) -> None:
    text = json.dumps(data, indent=1, allow_nan=False) + "\n"
    atomic_write_text(path, text, make_parents=True, verify=lambda tmp: json.loads(
        tmp.read_text(encoding="utf-8")))


def _nearby_sizes(cols: int, rows: int) -> list[tuple[int, int]]:
    """Chessboard sizes (inner corners) a person may have miscounted ``cols x rows`` for:
    the nearest first, then the common boards."""
    cands: list[tuple[int, int]] = []
    for dc in (-1, 0, 1, -2, 2):
        for dr in (-1, 0, 1, -2, 2):
            c, r = cols + dc, rows + dr
            if (dc or dr) and c >= 3 and r >= 3:
                cands.append((c, r))
    cands += [(9, 6), (7, 6), (8, 6), (7, 5), (6, 4), (10, 7), (11, 8), (8, 5)]
    seen_c: list[tuple[int, int]] = []
    for size in cands:
        if size not in seen_c and size != (cols, rows):
            seen_c.append(size)
    return seen_c


def _probe_board_size(images: list[Path], board) -> str | None:
    """On a few readable images, try nearby chessboard sizes; say which one is there
    (at most ~2 s: the detector is slow on cluttered images)."""
    import cv2

    from drovisio.calibration.board import to_gray
    from drovisio.images import ImageError, read_image

    seen_c = _nearby_sizes(board.cols, board.rows)
    deadline = time.monotonic() + 2.0
    for path in images[:3]:
        if time.monotonic() > deadline:
            break
        try:
            gray = to_gray(read_image(path, gray=True)[0])
        except ImageError:
            continue
        for c, r in seen_c:
            if time.monotonic() > deadline:
                break
            found, _ = cv2.findChessboardCorners(
                gray, (c, r), None, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                | cv2.CALIB_CB_FAST_CHECK)
            if found:
                return (f"a {c}x{r} chessboard is visible in {path.name}: did you mean "
                        f"--board chessboard:{c}x{r}? (inner corners: a board of "
                        f"{c + 1}x{r + 1} squares is {c}x{r})")
    return None


def _outputs(args: argparse.Namespace, images: list[Path]) -> tuple[Path, Path, Path | None]:
    """The camera file, the ROS camera file beside it and the report (or None), each checked
    against the inputs and the others."""
    inputs = {f"input {p}": p for p in images}
    out = check_output_path(args.out, "--out", inputs)
    ros = _ros_path(out)
    check_output_path(ros, "the ROS camera file written beside --out", inputs)
    report_path = None
    if getattr(args, "report", None):
        report_path = check_output_path(args.report, "--report",
                                        {**inputs, "--out": out, "the ROS camera file "
                                         "written beside --out": ros})
    return out, ros, report_path


def _evaluate_images(session, images: list[Path]) -> tuple[list, int]:
    """Find the board in every image, saying one line per image: (the evaluated frames, how
    many images could be read)."""
    from drovisio.images import ImageError, read_image

    n = len(images)
    width = len(str(n))
    frames = []  # FrameResult per readable image
    n_read = 0
    for i, path in enumerate(images, 1):
        name = str(path)
        tag = f"[{i:>{width}}/{n}] {path.name}"
        try:
            img, _notes = read_image(path)
        except ImageError as e:
            session.add_rejected(name, str(e))
            print(f"{tag}: rejected: {e}", file=sys.stderr, flush=True)
            continue
        n_read += 1
        fr = session.evaluate(img, name, still=True)
        del img
        frames.append(fr)
        if fr.usable and fr.detection is not None:
            edges = f", edges {fr.sharpness.width_px:.1f} px" if fr.sharpness else ""
            print(f"{tag}: {fr.detection.n} corners, squares {fr.detection.square_px:.0f} px"
                  f"{edges}", file=sys.stderr, flush=True)
        else:
            print(f"{tag}: rejected: {'; '.join(fr.reasons)}", file=sys.stderr, flush=True)
    return frames, n_read


def _one_size(frames: list) -> tuple[list, tuple[int, int]]:
    """The frames that have a size, and the one resolution calibrated: the one most usable
    views (then most images) have; mixed sizes are said."""
    sized = [(fr, fr.image_size) for fr in frames if fr.image_size is not None]
    sizes = Counter(s for fr, s in sized if fr.usable) or Counter(s for _, s in sized)
    size, _ = sizes.most_common(1)[0]
    all_sizes = Counter(s for _, s in sized)
    if len(all_sizes) > 1:
        desc = ", ".join(f"{c} at {w}x{h}" for (w, h), c in all_sizes.most_common())
        _err(f"mixed image sizes ({desc}); calibrating the {size[0]}x{size[1]} images (a "
             "calibration belongs to one resolution)")
    return sized, size


def _keep_views(session, frames: list) -> None:
    """Keep the usable views of the one resolution, each once; reject the others with why."""
    sized, size = _one_size(frames)
    for fr, fsize in sized:
        if fsize != size:
            session.add_rejected(fr.name, f"image size {fsize[0]}x{fsize[1]} "
                                          f"differs from the {size[0]}x{size[1]} of the others")
        elif fr.usable and fr.detection is not None:
            dup = session.duplicate_of(fr.detection)
            if dup is None:
                session.keep(fr)
            else:
                twin = next(v.name for v in session.views if v.id == dup)
                why = (f"the same picture as {Path(twin).name} (the board at the same place "
                       "within 0.5 px): it adds nothing and would make the result look "
                       "more certain than it is")
                session.add_rejected(fr.name, why)
                print(f"{Path(fr.name).name}: rejected: {why}", file=sys.stderr, flush=True)
        else:
            session.add_rejected(fr.name, "; ".join(fr.reasons) or "not usable")


def _too_few_views(session, frames: list, images: list[Path], board, n_read: int) -> bool:
    """Say why the views cannot be solved (no board found, fewer than 3 usable); True then."""
    n = len(images)
    kept = len(session.views)
    if not any(fr.detection is not None for fr in frames):
        _err(f"no {board.spec()} board found in any of the {n_read} image(s)")
        hint = _probe_board_size(images, board) if board.kind == "chessboard" else None
        print("  " + (hint or f"check --board: {board.cols}x{board.rows} counts INNER corners "
                      f"(a board of {board.cols + 1}x{board.rows + 1} squares)"
                      + ("; the whole board must be visible" if board.kind == "chessboard"
                         else "")), file=sys.stderr)
        return True
    if kept < 3:
        _err(f"only {kept} usable view(s) of {n} image(s); a calibration needs at least 3 "
             "(10 or more, varied, for a good one)")
        return True
    return False


def _write_results(result, session, out: Path, ros: Path, report_path: Path | None) -> None:
    """Write the camera files (and the report) and print the summary."""
    from drovisio.calibration.report import build_report, format_summary
    from drovisio.camera_file import save_camera

    cam = result.camera
    report = build_report(session)
    save_camera(cam, out)
    save_camera(cam, ros, fmt="ros")
    if report_path is not None:
        _write_json_atomic(report_path, report)
    print(format_summary(report), file=sys.stderr)
    if result.model_choice is not None:
        print(f"lens model: {result.model_choice['reason']}", file=sys.stderr)
    flat = result.board_flatness
    if flat is not None:
        print("board flatness: " + (flat["summary"] if flat["computed"] else
                                    f"not computed: {flat['reason']}"), file=sys.stderr)
    print(f"wrote {out} (OpenCV) and {ros} (ROS camera_info)"
          + (f", report {report_path}" if report_path else ""), file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """``drovisio calibrate``: 0 when the camera file was written, 1 when the images do not
    calibrate (said in one line, the report written all the same)."""
    # deferred: the calibration loads OpenCV, which `drovisio --help` must not
    from drovisio.calibration.board import BoardSpecError, parse_board
    from drovisio.calibration.report import build_report
    from drovisio.calibration.session import CalibrationSession, SessionConfig
    from drovisio.calibration.solve import CalibrationError, SolveOptions

    try:
        board = parse_board(args.board, args.square)
    except BoardSpecError as e:
        raise InputError(str(e)) from None
    images = collect_images(list(args.images))
    out, ros, report_path = _outputs(args, images)
    session = CalibrationSession(board, config=SessionConfig(
        camera_name=out.stem or "camera", solve=SolveOptions(
            model=args.model, board_flatness=args.board_flatness)))
    frames, n_read = _evaluate_images(session, images)
    if n_read == 0:
        _err(f"none of the {len(images)} file(s) could be read as an image")
        _maybe_report(report_path, session, build_report)
        return 1
    _keep_views(session, frames)
    if _too_few_views(session, frames, images, board, n_read):
        _maybe_report(report_path, session, build_report)
        return 1
    print(f"solving with {len(session.views)} views...", file=sys.stderr, flush=True)
    try:
        result = session.solve()
    except CalibrationError as e:
        _err(f"calibration failed: {e}")
        _maybe_report(report_path, session, build_report)
        return 1
    _write_results(result, session, out, ros, report_path)
    return 0


def _maybe_report(path: Path | None, session, build_report) -> None:
    if path is None:
        return
    try:
        _write_json_atomic(path, build_report(session))
        print(f"report written to {path}", file=sys.stderr)
    except OSError as e:   # the calibration failed already: say both
        _err(str(e))


def print_board(args: argparse.Namespace) -> int:
    """``drovisio calibrate board``: the board as a true-scale PDF."""
    from drovisio.calibration.board import BoardSpecError, parse_board
    from drovisio.calibration.printout import board_pdf

    try:
        board = parse_board(args.board, args.square or 0.025)
    except BoardSpecError as e:
        raise InputError(str(e)) from None
    out = check_output_path(args.pdf, "--pdf", {})
    info = board_pdf(board, out, args.paper,
                     None if args.square is None else args.square * 1000.0)
    w, h = info["board_mm"]
    print(f"wrote {out}: {board.spec()} on {info['paper']} "
          f"({'landscape' if info['landscape'] else 'portrait'}), squares of "
          f"{info['square_mm']:g} mm, board {w:g} x {h:g} mm. Print at 100 % and check the "
          "100 mm ruler; then calibrate with --square set to a square as measured (in metres).",
          file=sys.stderr)
    return 0


def measure_mount_command(args: argparse.Namespace) -> int:
    """``drovisio calibrate mount``: the mount from a code lying flat, the drone level."""
    from drovisio.calibration.mount import measure_from_images
    from drovisio.camera_file import load_camera
    from drovisio.images import ImageError, read_image
    from drovisio.layout import load_layout, shipped_layouts_dir
    from drovisio.mount import Mount, body_from_camera_angles, load_mount

    camera = load_camera(args.camera)
    paths = args.layout or [str(p) for p in sorted(shipped_layouts_dir().glob("*.json"))]
    layouts = [load_layout(p) for p in paths]
    if not any(lay.has_codes for lay in layouts):
        raise InputError("--layout: none of these layouts has ArUco codes; measuring the mount "
                         "needs a code lying flat (the shipped landing-pad.json is best)")
    images = collect_images(list(args.images))
    out = check_output_path(args.out, "--out", {f"input {p}": p for p in images})

    def pictures():
        for path in images:
            try:
                yield path.name, read_image(path)[0]
            except ImageError as e:
                yield path.name, str(e)

    measured = measure_from_images(pictures(), camera, layouts, aligned=args.aligned)
    for line in measured.lines:
        print(line, file=sys.stderr)
    m = measured.result
    pan = m["pan_deg"] if m["pan_deg"] is not None else 0.0
    pan_known = m["pan_deg"] is not None
    note = (f"measured from {m['n']} picture(s) of a code lying flat"
            + ("" if pan_known else "; pan not measured (set to 0): use --aligned with "
               "the landing pad's arrow toward the nose"))
    mount = Mount(body_from_camera_angles(m["tilt_deg"], pan, m["roll_deg"], args.offset),
                  note=note)
    # read back as `run --mount` reads it: a file it would refuse is never written
    atomic_write_text(out, json.dumps(mount.to_file(), indent=1) + "\n",
                      verify=lambda tmp: load_mount(tmp))
    print(f"tilt {m['tilt_deg']:.2f}°, roll {m['roll_deg']:.2f}°, pan "
          + (f"{pan:.2f}°" if pan_known else "not measured (set to 0)")
          + f" (largest difference between pictures {m['spread_deg']:.2f}°); wrote {out}",
          file=sys.stderr)
    if camera.size_known:   # where a straight descent onto each brick goes blind
        from drovisio.autopilot.blind import blind_heights_text

        for lay in layouts:
            print(blind_heights_text(camera, mount, lay), file=sys.stderr)
    return 0


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio calibrate``'s arguments."""
    p.add_argument("--board", required=True, metavar="KIND:COLSxROWS",
                   help="calibration target, e.g. chessboard:9x6 (inner corners, columns x rows)")
    p.add_argument("--square", required=True, type=board_square, metavar="METRES",
                   help="side of one board square in metres, e.g. 0.025")
    p.add_argument("--report", metavar="REPORT.json",
                   help="write the calibration report (errors, rejected views, verdict) here")
    p.add_argument("--out", required=True, metavar="CAMERA.yaml",
                   help="camera file to write (OpenCV FileStorage form)")
    p.add_argument("--model", default="plumb_bob",
                   choices=("auto", "plumb_bob", "rational", "thin_prism", "tilted", "fisheye"),
                   help="lens model: plumb_bob (OpenCV's 5 coefficients, default), rational "
                        "(8), thin_prism (12: rational + thin prism), tilted (14: + the "
                        "sensor's tilt), fisheye (Kannala-Brandt, 4: lenses of 120 deg and "
                        "more), or auto (plumb_bob, rational or fisheye, chosen on held-out "
                        "views; the report says why)")
    p.add_argument("--board-flatness", action="store_true",
                   help="also measure how far the board bowed (fitted with the lens, as "
                        "mrcal's board warp): a bow of a millimetre "
                        "moves the focal length by about 1 %%; the report says it")
    p.add_argument("images", nargs="+", metavar="IMAGE_OR_FOLDER",
                   help="calibration images, or folders of them")


def add_board_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio calibrate board``'s arguments."""
    p.add_argument("--pdf", required=True, metavar="BOARD.pdf", help="PDF file to write")
    p.add_argument("--board", default="chessboard:9x6", metavar="KIND:COLSxROWS",
                   help="chessboard:9x6 (default) or charuco:7x5 (inner corners)")
    p.add_argument("--paper", default="A4", choices=("A4", "A3", "Letter"),
                   help="paper size (default A4); the board is as large as fits")
    p.add_argument("--square", type=board_square, metavar="METRES",
                   help="side of one square on paper (default: the largest whole mm that fits)")


def add_mount_arguments(p: argparse.ArgumentParser) -> None:
    """``drovisio calibrate mount``'s arguments."""
    p.add_argument("--camera", required=True, metavar="CAMERA_FILE", help="camera file")
    p.add_argument("--layout", action="append", metavar="LAYOUT.json",
                   help="layout of the code lying flat (default: the shipped landing pad and "
                        "dricks)")
    p.add_argument("--aligned", action="store_true",
                   help="the code's x axis points toward the drone's nose: measure the pan too")
    p.add_argument("--offset", nargs=3, type=mount_offset, default=(0.0, 0.0, 0.0),
                   metavar=("FORWARD", "RIGHT", "DOWN"),
                   help="the camera's centre from the body origin, metres (measured with a "
                        "tape; default 0 0 0)")
    p.add_argument("--out", required=True, metavar="MOUNT.json", help="mount file to write")
    p.add_argument("images", nargs="+", metavar="IMAGE_OR_FOLDER",
                   help="pictures from the drone's camera, the drone standing level")


COMMAND = Command(
    name="calibrate",
    summary="calibrate a camera from chessboard images",
    description="Calibrate the camera and its lens model (--model) from views of a "
                "chessboard or ChArUco board. Writes the camera file and, with --report, "
                "the RMS reprojection error, per-view errors, rejected views and corners, "
                "and a verdict. To print a board first: drovisio calibrate board --pdf "
                "board.pdf [--board chessboard:9x6] [--paper A4|A3|Letter].",
    example="drovisio calibrate --board chessboard:9x6 --square 0.025 \\\n"
            "    --report report.json --out camera.yaml calib_images/",
    add_arguments=add_arguments,
)


BOARD_COMMAND = Command(
    name="calibrate-board",
    spelled="calibrate board",
    summary="write the calibration board to print (true-scale PDF)",
    description="Write a true-scale PDF of a calibration board to print, with a 100 mm "
                "ruler to check the print; measure a printed square and give it to "
                "--square when calibrating.",
    example="drovisio calibrate board --pdf board.pdf --board chessboard:9x6 --paper A4",
    add_arguments=add_board_arguments,
    target="drovisio.commands.calibrate:print_board",
)


MOUNT_COMMAND = Command(
    name="calibrate-mount",
    spelled="calibrate mount",
    summary="measure the camera mount from pictures of the landing pad",
    description="Measure the camera mount (tilt, roll, and pan with --aligned) from "
                "pictures of a shipped code lying flat (the landing pad is best) in "
                "front of the drone standing level, and write the mount file.",
    example="drovisio calibrate mount --camera sample_sessions/camera.yaml --aligned "
            "--offset 0.08 0 0.05 \\\n    --out mount.json sample_sessions/pad",
    add_arguments=add_mount_arguments,
    target="drovisio.commands.calibrate:measure_mount_command",
)
