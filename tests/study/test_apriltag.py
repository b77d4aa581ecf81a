"""AprilTag 3 as a peer for any of OpenCV's dictionaries (``drovisio.study.apriltag``): the
families built from OpenCV's tables are AprilTag's own where it has them, every dictionary's
codes are read with the right id and corners, and a dictionary with close codes is not
corrected into another code."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drovisio.layout import aruco_dictionary_id

pytest.importorskip("pupil_apriltags")

from drovisio.study.apriltag import (  # noqa: E402 - after the optional import's check
    APRILTAG_FAMILIES,
    apriltag_detector,
    apriltag_reader,
    aruco_family_bits,
)


@pytest.mark.parametrize("dictionary", sorted(APRILTAG_FAMILIES))
def test_a_family_built_from_opencvs_table_is_apriltags_own(dictionary):
    """tag36h11 (6x6), tag25h9 (5x5, the centre bit last) and tag16h5 (4x4): the same code
    words in the same order, the same bit positions, from OpenCV's table."""
    fam_name = APRILTAG_FAMILIES[dictionary]
    own = apriltag_detector(fam_name).tag_families[fam_name].contents
    codes, pos, n, correct = aruco_family_bits(dictionary)
    assert n * n == own.nbits and own.width_at_border == n + 2
    assert codes.tolist() == [int(own.codes[i]) for i in range(own.ncodes)]
    assert pos == [(own.bit_x[i], own.bit_y[i]) for i in range(own.nbits)]
    assert correct == 2


def _scene(dictionary: str, marker_id: int, turn: int) -> tuple[np.ndarray, np.ndarray]:
    """A code of 120 px turned by ``turn`` quarter turns on white, blurred (sigma 1 px);
    its true corners (TL, TR, BR, BL of the printed code) in OpenCV's convention."""
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary))
    img = np.full((300, 300), 255, np.uint8)
    img[90:210, 90:210] = np.rot90(cv2.aruco.generateImageMarker(d, marker_id, 120), turn)
    corners = np.array([[89.5, 89.5], [209.5, 89.5], [209.5, 209.5], [89.5, 209.5]])
    return cv2.GaussianBlur(img, (0, 0), 1.0), np.roll(corners, turn, axis=0)


@pytest.mark.parametrize("dictionary", ["DICT_4X4_50", "DICT_5X5_250", "DICT_6X6_250",
                                        "DICT_7X7_1000", "DICT_ARUCO_ORIGINAL",
                                        "DICT_ARUCO_MIP_36h12", "DICT_APRILTAG_36h10",
                                        "DICT_APRILTAG_36h11"])
def test_every_dictionary_is_read_with_its_id_and_corners(dictionary):
    """The first, a middle and the last id, in the four quarter turns: one code each, its
    id, no bit corrected, its corners in OpenCV's order within 0.25 px of the truth
    (measured 0.16 px: AprilTag's own edge placement on a blurred render)."""
    reader = apriltag_reader(dictionary)
    # the original ArUco dictionary's last code is its own quarter turn: no order to check
    last = len(cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary)).bytesList) - 1
    last -= dictionary == "DICT_ARUCO_ORIGINAL"
    for marker_id in (0, last // 2, last):
        for turn in range(4):
            img, truth = _scene(dictionary, marker_id, turn)
            found = reader.detect(img)
            assert [(c.dictionary, c.marker_id, c.hamming) for c in found] == [
                (dictionary, marker_id, 0)], (marker_id, turn)
            assert np.abs(found[0].corners - truth).max() < 0.25


def test_several_dictionaries_in_one_reader():
    reader = apriltag_reader(["DICT_6X6_250", "DICT_4X4_50"])
    a, ta = _scene("DICT_4X4_50", 3, 0)
    b, tb = _scene("DICT_6X6_250", 9, 1)
    found = reader.detect(np.hstack([a, b]))
    got = sorted((c.dictionary, c.marker_id) for c in found)
    assert got == [("DICT_4X4_50", 3), ("DICT_6X6_250", 9)]
    by = {c.dictionary: c.corners for c in found}
    assert np.abs(by["DICT_6X6_250"] - (tb + [300, 0])).max() < 0.25


def test_a_close_dictionary_corrects_no_bit():
    """DICT_4X4_50 (16 bits): OpenCV's detector corrects no bit of it at its defaults, and
    neither does AprilTag 3 here: a code with one cell flipped is read as no code, where
    AprilTag's usual 2-bit correction reads it as a code of the dictionary."""
    assert aruco_family_bits("DICT_4X4_50")[3] == 0
    assert aruco_family_bits("DICT_6X6_250")[3] == 2
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    m = cv2.aruco.generateImageMarker(d, 7, 120)
    m[30:60, 30:60] = 255 - m[30:60, 30:60]           # one inner cell flipped
    img = np.full((300, 300), 255, np.uint8)
    img[90:210, 90:210] = m
    assert apriltag_reader("DICT_4X4_50").detect(cv2.GaussianBlur(img, (0, 0), 1.0)) == []
