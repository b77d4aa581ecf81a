"""Layouts used together: unique names and no two layouts that could see the same code."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence

from drovisio.layout.dictionaries import aruco_family
from drovisio.layout.errors import LayoutError
from drovisio.layout.files import load_layout
from drovisio.layout.model import MarkerLayout

__all__ = ["check_id_clashes", "check_layout_set", "load_layouts"]


def _where(layout: MarkerLayout) -> str:
    return f"{layout.name!r} ({layout.source if layout.source is not None else 'not from a file'})"


def check_id_clashes(layouts: Sequence[MarkerLayout]) -> None:
    """Raise if layouts meant to be used together could see the same code.

    Each layout owns its whole id block (:meth:`MarkerLayout.id_block`) in every dictionary
    family its codes use; two layouts clash when they share a family and their blocks
    overlap.

    Raises:
        LayoutError: naming both layouts (name and file) and the overlapping ids.
    """
    lines: list[str] = []
    for a_i, a in enumerate(layouts):
        fam_a = {aruco_family(d) for d in a.dictionaries()}
        block_a = a.id_block()
        for b in layouts[a_i + 1:]:
            block_b = b.id_block()
            common = sorted(fam_a & {aruco_family(d) for d in b.dictionaries()})
            lo, hi = max(block_a.start, block_b.start), min(block_a.stop, block_b.stop)
            if common and lo < hi:
                ids = f"{lo}" if hi - lo == 1 else f"{lo}..{hi - 1}"
                lines.append(
                    f"layouts {_where(a)} and {_where(b)} share ids {ids} in the "
                    f"{'/'.join(common)} dictionary family ({a.name}: "
                    f"{block_a.start}..{block_a.stop - 1}, {b.name}: "
                    f"{block_b.start}..{block_b.stop - 1}); give one of them another "
                    "first_id or another dictionary family")
    if lines:
        raise LayoutError("\n".join(lines), lines)


def check_layout_set(layouts: Sequence[MarkerLayout]) -> None:
    """Checks for layouts used together: unique names and no id clashes.

    Raises:
        LayoutError: two layouts with the same name, or clashing ids (see
            :func:`check_id_clashes`).
    """
    seen: dict[str, MarkerLayout] = {}
    for lay in layouts:
        if lay.name in seen:
            raise LayoutError(f"layouts {_where(seen[lay.name])} and {_where(lay)} have the "
                              "same name; detections are reported by layout name, so rename "
                              "one")
        seen[lay.name] = lay
    check_id_clashes(layouts)


def load_layouts(paths: Iterable[str | os.PathLike[str]]) -> list[MarkerLayout]:
    """Load layouts meant to be used together and check them as a set.

    Args:
        paths: layout files.

    Returns:
        The layouts, in the order given.

    Raises:
        LayoutError: any invalid file, duplicate names, or overlapping ids
            (:func:`check_layout_set`).
    """
    layouts = [load_layout(p) for p in paths]
    check_layout_set(layouts)
    return layouts
