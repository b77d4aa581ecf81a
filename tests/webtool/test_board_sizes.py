"""The board's square size is one figure across the calibration page, the PDF and the
session: each paper's printout says the square it prints."""

from __future__ import annotations

from fastapi.testclient import TestClient

from drovisio.calibration.board import parse_board
from drovisio.calibration.printout import board_pdf_bytes, fit_square_mm, print_square_mm
from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"


def test_page_pdf_and_session_agree_on_the_square(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data", sample_seconds_per_view=0.4))
    with TestClient(app, base_url=LOCAL) as client:
        st = client.get("/api/calibration/state").json()["session"]
        assert st["square_mm"] == 25.0
        prints = st["print_square_mm"]
        board = parse_board(st["board"], 0.025)
        for paper, mm in prints.items():
            # the session's 25 mm when it fits the paper, else the largest that does
            assert mm == min(25.0, fit_square_mm(board, paper)), paper
            r = client.get(f"/api/calibration/board.pdf?paper={paper}")
            assert r.status_code == 200 and r.content.startswith(b"%PDF-")
            assert float(r.headers["x-square-mm"]) == mm
            assert r.content == board_pdf_bytes(board, paper, mm)[0]
        assert prints["A4"] == 21.0 and prints["A3"] == 25.0


def test_print_square_keeps_a_board_that_fits():
    small = parse_board("chessboard:5x4", 0.025)
    assert print_square_mm(small, "A4") == round(small.square * 1000, 3)
