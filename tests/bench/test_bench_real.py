"""``drovisio bench real``: the kind of each real folder, the figures beside OpenCV and
AprilTag 3, its JSON through the verified writer, bad arguments in one line."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from drovisio.cli import main

REAL = Path(os.environ.get("DROVISIO_REAL_DATA", Path(__file__).resolve().parents[3]
                           / "shared" / "datasets" / "real"))


def _need(sub: str) -> Path:
    d = REAL / sub
    if not d.is_dir():
        msg = f"real data {d} is absent; set DROVISIO_REAL_DATA to run these tests"
        if os.environ.get("DROVISIO_REQUIRE_SHARED") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return d


def test_charuco_and_chessboard_folders(tmp_path, capsys):
    charuco, chess = _need("charuco"), _need("chess-opencv24")
    out = tmp_path / "real.json"
    rc = main(["bench", "real", str(charuco), str(chess), "--calibrate", "none",
               "--json", str(out)])
    text, err = capsys.readouterr()
    assert rc == 0 and "Traceback" not in err
    rep = json.loads(out.read_text())["folders"]
    assert [r["kind"] for r in rep] == ["charuco", "chessboard"]
    ch, cb = rep
    assert ch["board_squares"] == [5, 7] and ch["dictionary"] == "DICT_6X6_250"
    assert ch["codes"]["drovisio"] == ch["codes"]["opencv"] == 17
    assert ch["codes"]["ambiguous"] == 0
    assert ch["pose_vs_board"]["trans_mm"]["max"] < 2.0
    assert ch["pose_vs_board"]["rot_deg"]["max"] < 0.2
    assert (ch["corners_vs_board_px"]["drovisio"]["median"]
            < ch["corners_vs_board_px"]["opencv"]["median"])
    # OpenCV's 2.4-era chessboards with its expected corners: 7 of 7, within 0.05 px
    assert cb["board"] in ([7, 5], [5, 7]) and cb["found"] == {"drovisio": 7, "opencv": 7}
    c = cb["corners_vs_expected_px"]["drovisio"]
    assert c["n"] == 7 * 35 and c["median"] < 0.05
    assert "codes found: Drovisio 17, OpenCV 17" in text


def test_tag_folder_with_apriltag(tmp_path, capsys):
    d = _need("apriltag-multi")
    pytest.importorskip("pupil_apriltags")
    out = tmp_path / "tags.json"
    assert main(["bench", "real", str(d), "--json", str(out)]) == 0
    r = json.loads(out.read_text())["folders"][0]
    assert r["kind"] == "tags" and r["dictionary"] == "DICT_APRILTAG_36h11"
    n = r["codes"]
    assert n["opencv"] == 54 and n["apriltag"] == 56 and n["opencv_kept"] >= 51
    assert n["false"] == 0 and n["duplicate_bricks"] == 0
    c = r["corners_rms_px"]
    assert c["drovisio_vs_apriltag"]["median"] < 0.5 * c["opencv_vs_apriltag"]["median"]
    assert set(r["ms_per_photo"]) == {"drovisio", "opencv", "apriltag"}


@pytest.mark.parametrize("argv, words", [
    (["--repeat", "0"], "--repeat 0: give 1 to 20"),
    (["--calibrate", "brown"], "'brown' is no model"),
    (["--marker", "0.05"], "smaller than the square"),
])
def test_bad_arguments_are_one_line(tmp_path, capsys, argv, words):
    rc = main(["bench", "real", str(tmp_path), *argv])
    _, err = capsys.readouterr()
    assert rc == 2 and words in err and "Traceback" not in err
    assert len([x for x in err.splitlines() if x.strip()]) == 1


def test_folders_that_are_none_of_the_kinds(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("no photos here")
    rc = main(["bench", "real", str(tmp_path)])
    _, err = capsys.readouterr()
    assert rc == 2 and "no images" in err and str(tmp_path) in err
    rc = main(["bench", "real", str(tmp_path / "missing")])
    _, err = capsys.readouterr()
    assert rc == 2 and "not a folder" in err
