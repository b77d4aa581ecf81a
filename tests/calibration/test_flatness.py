"""The board's bow, fitted with the lens (mrcal's board warp): recovered on corners of a bowed
board, flat on OpenCV's real views, named when it cannot be computed, in the CLI's report."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from drovisio import cli
from drovisio.calibration.flatness import board_flatness
from drovisio.calibration.session import CalibrationSession, SessionConfig
from drovisio.calibration.solve import SolveOptions, ViewInput, solve
from drovisio.calibration.synthetic import DEFAULT_BOARD
from drovisio.camera import Camera
from drovisio.resources import sample_sessions_dir

CAM = Camera.drone_webcam()
OBJ = DEFAULT_BOARD.object_points().reshape(-1, 3).astype(np.float64)


def _views(bow_x: float, bow_y: float, n: int = 20, seed: int = 0, noise_px: float = 0.1
           ) -> list[ViewInput]:
    """Corners of the 9×6 board bowed by (bow_x, bow_y) metres, seen from random poses."""
    rng = np.random.default_rng(seed)
    x, y = OBJ[:, 0], OBJ[:, 1]
    u = 2 * (x - x.min()) / np.ptp(x) - 1
    v = 2 * (y - y.min()) / np.ptp(y) - 1
    bowed = OBJ.copy()
    bowed[:, 2] = bow_x * (1 - u * u) + bow_y * (1 - v * v)
    out = []
    while len(out) < n:
        R = cv2.Rodrigues(rng.normal(0, 0.35, 3))[0]
        t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.08, 0.08),
                      rng.uniform(0.35, 0.7)]) - R @ OBJ.mean(axis=0)
        px = CAM.project(bowed @ R.T + t)
        if (np.all(np.isfinite(px)) and px.min() >= 5 and px[:, 0].max() < CAM.width - 5
                and px[:, 1].max() < CAM.height - 5):
            out.append(ViewInput(f"v{len(out)}", px + rng.normal(0, noise_px, px.shape), OBJ))
    return out


@pytest.mark.parametrize("bow", [(0.0015, 0.0), (0.001, -0.002)])
def test_a_bowed_board_is_measured_and_named(bow):
    r = solve(_views(*bow), CAM.size, SolveOptions(board_flatness=True))
    f = r.board_flatness
    assert f["computed"] and f["significant"] and f["matters"]
    # measured: 1.499 / 0.044 and 0.997 / -1.958 mm, standard errors 0.02 mm
    np.testing.assert_allclose([f["warp_x_mm"], f["warp_y_mm"]], np.array(bow) * 1000,
                               atol=0.08)
    assert max(f["warp_std_mm"]) < 0.05
    # the flat solve pays for the bow in its focal length (1-2 %) and its RMS; the bowed
    # fit is back at the corners' noise
    assert abs(f["fx_shift_pct"]) > 0.8 and abs(r.camera.fx - CAM.fx) / CAM.fx > 0.008
    assert f["rms_px_bowed"] < 0.16 < f["rms_px_flat"]
    assert "glue the print to something flat" in f["summary"]


def test_a_flat_board_is_flat_within_the_measurement():
    r = solve(_views(0.0, 0.0, seed=1), CAM.size, SolveOptions(board_flatness=True))
    f = r.board_flatness
    assert f["computed"] and not f["matters"]
    assert abs(f["warp_x_mm"]) < 3 * f["warp_std_mm"][0] + 0.01
    assert abs(f["fx_shift_pct"]) < 0.1
    assert f["summary"].startswith("the board is flat within the measurement")
    # not asked: not computed
    assert solve(_views(0.0, 0.0, seed=1), CAM.size).board_flatness is None


def test_opencv_real_board_is_flat_enough(opencv_images, opencv_board):
    s = CalibrationSession(opencv_board, config=SessionConfig(
        solve=SolveOptions(board_flatness=True)))
    for name, img in opencv_images.items():
        s.add_image(img, name)
    f = s.solve().board_flatness
    # measured: 0.05 / -0.17 mm (± 0.02): real, but the focal length moves by < 0.01 %
    assert f["computed"] and not f["matters"]
    assert max(abs(f["warp_x_mm"]), abs(f["warp_y_mm"])) < 0.3
    assert abs(f["fx_shift_pct"]) < 0.05


def test_what_cannot_be_measured_is_named():
    views = _views(0.0, 0.0, n=8)
    fits = solve(views, CAM.size).per_view
    assert board_flatness(views, CAM, "fisheye", 0.1, fits, 1.0) == {
        "computed": False, "reason": "not for the fisheye model"}
    assert "the bow needs 6" in board_flatness(views[:4], CAM, "plumb_bob", 0.1, fits, 1.0)[
        "reason"]
    lifted = [ViewInput(v.name, v.corners, OBJ + [0, 0, 0.01 * (i % 2)])
              for i, v in enumerate(views)]
    assert board_flatness(lifted, CAM, "plumb_bob", 0.1, fits, 1.0)["reason"] == \
        "the board points are not in one plane"
    with pytest.raises(ValueError, match="iterations 0, at least 1"):
        board_flatness(views, CAM, "plumb_bob", 0.1, fits, 1.0, iterations=0)


def test_calibrate_board_flatness_in_the_report(capsys, tmp_path):
    rc = cli.main(["calibrate", "--board", "chessboard:9x6", "--square", "0.025",
                   "--board-flatness", "--out", str(tmp_path / "cam.yaml"), "--report",
                   str(tmp_path / "report.json"), str(sample_sessions_dir() / "calibration")])
    assert rc == 0
    err = capsys.readouterr().err
    assert "board flatness: the board is flat within the measurement" in err
    f = json.loads((tmp_path / "report.json").read_text())["board_flatness"]
    assert f["computed"] and abs(f["warp_x_mm"]) < 0.05 and abs(f["warp_y_mm"]) < 0.05


def test_a_failing_bow_fit_is_named_and_the_calibration_stands(monkeypatch):
    import drovisio.calibration.flatness as flatness

    def broken(*a, **k):  # as OpenCV's projection fails on a pose it cannot take
        raise cv2.error("OpenCV(5.0.0) projectPoints: bad argument")

    monkeypatch.setattr(flatness, "_residuals", broken)
    r = solve(_views(0.0015, 0.0), CAM.size, SolveOptions(board_flatness=True))
    assert r.board_flatness["computed"] is False
    assert r.board_flatness["reason"].startswith("the fit failed (")
    assert abs(r.camera.fx - CAM.fx) / CAM.fx < 0.05   # the flat solve is still there
