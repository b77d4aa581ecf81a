"""The layouts shipped with the package (``marker_layouts/``)."""

from __future__ import annotations

import re
from pathlib import Path

from drovisio.errors import InputError, one_line
from drovisio.resources import layouts_dir

__all__ = ["shipped_layouts_dir", "list_shipped_layouts", "shipped_layout_file"]

# a shipped layout's name: a file name's stem, never a path (no separator, no leading dot)
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,99}")


def shipped_layouts_dir() -> Path:
    """The shipped ``marker_layouts/`` folder (installed with the package)."""
    return layouts_dir()


def list_shipped_layouts() -> list[Path]:
    """The shipped layout files, sorted by name."""
    d = shipped_layouts_dir()
    return sorted(d.glob("*.json")) if d.is_dir() else []


def shipped_layout_file(name: object) -> Path:
    """The shipped layout file a layout name names (``"drick-aruco-centre"``): the one
    resolver of a name read from outside (a scenario's ``layouts``, a study protocol's, a
    recording's manifest). A name is a plain name, checked as text before anything is
    opened: one with a separator, a leading dot or a NUL byte never reaches a file.

    Raises:
        InputError: ``no shipped layout called NAME; give one of ...`` (callers add the file
            and the field).
    """
    path = (shipped_layouts_dir() / f"{name}.json"
            if isinstance(name, str) and _NAME.fullmatch(name) else None)
    if path is None or not path.is_file():
        names = ", ".join(p.stem for p in list_shipped_layouts())
        raise InputError(f"no shipped layout called {one_line(repr(name), 160)}; give one of "
                         f"{names}")
    return path
