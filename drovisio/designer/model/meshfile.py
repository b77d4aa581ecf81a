"""Uploaded mesh files: what format the bytes are, reading them into one triangle mesh, and
the length unit their numbers are in."""

from __future__ import annotations

import trimesh

from drovisio.designer.model.errors import DesignError
from drovisio.errors import InputError
from drovisio.layout import UNITS_TO_M
from drovisio.mesh_file import MESH_TYPES
from drovisio.mesh_file import read_mesh as _read_mesh

__all__ = ["MESH_TYPES", "UNITS", "read_mesh", "guess_units", "units_problem"]


def read_mesh(data: bytes, filename: str) -> trimesh.Trimesh:
    """:func:`drovisio.mesh_file.read_mesh`, its refusals as the designer's errors."""
    try:
        return _read_mesh(data, filename)
    except InputError as e:
        raise DesignError(str(e)) from None


#: The length units a mesh file's numbers may be in.
UNITS = ("mm", "cm", "m")


def guess_units(extent: float) -> str:
    """Guess a mesh's length unit from its largest extent, in file numbers.

    Bricks are 2 cm to 5 m: up to 5 the numbers are metres, from 20 millimetres (CAD
    programs' default), in between centimetres.
    """
    if extent <= 5.0:
        return "m"
    if extent < 20.0:
        return "cm"
    return "mm"


def _fmt_len(m: float) -> str:
    if m >= 1.0:
        return f"{m:.3g} m"
    if m >= 0.01:
        return f"{m * 100:.3g} cm" if m * 1000 % 10 else f"{m * 1000:.0f} mm"
    return f"{m * 1000:.3g} mm"


def units_problem(extent: float, units: str) -> tuple[str, str] | None:
    """A warning when ``units`` makes a brick of absurd size.

    Args:
        extent: largest extent of the mesh in file numbers.
        units: the declared unit.

    Returns:
        ``(message, suggested_units)``, or None when the size is plausible (1 cm .. 5 m).
    """
    size = extent * UNITS_TO_M[units]
    guess = guess_units(extent)
    if 0.01 <= size <= 5.0 or guess == units:
        return None
    names = {"mm": "millimetres", "cm": "centimetres", "m": "metres"}
    msg = (f"In {names[units]}, this model is {_fmt_len(size)} long, which is not a brick "
           f"size. Its numbers are probably {names[guess]} (then it is "
           f"{_fmt_len(extent * UNITS_TO_M[guess])} long): choose '{guess}' as the unit.")
    return msg, guess
