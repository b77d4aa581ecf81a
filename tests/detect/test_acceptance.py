"""The rules that accept a read code, from the statistics of its cells and of the frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drovisio.detect.corners import cell_verdict
from drovisio.detect.corners.fit import _move_limits

BITS = np.array([1, 0] * 18, np.float64)   # 36 cells, half white


def _cells(rng, spread, white=0.9, black=0.1):
    """Cell whitenesses: the two levels, a bounded jitter of about ``spread`` (no tail: the
    tests place their outliers themselves), and a little noise."""
    jitter = spread * np.sin(np.arange(BITS.size) * 1.7)
    return np.where(BITS > 0.5, white, black) + jitter + rng.normal(0, 0.05 * spread, BITS.size)


def test_cells_read_right_are_kept_whatever_their_absolute_margin():
    """A real JPEG's classes sit at 0.68 and 0.30 (margins ~0.18, under the old fixed 0.25)
    yet are 10+ spreads apart: every cell reads right."""
    rng = np.random.default_rng(1)
    a = _cells(rng, 0.02, white=0.68, black=0.30)
    ok, wrong, undecided, sep = cell_verdict(a, BITS, tolerable=0)
    assert ok and wrong == 0 and undecided == 0 and sep > 10


def test_a_cell_that_reads_as_the_other_class_refuses_the_code():
    rng = np.random.default_rng(2)
    a = _cells(rng, 0.03)
    a[5] = 0.85          # a black cell that reads white: a decoy or another code
    ok, wrong, _, _ = cell_verdict(a, BITS, tolerable=3)
    assert not ok and wrong == 1


def test_undecided_cells_up_to_the_dictionary_tolerance():
    rng = np.random.default_rng(3)
    a = _cells(rng, 0.03)
    a[[0, 2]] = 0.503    # two white cells at the midpoint: unknown (log odds < ln 7200)
    assert cell_verdict(a, BITS, tolerable=3)[0]
    assert cell_verdict(a, BITS, tolerable=2)[0]
    ok, wrong, undecided, _ = cell_verdict(a, BITS, tolerable=1)
    assert not ok and wrong == 0 and undecided == 2
    # 4x4 codes (tolerance 0): every cell must be decided
    assert not cell_verdict(a, BITS, tolerable=0)[0]


def test_classes_that_overlap_refuse_the_code():
    rng = np.random.default_rng(4)
    a = _cells(rng, 0.25, white=0.6, black=0.4)   # noise as wide as the contrast
    ok, _, _, sep = cell_verdict(a, BITS, tolerable=3)
    assert not ok and sep < 6


def test_cells_beyond_a_smaller_code_are_ignored():
    rng = np.random.default_rng(5)
    a = _cells(rng, 0.02)
    a[30:] = np.nan
    a[31] = np.nan
    assert cell_verdict(a, BITS, tolerable=0)[0]


def test_move_limit_follows_the_frame_start_noise():
    """A corner that moves 11 px where the frame's others move about 1 px is refused; the
    limit is the 2-D normal's tail at the frame's measured spread, capped by 1.5 cells."""
    rng = np.random.default_rng(6)
    moved = np.abs(rng.normal(0, 1.0, (6, 4))) + 0.3
    moved[0, 2] = 11.4
    lim = _move_limits(moved, np.ones(6, bool), 0.85, np.full(6, 13.5))
    assert np.all(lim > 3.0) and np.all(lim < 6.0)
    assert moved[0, 2] > lim[0] and np.all(np.delete(moved.ravel(), 2) < lim[0])
    # a noisier frame allows more, never beyond one and a half cells
    lim2 = _move_limits(moved * 3, np.ones(6, bool), 0.85, np.full(6, 4.0))
    assert np.all(lim2 == 6.0)
    # small codes keep the old bound (2 px at least)
    assert np.all(_move_limits(moved, np.ones(6, bool), 0.85, np.full(6, 1.0)) == 2.0)


def _copies_of_tag0(folder: Path, n_frames: int) -> None:
    """Pictures of three printed copies of tag36h11 id 0 (plain white paper, grey floor)."""
    import cv2

    tag = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), 0, 80)
    tag = cv2.copyMakeBorder(tag, 16, 16, 16, 16, cv2.BORDER_CONSTANT, value=255)
    for k in range(n_frames):
        img = np.full((480, 640), 110, np.uint8)
        for x, y in [(60, 60), (300, 120), (420, 300)]:
            img[y + 4 * k:y + 4 * k + tag.shape[0], x:x + tag.shape[1]] = tag
        cv2.imwrite(str(folder / f"copies_{k}.png"), cv2.GaussianBlur(img, (3, 3), 0.8))


def test_detect_says_once_that_codes_share_an_id(tmp_path, capsys):
    """``drovisio detect`` on pictures of three copies of one code: one stderr line per input
    naming the instance, every brick flagged in the JSON."""
    from drovisio.cli import main
    from drovisio.resources import sample_sessions_dir

    pics = tmp_path / "pics"
    pics.mkdir()
    _copies_of_tag0(pics, 3)
    lay = tmp_path / "tag.json"
    lay.write_text(json.dumps({
        "schema": "drovisio/marker-layout@1", "name": "cube-tag", "units": "m",
        "first_id": 0, "ids_per_instance": 1, "instances": 1, "symmetry": "none",
        "markers": [{"kind": "aruco", "dictionary": "DICT_APRILTAG_36h11", "id": 0,
                     "size": 0.065, "center": [0, 0, 0], "normal": [0, 0, 1],
                     "up": [0, 1, 0]}]}))
    rc = main(["detect", "--camera", str(sample_sessions_dir() / "camera.yaml"), "--layout",
               str(lay), str(pics)])
    out, err = capsys.readouterr()
    frames = [json.loads(x) for x in out.splitlines()]
    assert rc == 0 and len(frames) == 3
    assert all(len(f["bricks"]) == 3 and all(b.get("duplicate") for b in f["bricks"])
               for f in frames)
    said = [x for x in err.splitlines() if "share their id" in x]
    assert len(said) == 1 and "cube-tag instance 0" in said[0]
    assert "3 of 3 frames had codes sharing one id" in err
