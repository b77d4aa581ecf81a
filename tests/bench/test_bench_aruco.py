"""``drovisio bench aruco``: recall by code size and AprilTag 3 on the same frames, in the
JSON it writes; clear refusals of what it cannot measure."""

from __future__ import annotations

import json

import pytest

from drovisio.bench import aruco


def test_recall_by_size_and_apriltag_on_the_same_frames(tmp_path, capsys):
    pytest.importorskip("pupil_apriltags")
    out = tmp_path / "report.json"
    rc = aruco.main(["--frames", "3", "--bricks", "4", "--empty", "2", "--repeat", "1",
                     "--dictionary", "DICT_APRILTAG_36h11", "--apriltag", "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    by = data["recall_by_size"]
    assert set(by) == {"drovisio", "apriltag3"}
    for method in by.values():
        assert list(method) == ["14-20 px", "20-30 px", ">30 px"]
    # the bins add up to the rows' countable bricks, for both methods on the same frames
    ours = [r for r in data["rows"] if r.get("method") is None and r["scene"] == "bricks"
            and r["gravity"]]
    peer = [r for r in data["rows"] if r.get("method") == "apriltag3" and r["scene"] == "bricks"]
    assert sum(b["countable"] for b in by["drovisio"].values()) == ours[0]["countable"] > 0
    assert sum(b["countable"] for b in by["apriltag3"].values()) == peer[0]["countable"]
    assert sum(b["found"] for b in by["apriltag3"].values()) == peer[0]["found"] > 0
    assert peer[0]["apriltag_ms_median"] > 0 and peer[0]["false_bricks"] == 0
    text = capsys.readouterr().out
    assert "recall by code size, apriltag3:" in text and "AT3" in text


def test_what_cannot_be_measured_is_refused_in_one_line(capsys, request):
    assert aruco.main(["--dictionary", "DICT_9X9_1", "--frames", "1"]) == 2
    assert "--dictionary:" in capsys.readouterr().err
    # AprilTag 3 cannot read 4x4 ArUco codes
    assert aruco.main(["--apriltag", "--frames", "1"]) == 2
    err = capsys.readouterr().err
    assert "cannot read DICT_4X4_50" in err and "DICT_APRILTAG_36h11" in err
    request.getfixturevalue("no_apriltag")
    assert aruco.main(["--apriltag", "--dictionary", "DICT_APRILTAG_36h11",
                       "--frames", "1"]) == 2
    assert "pip install drovisio[peers]" in capsys.readouterr().err
