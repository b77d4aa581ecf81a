"""Images taken elsewhere, uploaded to the calibration page: the first pass over the files
(which are images, their sizes), the checks of size, the summary in plain words, and the probe
for another board size when no board was found.

The files are read twice (sizes first, then one at a time for detection), so that a big folder
never sits decoded in memory at once; the second pass is the service's (it keeps views).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

import cv2
import numpy as np

from drovisio.calibration.board import BoardSpec
from drovisio.calibration.session import CalibrationSession
from drovisio.images import IMAGE_SUFFIXES
from webtool.calibration.pictures import decode

__all__ = [
    "MAX_UPLOAD_BYTES",
    "Row",
    "Size",
    "measure",
    "probe_board",
    "read_upload",
    "summary",
    "target_size",
    "upload_label",
    "wrong_size",
]

MAX_UPLOAD_BYTES = 64 * 1024 * 1024  # per file
Size = tuple[int, int]  # (width, height), pixels
Row = dict[str, Any]    # one file's line of the answer: file, ok, message (view_id, skipped)


def upload_label(name: str, index: int) -> str:
    """What to call an uploaded file (its name, else "file N")."""
    return name or f"file {index + 1}"


def read_upload(fh: BinaryIO) -> bytes | None:
    """The file's bytes from its start; None when it is over :data:`MAX_UPLOAD_BYTES`."""
    fh.seek(0)
    data = fh.read(MAX_UPLOAD_BYTES + 1)
    return None if len(data) > MAX_UPLOAD_BYTES else data


def _measure_one(label: str, fh: BinaryIO, session: CalibrationSession) -> Row | Size:
    """The image size of one file, or its answer row when it cannot be used."""
    if Path(label).suffix.lower() not in IMAGE_SUFFIXES:
        return {"file": label, "ok": False, "skipped": True,
                "message": "skipped: not an image file"}
    data = read_upload(fh)
    if data is None:
        return {"file": label, "ok": False, "message": "too large (over "
                f"{MAX_UPLOAD_BYTES // (1024 * 1024)} MB): not a camera image?"}
    img, why = decode(data, label)
    if img is None:
        session.add_rejected(label, str(why))
        return {"file": label, "ok": False, "message": why}
    return (img.shape[1], img.shape[0])


def measure(files: Sequence[tuple[str, BinaryIO]], session: CalibrationSession
            ) -> tuple[list[Row | None], dict[int, Size]]:
    """The first pass: an answer row for each file that cannot be used (not an image, too
    large, undecodable: recorded as rejected in ``session``) and the size of each other one
    (by index)."""
    results: list[Row | None] = [None] * len(files)
    sizes: dict[int, Size] = {}
    for i, (name, fh) in enumerate(files):
        got = _measure_one(upload_label(name, i), fh, session)
        if isinstance(got, dict):
            results[i] = got
        else:
            sizes[i] = got
    return results, sizes


def target_size(session_size: Size | None, sizes: dict[int, Size]) -> Size | None:
    """The size every image must have: the session's, else the most common of the upload."""
    if session_size is None and sizes:
        return Counter(sizes.values()).most_common(1)[0][0]
    return session_size


def wrong_size(size: Size, target: Size, *, mixed: bool, session_sized: bool) -> str:
    """Why an image of another size than the session's is not kept."""
    return (f"wrong size: {size[0]}×{size[1]}, but this session's images are "
            f"{target[0]}×{target[1]} (a calibration belongs to one image size"
            + ("; the most common size of this upload was kept" if mixed and
               not session_sized else "; start a new session for these")
            + ")")


def summary(results: Sequence[Row | None], kept: int, no_board: bool, board: BoardSpec,
            hint: str | None) -> str:
    """The upload's one-line summary ("3 of 5 images kept…").

    Args:
        results: Every file's answer row.
        kept: Views kept.
        no_board: There were images, and no board was found in any of them.
        board: The session's board.
        hint: Which other board size is visible, if one was found.
    """
    n_images = sum(1 for r in results if not (r or {}).get("skipped"))
    text = (f"{kept} of {n_images} image{'s' if n_images != 1 else ''} kept"
            if n_images else "No images in this upload (.jpg, .png …).")
    if no_board:
        text += f". No {board.spec()} board was found in any of them"
        text += f": {hint}" if hint else (
            f" — check that the whole board is visible and that it has "
            f"{board.cols + 1}×{board.rows + 1} squares")
    return text


def _probe_sizes(board: BoardSpec) -> list[tuple[int, int]]:
    """Chessboard sizes (inner corners) to try: the usual printed boards first (each wrong
    size costs ~0.15 s), then the near misses of ``board``."""
    cands = [(9, 6), (7, 6), (8, 6), (7, 5), (6, 4), (10, 7), (11, 8), (8, 5)]
    cands += [(board.cols + dc, board.rows + dr) for dc in (-1, 0, 1, -2, 2)
              for dr in (-1, 0, 1, -2, 2)
              if (dc or dr) and board.cols + dc >= 3 and board.rows + dr >= 3]
    return [c for i, c in enumerate(cands)
            if c not in cands[:i] and c != (board.cols, board.rows)]


def probe_board(board: BoardSpec, grays: list[tuple[str, np.ndarray]]) -> str | None:
    """Which other chessboard size is visible in one of ``grays`` ((label, grey image (H, W)
    uint8)), in plain words; None when none is (or after ~3 s)."""
    if board.kind != "chessboard":
        return None
    cands = _probe_sizes(board)
    deadline = time.monotonic() + 3.0
    for label, gray in grays:
        for c in cands:
            if time.monotonic() > deadline:
                return None
            found, _ = cv2.findChessboardCorners(
                gray, c, None, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                | cv2.CALIB_CB_FAST_CHECK)
            if found:
                return (f"a chessboard with {c[0]}×{c[1]} inner corners is visible in "
                        f"{label}: start a new session with that board size")
    return None
