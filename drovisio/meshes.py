"""Procedural meshes of the shipped elements (the drick, the landing pad).

All meshes are in metres, in the brick frame of the shipped layouts: origin at the centre of
the body's top face, x along the length, y along the width, z up. They are closed
(watertight) triangle meshes with outward normals, built without boolean operations so the
result is exact and deterministic.

``python -m drovisio.meshes`` (re)writes ``marker_layouts/meshes/*.stl``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import trimesh

from drovisio.fileio import atomic_write
from drovisio.resources import layouts_dir

__all__ = [
    "DRICK_BODY",
    "DRICK_PYRAMID_CENTERS_X",
    "DRICK_PYRAMID_BASE",
    "DRICK_PYRAMID_TOP",
    "DRICK_PYRAMID_HEIGHT",
    "LANDING_PAD",
    "drick_mesh",
    "landing_pad_mesh",
    "shipped_mesh",
    "write_shipped_meshes",
]

#: Drick body size (x, y, z) in metres; the body spans z in [-0.10, 0].
DRICK_BODY = (0.30, 0.15, 0.10)
#: x of the two pyramid centres (y = 0), metres.
DRICK_PYRAMID_CENTERS_X = (-0.075, 0.075)
#: Pyramid base side at z = 0 and top side at z = DRICK_PYRAMID_HEIGHT, metres.
DRICK_PYRAMID_BASE = 0.075
DRICK_PYRAMID_TOP = 0.07
DRICK_PYRAMID_HEIGHT = 0.02
#: Landing pad size (x, y, z) in metres; top face at z = 0.
LANDING_PAD = (0.60, 0.60, 0.01)


def _from_polygons(polygons: Sequence[Sequence[Sequence[float]]]) -> trimesh.Trimesh:
    """A mesh from convex planar polygons (vertices counter-clockwise seen from outside).

    Each polygon is fanned from its first vertex, so the first vertex must not be
    collinear with any pair of consecutive others (true for a corner of a convex polygon
    whose other corners are not all on its two incident edges).
    """
    verts: list[tuple[float, float, float]] = []
    index: dict[tuple[float, float, float], int] = {}
    faces: list[tuple[int, int, int]] = []

    def vid(p: Sequence[float]) -> int:
        x, y, z = (round(float(c), 12) for c in p)
        key = (x, y, z)
        if key not in index:
            index[key] = len(verts)
            verts.append(key)
        return index[key]

    for poly in polygons:
        ids = [vid(p) for p in poly]
        for a, b in zip(ids[1:-1], ids[2:]):
            faces.append((ids[0], a, b))
    mesh = trimesh.Trimesh(np.array(verts, np.float64), np.array(faces, np.int64), process=False)
    return mesh


def drick_mesh() -> trimesh.Trimesh:
    """The drick: a 0.30 x 0.15 x 0.10 m body (z from -0.10 to 0) with two truncated
    pyramids centred at (+-0.075, 0): base 0.075 x 0.075 at z = 0, top 0.07 x 0.07 at
    z = 0.02.

    Returns:
        A watertight trimesh in metres (brick frame).
    """
    lx, ly, lz = DRICK_BODY[0] / 2, DRICK_BODY[1] / 2, DRICK_BODY[2]
    b, t, h = DRICK_PYRAMID_BASE / 2, DRICK_PYRAMID_TOP / 2, DRICK_PYRAMID_HEIGHT
    cxs = DRICK_PYRAMID_CENTERS_X
    # Grid of the top face: the pyramid bases are holes in it.
    xs = sorted({-lx, lx, *(c - b for c in cxs), *(c + b for c in cxs)})
    ys = [-ly, -b, b, ly]
    holes = {(round(c - b, 12), round(-b, 12)) for c in cxs}
    polys: list[list[tuple[float, float, float]]] = []
    for x0, x1 in zip(xs[:-1], xs[1:]):
        for y0, y1 in zip(ys[:-1], ys[1:]):
            if (round(x0, 12), round(y0, 12)) in holes:
                continue
            polys.append([(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)])
    # Sides: top edges carry the grid vertices; fan from a bottom corner.
    polys.append([(-lx, -ly, -lz), (lx, -ly, -lz)] + [(x, -ly, 0) for x in reversed(xs)])
    polys.append([(lx, ly, -lz), (-lx, ly, -lz)] + [(x, ly, 0) for x in xs])
    polys.append([(lx, -ly, -lz), (lx, ly, -lz)] + [(lx, y, 0) for y in reversed(ys)])
    polys.append([(-lx, ly, -lz), (-lx, -ly, -lz)] + [(-lx, y, 0) for y in ys])
    polys.append([(-lx, -ly, -lz), (-lx, ly, -lz), (lx, ly, -lz), (lx, -ly, -lz)])  # bottom
    for c in cxs:
        base = [(c - b, -b, 0), (c + b, -b, 0), (c + b, b, 0), (c - b, b, 0)]
        top = [(c - t, -t, h), (c + t, -t, h), (c + t, t, h), (c - t, t, h)]
        for i in range(4):
            j = (i + 1) % 4
            polys.append([base[i], base[j], top[j], top[i]])
        polys.append(top)
    return _from_polygons(polys)


def landing_pad_mesh() -> trimesh.Trimesh:
    """The landing pad: a 0.60 x 0.60 x 0.01 m plate, top face at z = 0.

    Returns:
        A watertight trimesh in metres.
    """
    x, y, z = LANDING_PAD
    return trimesh.creation.box(
        extents=(x, y, z), transform=trimesh.transformations.translation_matrix((0, 0, -z / 2))
    )


_SHIPPED: dict[str, Callable[[], trimesh.Trimesh]] = {
    "drick.stl": drick_mesh,
    "landing-pad.stl": landing_pad_mesh,
}


def shipped_mesh(file_name: str) -> trimesh.Trimesh | None:
    """The procedural mesh behind a shipped mesh file name (``"drick.stl"``), or None."""
    make = _SHIPPED.get(Path(file_name).name)
    return make() if make is not None else None


def _stl_writer(make: Callable[[], trimesh.Trimesh]) -> Callable[[Path], None]:
    """A writer for :func:`drovisio.fileio.atomic_write` of the mesh ``make`` builds."""
    def write(tmp: Path) -> None:
        make().export(tmp, file_type="stl")
    return write


def write_shipped_meshes(folder: str | os.PathLike[str] | None = None) -> list[Path]:
    """Write the shipped meshes as binary STL (metres).

    Args:
        folder: destination; default ``marker_layouts/meshes`` of the repository.

    Returns:
        The files written.
    """
    out = Path(folder) if folder is not None else layouts_dir() / "meshes"
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, make in _SHIPPED.items():
        path = out / name
        atomic_write(path, _stl_writer(make))
        written.append(path)
    return written


if __name__ == "__main__":
    for p in write_shipped_meshes():
        print(p)
