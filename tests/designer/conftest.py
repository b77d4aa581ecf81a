"""Fixtures of the marker designer tests: the drick mesh and a design made by click rays."""

from __future__ import annotations

import pytest

from drovisio.layout import list_shipped_layouts, load_layout, shipped_layouts_dir

DRICK_STL = shipped_layouts_dir() / "meshes" / "drick.stl"

#: Click rays (origin, direction) from above, a few mm off the intended spots (snapping puts
#: them exactly): two codes on the pyramid tops, six dots in the thesis's 2x3 grid.
CODE_RAYS = [([-0.076, 0.003, 1.0], [0.0, 0.0, -1.0]), ([0.074, -0.002, 1.0], [0.0, 0.0, -1.0])]
DOT_RAYS = [([x + 0.0012, y - 0.0014, 1.0], [0.0, 0.0, -1.0])
            for x in (-0.1, 0.0, 0.1) for y in (0.05, -0.05)]


@pytest.fixture(scope="session")
def drick_bytes() -> bytes:
    return DRICK_STL.read_bytes()


@pytest.fixture(scope="session")
def shipped_layouts():
    return [load_layout(p) for p in list_shipped_layouts()]


def place_drick_markers(doc) -> None:
    """Two codes and six dots by click rays, as a user would."""
    doc.set_mode("code")
    for o, d in CODE_RAYS:
        assert doc.click(o, d).action == "added"
    doc.set_mode("dot")
    for o, d in DOT_RAYS:
        assert doc.click(o, d).action == "added"


@pytest.fixture
def drick_doc(drick_bytes, shipped_layouts):
    from drovisio.designer.model import DesignDocument

    doc = DesignDocument.from_mesh_bytes(drick_bytes, "drick.stl", others=shipped_layouts)
    return doc


@pytest.fixture
def designed(drick_doc):
    place_drick_markers(drick_doc)
    return drick_doc
