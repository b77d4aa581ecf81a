"""Uploaded mesh files: what format the bytes are, reading them into one triangle mesh, and
the length unit their numbers are in."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import trimesh

from drovisio.designer.model.errors import DesignError
from drovisio.layout import UNITS_TO_M

__all__ = ["MESH_TYPES", "UNITS", "read_mesh", "guess_units", "units_problem"]

#: File extensions :func:`read_mesh` accepts.
MESH_TYPES = ("stl", "obj", "ply", "glb", "gltf", "off")
#: The length units a mesh file's numbers may be in.
UNITS = ("mm", "cm", "m")


def _is_stl(data: bytes) -> bool:
    if len(data) >= 84:
        n = int.from_bytes(data[80:84], "little")
        if 84 + 50 * n == len(data):
            return True
    head = data[:2048].lstrip().lower()
    return head.startswith(b"solid") and (b"facet" in data[:1 << 20].lower()
                                         or b"endsolid" in data.lower())


def _is_text(data: bytes) -> bool:
    if b"\0" in data[:65536]:
        return False
    try:
        data[:65536].decode("utf-8")
    except UnicodeDecodeError:
        try:
            data[:65536].decode("latin-1")
        except UnicodeDecodeError:  # pragma: no cover - latin-1 decodes anything
            return False
    return True


def _looks_like(ext: str, data: bytes) -> bool:
    """Whether the bytes look like the format their extension claims."""
    if ext == "stl":
        return _is_stl(data)
    if ext == "ply":
        return data[:3] == b"ply"
    if ext == "glb":
        return data[:4] == b"glTF"
    if ext == "off":
        first = data.lstrip()[:16].upper()
        return _is_text(data) and b"OFF" in first
    if ext == "gltf":
        return _is_text(data) and b'"asset"' in data[:1 << 20]
    if ext == "obj":
        if not _is_text(data):
            return False
        return re.search(rb"(?m)^\s*(v|f)\s", data[:1 << 22]) is not None
    return False


def read_mesh(data: bytes, filename: str) -> trimesh.Trimesh:
    """Read a triangle mesh from the bytes of an uploaded file.

    Args:
        data: the file's content.
        filename: its name; the extension picks the format (STL, OBJ, PLY, GLB, GLTF, OFF).

    Returns:
        The mesh, in the file's own units and axes (vertices merged, degenerate triangles
        dropped). A GLB/GLTF scene is flattened into one mesh.

    Raises:
        DesignError: not a mesh file, an unreadable one, or a mesh with no triangles; the
            message says what to do.
    """
    name = Path(filename or "model").name
    ext = Path(name).suffix.lower().lstrip(".")
    kinds = "STL, OBJ, PLY, GLB/GLTF or OFF"
    if ext not in MESH_TYPES:
        what = f"'.{ext}' files" if ext else "files without an extension"
        raise DesignError(f"{name}: {what} are not 3D models this tool can read. Export the "
                          f"brick from your CAD program as {kinds} (STL is the safest) and "
                          "upload that file.")
    if not data:
        raise DesignError(f"{name}: the file is empty (0 bytes). Export the model again and "
                          "upload the new file.")
    if not _looks_like(ext, data):
        raise DesignError(f"{name}: this is not a {ext.upper()} 3D model (its content does not "
                          f"match the format). Check that you picked the right file, or "
                          f"export the brick again as {kinds}.")
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=ext, force="mesh", process=True)
    except Exception as e:  # trimesh raises many kinds on corrupt files
        reason = str(e).splitlines()[0][:160] if str(e) else type(e).__name__
        extra = (" A .gltf file that refers to separate .bin or image files cannot be read "
                 "alone: export a single .glb file instead." if ext == "gltf" else "")
        raise DesignError(f"{name}: could not read this {ext.upper()} file ({reason}). It may "
                          f"be damaged: export the model again.{extra}") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise DesignError(f"{name}: the model has no triangles (an empty model, or only points "
                          "or lines). Export the solid brick as a surface mesh (STL).")
    V = np.asarray(loaded.vertices, np.float64)
    if not np.all(np.isfinite(V)):
        raise DesignError(f"{name}: the model has invalid coordinates (NaN or infinite). "
                          "Export it again.")
    mesh = trimesh.Trimesh(V, np.asarray(loaded.faces, np.int64), process=True)
    keep = mesh.nondegenerate_faces()
    if not np.all(keep):
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0 or float(np.max(mesh.extents)) <= 0:
        raise DesignError(f"{name}: the model has no triangles with an area (all are "
                          "flattened to lines or points). Export the solid brick again.")
    return mesh


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
