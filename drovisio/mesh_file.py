"""Mesh files from outside (uploaded to the designer, named by a layout): what format the
bytes are, their declared size bounded before anything is built, and reading them into one
triangle mesh. :func:`load_layout_mesh` is the one reader of a layout's ``mesh``: its
bounds, the dot detector's occluders, the renderer and the 3D views all read through it."""

from __future__ import annotations

import io
import json
import os
import re
import struct
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import trimesh

from drovisio.errors import InputError
from drovisio.meshes import shipped_mesh
from drovisio.textfile import missing_reason, name_inside, read_bytes, resolve_inside

__all__ = ["MAX_DEPTH", "MAX_FACES", "MAX_MESH_BYTES", "MAX_NODES", "MESH_TYPES",
           "NamesAMesh", "load_layout_mesh", "read_mesh"]

#: File extensions :func:`read_mesh` accepts.
MESH_TYPES = ("stl", "obj", "ply", "glb", "gltf", "off")
#: Most triangles a mesh may have once a glTF scene's instances are counted (a brick's mesh
#: has thousands; a binary STL at the upload limit about a million).
MAX_FACES = 2_000_000
#: Most node instances in a glTF scene (each placement of a node counts), and its deepest
#: nesting: a few kilobytes of scene graph can otherwise ask for millions of copies.
MAX_NODES = 10_000
MAX_DEPTH = 256
#: Largest mesh file a layout may name (a brick's mesh is a few MB at most).
MAX_MESH_BYTES = 256 * 2**20


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


def _gltf_document(data: bytes, ext: str) -> dict | None:
    """The JSON of a .gltf file or of a .glb's first chunk; None where it cannot be read
    (trimesh then says what is wrong)."""
    if ext == "glb":
        if len(data) < 20:
            return None
        n, kind = struct.unpack_from("<I4s", data, 12)
        if kind != b"JSON" or 20 + n > len(data):
            return None
        text = data[20:20 + n]
    else:
        text = data
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):
        return None
    return doc if isinstance(doc, dict) else None


def _list(x: object) -> list:
    return x if isinstance(x, list) else []


def _count(x: object) -> int:
    return x if isinstance(x, int) and x >= 0 else 0


def _mesh_triangles(doc: dict, k: object) -> int:
    """Triangles of one glTF mesh, from its accessors' declared counts."""
    meshes, acc = doc.get("meshes"), doc.get("accessors")
    if not (isinstance(k, int) and isinstance(meshes, list) and 0 <= k < len(meshes)
            and isinstance(acc, list) and isinstance(meshes[k], dict)):
        return 0
    total = 0
    for prim in meshes[k].get("primitives") or []:
        if not isinstance(prim, dict):
            continue
        attrs = prim.get("attributes")
        i = prim.get("indices", attrs.get("POSITION") if isinstance(attrs, dict) else None)
        n = _count(acc[i].get("count")) if (isinstance(i, int) and 0 <= i < len(acc)
                                           and isinstance(acc[i], dict)) else 0
        mode = prim.get("mode", 4)
        total += n // 3 if mode == 4 else max(n - 2, 0) if mode in (5, 6) else 0
    return total


def _check_gltf(doc: dict, name: str) -> None:
    """Refuse a glTF scene whose node instances, nesting or triangles (each instance of a
    mesh counted) exceed :data:`MAX_NODES`, :data:`MAX_DEPTH`, :data:`MAX_FACES`, from the
    declared structure, before anything is built.

    Raises:
        InputError: the count, the limit and the fix, in one message.
    """
    nodes = _list(doc.get("nodes"))
    scenes = _list(doc.get("scenes"))
    roots: list = []
    for sc in scenes:
        if isinstance(sc, dict) and isinstance(sc.get("nodes"), list):
            roots += sc["nodes"]
    if not scenes:
        children = {c for nd in nodes if isinstance(nd, dict)
                    for c in (nd.get("children") or []) if isinstance(c, int)}
        roots = [i for i in range(len(nodes)) if i not in children]
    fix = ("Export the brick as one mesh (STL is the safest), or simplify the model in "
           "your CAD program, and use the new file.")
    stack = [(r, 1) for r in roots]
    seen, faces = 0, 0
    while stack:
        i, depth = stack.pop()
        if not (isinstance(i, int) and 0 <= i < len(nodes) and isinstance(nodes[i], dict)):
            continue
        seen += 1
        if seen > MAX_NODES or depth > MAX_DEPTH:
            what = (f"more than {MAX_NODES} placed parts" if seen > MAX_NODES
                    else f"parts nested more than {MAX_DEPTH} deep")
            raise InputError(f"{name}: the model's scene has {what}. {fix}")
        faces += _mesh_triangles(doc, nodes[i].get("mesh"))
        if faces > MAX_FACES:
            raise InputError(f"{name}: the model has more than {MAX_FACES:,} triangles once "
                             f"its parts are placed. {fix}")
        kids = nodes[i].get("children")
        if isinstance(kids, list):
            stack += [(c, depth + 1) for c in kids]


