"""Fixtures of the detector tests."""

from __future__ import annotations

import pytest

from drovisio.layout import load_layouts, shipped_layouts_dir, with_dictionary


@pytest.fixture(scope="module")
def tag36h11_layouts():
    """The shipped ArUco bricks (centre code, two pyramid codes) with tag36h11 codes."""
    base = load_layouts([shipped_layouts_dir() / "drick-aruco-centre.json",
                         shipped_layouts_dir() / "drick-aruco-pyramids.json"])
    return [with_dictionary(lay, "DICT_APRILTAG_36h11") for lay in base]
