"""A true-scale PDF of the calibration board, to print: chessboard or ChArUco, on A4, A3 or
Letter, with a 100 mm ruler to check that the printer kept the scale.

Scale is exact by construction: the page is drawn in millimetres of paper as vectors
(:mod:`drovisio.printing`, the writer of the designer's print sheets too); ChArUco markers are
drawn cell by cell from OpenCV's dictionary. Printers often shrink a page "to fit": the ruler
and the page's instructions say to print at 100 % and to measure a square before solving.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drovisio.calibration.board import BoardSpec
from drovisio.errors import InputError
from drovisio.fileio import atomic_write_bytes
from drovisio.layout import aruco_code_bits
from drovisio.printing import Page, pdf_bytes

__all__ = ["PAPER_MM", "board_pdf", "board_pdf_bytes", "fit_square_mm"]

PAPER_MM = {"A4": (210.0, 297.0), "A3": (297.0, 420.0), "Letter": (215.9, 279.4)}
"""Paper sizes (width, height) in millimetres, portrait."""

MARGIN_MM = 15.0
"""Blank border kept on every side (most printers cannot print the last 5 mm)."""
RULER_BAND_MM = 30.0
"""Height kept below the board for the ruler and the instructions."""
MIN_SQUARE_MM = 5.0
"""Smallest square printed: below it the printer's ink and the camera's blur merge them."""


def _paper(paper: str) -> tuple[float, float]:
    for name, size in PAPER_MM.items():
        if name.lower() == str(paper).lower():
            return size
    raise InputError(f"paper {paper!r} is not known: use A4, A3 or Letter")


def _layout(board: BoardSpec, paper: str) -> tuple[tuple[float, float], bool]:
    """(paper size (w, h) mm in the orientation that fits the board best, landscape?)."""
    w, h = _paper(paper)
    sq_cols, sq_rows = board.cols + 1, board.rows + 1
    # the orientation where the board's longer side lies along the paper's longer side
    landscape = (sq_cols >= sq_rows)
    return ((h, w) if landscape else (w, h)), landscape


def _room_mm(board: BoardSpec, paper: str) -> tuple[float, float]:
    """The room the board has on ``paper`` (w, h) mm, along its columns and its rows."""
    (W, H), _ = _layout(board, paper)
    return W - 2 * MARGIN_MM, H - 2 * MARGIN_MM - RULER_BAND_MM


def _largest_square_mm(board: BoardSpec, paper: str) -> float:
    w, h = _room_mm(board, paper)
    return float(np.floor(min(w / (board.cols + 1), h / (board.rows + 1))))


def fit_square_mm(board: BoardSpec, paper: str) -> float:
    """The largest whole-millimetre square (at least :data:`MIN_SQUARE_MM`) that fits the
    paper."""
    return max(MIN_SQUARE_MM, _largest_square_mm(board, paper))


def print_square_mm(board: BoardSpec, paper: str) -> float:
    """The square a printout of ``board`` on ``paper`` has: the board's own square when it
    fits the paper, else the largest that does (what the page, the PDF and the session all
    say; one source of truth)."""
    own = round(board.square * 1000, 3)
    fit = fit_square_mm(board, paper)
    return own if own <= fit else fit


def _too_many_squares(board: BoardSpec, paper: str) -> str:
    """Why a board cannot be printed on ``paper`` at any square size, and the most inner
    corners that can."""
    w, h = _room_mm(board, paper)
    most = (int(w // MIN_SQUARE_MM) - 1, int(h // MIN_SQUARE_MM) - 1)
    a3 = paper.upper() != "A3" and _largest_square_mm(board, "A3") >= MIN_SQUARE_MM
    return (f"a {board.cols}x{board.rows} board has too many squares for {paper} paper: even "
            f"at {MIN_SQUARE_MM:g} mm, the smallest square Drovisio prints, its "
            f"{board.cols + 1}x{board.rows + 1} squares need "
            f"{(board.cols + 1) * MIN_SQUARE_MM:g}x{(board.rows + 1) * MIN_SQUARE_MM:g} mm and "
            f"the sheet has room for {w:g}x{h:g} mm; give at most {most[0]}x{most[1]} inner "
            "corners" + (", or use A3 paper" if a3 else ""))


def board_pdf(board: BoardSpec, path: str | Path, paper: str = "A4",
              square_mm: float | None = None) -> dict:
    """Write :func:`board_pdf_bytes` to ``path`` (atomically); returns its description."""
    data, info = board_pdf_bytes(board, paper, square_mm)
    atomic_write_bytes(Path(path), data)
    return info


def board_pdf_bytes(board: BoardSpec, paper: str = "A4", square_mm: float | None = None
                    ) -> tuple[bytes, dict]:
    """The board as a one-page PDF at true scale.

    Args:
        board: The board (its ``square`` is ignored: the printed size is ``square_mm``).
        paper: ``A4``, ``A3`` or ``Letter``.
        square_mm: Side of one square on paper, millimetres (default: the largest whole
            millimetre that fits, :func:`fit_square_mm`).

    Returns:
        (PDF bytes, ``{"paper", "landscape", "square_mm", "board_mm": (w, h),
        "ruler_mm": 100}``).

    Raises:
        InputError: Unknown paper, or a square that does not fit it.
    """
    (W, H), landscape = _layout(board, paper)
    s = fit_square_mm(board, paper) if square_mm is None else float(square_mm)
    nx, ny = board.cols + 1, board.rows + 1
    bw, bh = nx * s, ny * s
    if _largest_square_mm(board, paper) < MIN_SQUARE_MM:
        raise InputError(_too_many_squares(board, paper))
    if not (np.isfinite(s) and s > 0) or bw > W - 2 * MARGIN_MM \
            or bh > H - 2 * MARGIN_MM - RULER_BAND_MM:
        fit = fit_square_mm(board, paper)
        raise InputError(f"a {board.cols}x{board.rows} board of {s:g} mm squares does not fit "
                         f"{paper} paper: use squares of at most {fit:g} mm"
                         + ("" if paper.upper() == "A3" else ", or A3 paper"))
    page = Page(W, H)
    black = (0.0, 0.0, 0.0)
    x0 = (W - bw) / 2
    y0 = MARGIN_MM

    def rect(x: float, y: float, w: float, h: float) -> None:
        page.ops.append(("rect", x, y, w, h, black, None, None, 0))

    for j in range(ny):
        for i in range(nx):
            if (i + j) % 2 == 0:
                rect(x0 + i * s, y0 + j * s, s, s)
    if board.kind == "charuco":
        # OpenCV's board: markers in the white squares, ids in order, row by row from the top
        ids = np.asarray(board.charuco_board().getIds()).ravel()
        m = s * board.marker_ratio
        k = 0
        for j in range(ny):
            for i in range(nx):
                if (i + j) % 2 == 1:
                    bits = aruco_code_bits(board.dictionary, int(ids[k]))
                    k += 1
                    c = m / bits.shape[0]
                    mx, my = x0 + i * s + (s - m) / 2, y0 + j * s + (s - m) / 2
                    for r, row in enumerate(bits):
                        for q, white in enumerate(row):
                            if not white:
                                rect(mx + q * c, my + r * c, c, c)
    # ---- the ruler: 100 mm, ticks every 10 mm (longer), 5 mm and 1 mm
    ry = y0 + bh + 12.0
    rx = (W - 100.0) / 2
    rect(rx, ry, 100.0, 0.8)
    for t in range(101):
        tick = 5.0 if t % 10 == 0 else (3.5 if t % 5 == 0 else 2.0)
        page.ops.append(("line", rx + t, ry, rx + t, ry - tick, black, 0.15, None))
    page.ops.append(("text", rx + 50.0, ry + 5.0, 8, "This bar must measure 100 mm. Print at "
                     "100 % ('Actual size', not 'Fit to page').", False, "middle"))
    page.ops.append(("text", rx + 50.0, ry + 9.5, 8, f"{board.spec()}: squares of {s:g} mm. "
                     "Measure one square and enter it before solving.", False, "middle"))
    data = pdf_bytes([page], title=f"Drovisio {board.spec()} board",
                     producer="Drovisio calibration")
    return data, {"paper": paper, "landscape": landscape, "square_mm": s, "board_mm": (bw, bh),
                  "ruler_mm": 100.0}