def read_mesh(data: bytes, filename: str) -> trimesh.Trimesh:
    """Read a triangle mesh from the bytes of an uploaded file.

    Args:
        data: the file's content.
        filename: its name; the extension picks the format (STL, OBJ, PLY, GLB, GLTF, OFF).

    Returns:
        The mesh, in the file's own units and axes (vertices merged, degenerate triangles
        dropped). A GLB/GLTF scene is flattened into one mesh.

    Raises:
        InputError: not a mesh file, an unreadable one, or a mesh with no triangles; the
            message says what to do.
    """
    name = Path(filename or "model").name
    ext = Path(name).suffix.lower().lstrip(".")
    kinds = "STL, OBJ, PLY, GLB/GLTF or OFF"
    if ext not in MESH_TYPES:
        what = f"'.{ext}' files" if ext else "files without an extension"
        raise InputError(f"{name}: {what} are not 3D models this tool can read. Export the "
                         f"brick from your CAD program as {kinds} (STL is the safest) and "
                         "use that file.")
    if not data:
        raise InputError(f"{name}: the file is empty (0 bytes). Export the model again and "
                         "use the new file.")
    if not _looks_like(ext, data):
        raise InputError(f"{name}: this is not a {ext.upper()} 3D model (its content does not "
                         f"match the format). Check that you picked the right file, or "
                         f"export the brick again as {kinds}.")
    extra_args: dict[str, Any] = {}
    if ext in ("glb", "gltf"):
        doc = _gltf_document(data, ext)
        if doc is not None:
            _check_gltf(doc, name)
        extra_args["skip_materials"] = True   # the shape is all a layout needs; no textures
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=ext, force="mesh", process=True,
                              **extra_args)
    except Exception as e:  # trimesh raises many kinds on corrupt files
        reason = str(e).splitlines()[0][:160] if str(e) else type(e).__name__
        extra = (" A .gltf file that refers to separate .bin or image files cannot be read "
                 "alone: export a single .glb file instead." if ext == "gltf" else "")
        raise InputError(f"{name}: could not read this {ext.upper()} file ({reason}). It may "
                         f"be damaged: export the model again.{extra}") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(f"{name}: the model has no triangles (an empty model, or only points "
                         "or lines). Export the solid brick as a surface mesh (STL).")
    V = np.asarray(loaded.vertices, np.float64)
    if not np.all(np.isfinite(V)):
        raise InputError(f"{name}: the model has invalid coordinates (NaN or infinite). "
                         "Export it again.")
    mesh = trimesh.Trimesh(V, np.asarray(loaded.faces, np.int64), process=True)
    keep = mesh.nondegenerate_faces()
    if not np.all(keep):
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0 or float(np.max(mesh.extents)) <= 0:
        raise InputError(f"{name}: the model has no triangles with an area (all are "
                         "flattened to lines or points). Export the solid brick again.")
    return mesh


class NamesAMesh(Protocol):
    """What :func:`load_layout_mesh` reads of a layout (a
    :class:`~drovisio.layout.MarkerLayout`)."""

    @property
    def name(self) -> str: ...
    @property
    def mesh(self) -> str | None: ...
    @property
    def source(self) -> Path | None: ...
    @property
    def scale_to_m(self) -> float: ...


def load_layout_mesh(layout: NamesAMesh) -> trimesh.Trimesh | None:
    """The mesh a layout names, in metres: the one reader of a layout's ``mesh``.

    The name is read relative to the layout file (the working directory for a layout without
    one) and only inside that folder, links followed, from a regular file of at most
    :data:`MAX_MESH_BYTES`, by :func:`read_mesh` (the bounds of an uploaded mesh). A name
    with nothing behind it that is a shipped mesh's (``meshes/drick.stl``) is built
    procedurally (:func:`drovisio.meshes.shipped_mesh`, metres).

    Args:
        layout: a :class:`~drovisio.layout.MarkerLayout`.

    Returns:
        The mesh in metres (brick frame), or None when the layout names no mesh.

    Raises:
        InputError: ``LAYOUT: mesh: what is wrong and what to do``, in one line: a name
            outside the layout's folder (``..``, a link out of it), missing, not a regular
            file, too large, or not a mesh :func:`read_mesh` reads.
    """
    if layout.mesh is None:
        return None
    source = layout.source
    folder = source.parent if source is not None else Path.cwd()
    where = f"{source or layout.name}: mesh"
    path = name_inside(folder, layout.mesh, where, "mesh")
    if missing_reason(path) is not None and not os.path.islink(path):
        shipped = shipped_mesh(path.name)
        if shipped is None:
            raise InputError(f"{where}: {layout.mesh!r} not found in {folder}; put the mesh "
                             "there or remove the mesh field")
        return shipped
    path = resolve_inside(folder, layout.mesh, where, "mesh")
    try:
        mesh = read_mesh(read_bytes(path, "mesh", MAX_MESH_BYTES), path.name)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    if layout.scale_to_m != 1.0:
        mesh.apply_scale(layout.scale_to_m)
    return mesh
