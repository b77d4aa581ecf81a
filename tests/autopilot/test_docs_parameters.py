"""The field guide's Fly step and the README name every parameter the check reads, with its value."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from drovisio.autopilot.check import ARDUPILOT, PX4

REPO = Path(__file__).resolve().parents[2]
FLY = (REPO / "docs" / "field-guide.md").read_text().split("## 6. Fly")[1].split("\n## ")[0]
README = (REPO / "README.md").read_text()


def _rows(text: str) -> dict[str, str]:
    """Parameter name → the value cell of the table row naming it."""
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3:
            for name in re.findall(r"`([A-Z][A-Za-z0-9_]+)`", cells[0]):
                out[name] = cells[1]
    return out


@pytest.mark.parametrize("doc", ["fly", "readme"])
def test_every_parameter_is_in_the_table_with_its_value(doc):
    rows = _rows(FLY if doc == "fly" else README)
    for e in (*ARDUPILOT, *PX4):
        assert e.name in rows, e.name
        if e.value is not None:
            assert re.search(rf"(^|\D){re.escape(f'{e.value:g}')}(\D|$)", rows[e.name]), \
                (e.name, rows[e.name])
    assert "SERIALn_PROTOCOL" in rows and rows["SERIALn_PROTOCOL"].startswith("2")
