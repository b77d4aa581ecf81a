"""Checks on the values a user types into the designer; each raises :class:`DesignError`
saying what is allowed."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from drovisio.designer.model.codes import code_families
from drovisio.designer.model.errors import DesignError
from drovisio.layout import SYMMETRY_TOL_M

__all__ = [
    "KEEP",
    "MAX_MARKER_SIZE_M",
    "MIN_MARKER_SIZE_M",
    "check_colour",
    "check_size",
    "check_slot",
    "check_defaults",
    "check_name",
    "check_layout_numbers",
    "check_symmetry_and_family",
]

#: The value of ``first_id``/``ids_per_instance`` that leaves them unchanged.
KEEP = "keep"

#: Smallest code side or dot diameter, metres: the layout's checks compare marker positions
#: to 1 mm (:data:`~drovisio.layout.SYMMETRY_TOL_M`); a smaller mark is below what they
#: resolve (and below what a printer and a camera make of it).
MIN_MARKER_SIZE_M = SYMMETRY_TOL_M
#: Largest code side or dot diameter, metres (more is a unit mistake).
MAX_MARKER_SIZE_M = 5.0


def _size_range() -> str:
    return f"from {MIN_MARKER_SIZE_M * 1000:g} mm to {MAX_MARKER_SIZE_M:g} m"


def check_colour(colour: str, palette: Mapping[str, Any]) -> None:
    """A dot colour must be in the design's palette."""
    if colour not in palette:
        raise DesignError(f"unknown colour {colour!r}: use one of {', '.join(palette)}")


def check_size(size: Any) -> float:
    """A marker size in metres, :data:`MIN_MARKER_SIZE_M` to :data:`MAX_MARKER_SIZE_M`.
    Returns it as a float."""
    if not (isinstance(size, (int, float)) and math.isfinite(size) and size > 0):
        raise DesignError("the size must be a positive number")
    if not MIN_MARKER_SIZE_M <= size <= MAX_MARKER_SIZE_M:
        raise DesignError(f"the size is given in metres and must be {_size_range()}")
    return float(size)


def check_slot(slot: Any) -> int:
    """A code's slot: a whole number from 0 to 999."""
    if not isinstance(slot, int) or slot < 0 or slot > 999:
        raise DesignError("the slot must be a whole number from 0 to 999")
    return slot


def check_defaults(*, code_size: float | None, dot_diameter: float | None,
                   dot_color: str | None, grid: float | None, snap_radius: float | None,
                   palette: Mapping[str, Any]) -> None:
    """Sizes for the next markers (see :func:`check_size`), snapping steps (0..1 m), a
    palette colour."""
    for name, v in (("code size", code_size), ("dot diameter", dot_diameter)):
        if v is not None and not (math.isfinite(v)
                                  and MIN_MARKER_SIZE_M <= v <= MAX_MARKER_SIZE_M):
            raise DesignError(f"the {name} must be {_size_range()}")
    for name, v in (("grid step", grid), ("snap distance", snap_radius)):
        if v is not None and not (math.isfinite(v) and 0 <= v <= 1):
            raise DesignError(f"the {name} must be between 0 and 1 m (0 turns it off)")
    if dot_color is not None:
        check_colour(dot_color, palette)


def check_name(name: str) -> str:
    """A layout name (it becomes the file name). Returns it without surrounding spaces."""
    name = name.strip()
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", name):
        raise DesignError("the name may use letters, digits, '-', '_' and '.', start "
                          "with a letter or digit, and be at most 64 characters "
                          "(it becomes the file name)")
    return name


def check_layout_numbers(first_id: Any, ids_per_instance: Any, instances: Any) -> None:
    """Whole numbers up to 100000 (None or :data:`KEEP` pass: automatic, unchanged)."""
    for label, v, lo in (("first id", first_id, 0), ("ids per brick", ids_per_instance, 1),
                         ("number of bricks", instances, 1)):
        if v not in (None, KEEP) and (not isinstance(v, int) or isinstance(v, bool)
                                      or v < lo or v > 100000):
            raise DesignError(f"the {label} must be a whole number from {lo}")


def check_symmetry_and_family(symmetry: str | None, code_family: str | None) -> None:
    """A known symmetry and code family (None passes: unchanged)."""
    if symmetry is not None and symmetry not in ("none", "rot180_z"):
        raise DesignError("symmetry must be 'none' or 'rot180_z'")
    if code_family is not None and code_family not in dict(code_families()):
        raise DesignError(f"unknown code family {code_family!r}")
