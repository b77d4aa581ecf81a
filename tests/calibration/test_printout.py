"""The printable board: a true-scale PDF read back (page size, square size, ruler length within
0.1 %), rasterised and detected as the board it claims to be; the CLI that writes it."""

from __future__ import annotations

import numpy as np
import pymupdf
import pytest

from drovisio import cli
from drovisio.calibration.board import detect, parse_board
from drovisio.calibration.printout import PAPER_MM, board_pdf
from drovisio.errors import InputError

PT = 25.4 / 72          # mm per PDF point


def _rects(path) -> tuple[tuple[float, float], list[tuple[float, float, float, float]]]:
    doc = pymupdf.open(str(path))
    page = doc[0]
    rects = []
    for d in page.get_drawings():
        for item in d["items"]:
            if item[0] == "re":
                r = item[1]
                rects.append((r.x0 * PT, r.y0 * PT, r.width * PT, r.height * PT))
    return (page.rect.width * PT, page.rect.height * PT), rects


@pytest.mark.parametrize("paper", ["A4", "A3", "Letter"])
@pytest.mark.parametrize("spec", ["chessboard:9x6", "charuco:7x5"])
def test_true_scale_on_every_paper(tmp_path, paper, spec):
    board = parse_board(spec, 0.025)
    out = tmp_path / "board.pdf"
    info = board_pdf(board, out, paper)
    (w, h), rects = _rects(out)
    assert sorted((w, h)) == pytest.approx(sorted(PAPER_MM[paper]), rel=1e-3)
    s = info["square_mm"]
    squares = [r for r in rects if abs(r[2] - s) < 0.5 and abs(r[3] - s) < 0.5]
    assert len(squares) == (board.cols + 1) * (board.rows + 1) // 2 + \
        ((board.cols + 1) * (board.rows + 1)) % 2
    for r in squares:
        assert r[2] == pytest.approx(s, rel=1e-3) and r[3] == pytest.approx(s, rel=1e-3)
    # neighbouring squares are one square apart: the board's pitch is true as well
    xs = sorted({round(r[0], 3) for r in squares})
    assert np.diff(xs) == pytest.approx(s, rel=1e-3)
    ruler = [r for r in rects if abs(r[2] - 100) < 1]
    assert len(ruler) == 1 and ruler[0][2] == pytest.approx(100.0, rel=1e-3)


@pytest.mark.parametrize("spec", ["chessboard:9x6", "charuco:7x5"])
def test_the_printed_board_is_detected_as_itself(tmp_path, spec):
    board = parse_board(spec, 0.025)
    out = tmp_path / "board.pdf"
    info = board_pdf(board, out, "A4")
    ppm = 6.0                                  # pixels per millimetre
    pix = pymupdf.open(str(out))[0].get_pixmap(matrix=pymupdf.Matrix(ppm * PT, ppm * PT),
                                               colorspace=pymupdf.csGRAY)
    img = np.frombuffer(pix.samples, np.uint8).reshape(pix.height, pix.width)
    det = detect(img, board)
    assert det is not None and det.n == board.n_corners
    c = det.corners.reshape(board.rows, board.cols, 2)
    pitch = np.linalg.norm(np.diff(c, axis=1), axis=2).mean() / ppm
    assert pitch == pytest.approx(info["square_mm"], rel=5e-3)


def test_a_square_too_big_for_the_paper(tmp_path):
    with pytest.raises(InputError, match="at most 21 mm, or A3 paper"):
        board_pdf(parse_board("chessboard:9x6", 0.025), tmp_path / "b.pdf", "A4",
                  square_mm=30)
    assert not (tmp_path / "b.pdf").exists()


def test_a_board_of_too_many_squares_names_them_not_the_square_size(tmp_path, capsys):
    with pytest.raises(InputError) as err:
        board_pdf(parse_board("chessboard:60x30", 0.025), tmp_path / "b.pdf", "A4")
    assert str(err.value) == (
        "a 60x30 board has too many squares for A4 paper: even at 5 mm, the smallest square "
        "Drovisio prints, its 61x31 squares need 305x155 mm and the sheet has room for "
        "267x150 mm; give at most 52x29 inner corners, or use A3 paper")
    assert not (tmp_path / "b.pdf").exists()
    rc = cli.main(["calibrate", "board", "--pdf", str(tmp_path / "x.pdf"), "--board",
                   "chessboard:200x200"])
    err_line = capsys.readouterr().err
    assert rc == 2 and err_line.count("\n") == 1
    assert "too many squares for A4 paper" in err_line and "at most 52x29 inner corners" \
        in err_line and "A3" not in err_line and "squares of at most" not in err_line


def test_cli(tmp_path, capsys):
    out = tmp_path / "board.pdf"
    rc = cli.main(["calibrate", "board", "--pdf", str(out), "--paper", "Letter",
                   "--square", "0.02"])
    err = capsys.readouterr().err
    assert rc == 0 and "squares of 20 mm" in err and "100 mm ruler" in err
    _, rects = _rects(out)
    assert sum(1 for r in rects if abs(r[2] - 20) < 1e-2 and abs(r[3] - 20) < 1e-2) == 35
    rc = cli.main(["calibrate", "board", "--pdf", str(tmp_path / "x.pdf"), "--paper", "A5"])
    assert rc == 2 and "invalid choice: 'A5'" in capsys.readouterr().err
    rc = cli.main(["calibrate", "board", "--pdf", str(tmp_path / "x.pdf"), "--square", "0.5"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("drovisio calibrate board: a 9x6 board of 500 mm")
