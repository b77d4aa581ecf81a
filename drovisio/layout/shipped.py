"""The layouts shipped with the package (``marker_layouts/``)."""

from __future__ import annotations

from pathlib import Path

from drovisio.resources import layouts_dir

__all__ = ["shipped_layouts_dir", "list_shipped_layouts"]


def shipped_layouts_dir() -> Path:
    """The shipped ``marker_layouts/`` folder (installed with the package)."""
    return layouts_dir()


def list_shipped_layouts() -> list[Path]:
    """The shipped layout files, sorted by name."""
    d = shipped_layouts_dir()
    return sorted(d.glob("*.json")) if d.is_dir() else []
