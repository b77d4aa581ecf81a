"""The marker designer's editable document: a mesh, its units, the brick frame, the markers.

:class:`DesignDocument` is what the web page edits. It wraps the pieces that become a
:class:`drovisio.layout.MarkerLayout` (see :mod:`drovisio.designer.export`):

* **Mesh.** Read from STL, OBJ, PLY, GLB/GLTF or OFF (:func:`read_mesh`, clear messages for a
  file that is not a mesh or has no triangles), kept as loaded; ``units`` says what its numbers
  are (``mm``, ``cm``, ``m``; :func:`guess_units` guesses from the size). Internally it is used
  in metres (:attr:`DesignDocument.mesh`), in the *mesh frame* (the file's own axes).
* **Brick frame.** ``brick_from_mesh`` (4x4, metres): where the layout's origin and axes are on
  the mesh. Set by clicking a face (origin at the face centre, z along its normal), aligning x
  with the longest horizontal edge, turning by 90 deg, flipping. The markers are stored in the
  mesh frame, so moving the brick frame never moves a marker on the brick.
* **Markers.** :class:`DesignMarker`: codes (``aruco``, a slot in the id block) and dots. A
  click ray is cast on the mesh (:mod:`drovisio.designer.raycast`); the marker lies on the hit
  flat face, its normal the face normal, snapped to the face centre (within ``snap_radius``)
  or to a grid laid on the face from its centre. Move, rotate about the normal, resize, centre
  on the face, delete.
* **Ids.** A code's dictionary is chosen from the selected family (``DICT_4X4`` ...) as the
  smallest dictionary holding the id block; ``first_id`` is automatic by default: the lowest
  block that does not clash with the other known layouts (:attr:`DesignDocument.others`).
* **Undo/redo** of every edit (not of loading a new mesh, which starts a new document).

Everything is in metres and radians; degrees only in the arguments named ``*_deg``.
"""

from __future__ import annotations

import copy
import io
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from drovisio.designer.raycast import FlatFace, FlatFaces, RayHit, cast_ray
from drovisio.layout import (
    DEFAULT_PALETTE,
    UNITS_TO_M,
    ColorSpec,
    MarkerLayout,
    aruco_dictionaries,
    aruco_dictionary_size,
    aruco_family,
)

__all__ = [
    "MESH_TYPES", "UNITS", "MODES", "DesignError", "DesignMarker", "DesignDocument",
    "read_mesh", "guess_units", "units_problem", "code_families", "dictionary_for_block",
    "rotation_about",
]

#: File extensions :func:`read_mesh` accepts.
MESH_TYPES = ("stl", "obj", "ply", "glb", "gltf", "off")
UNITS = ("mm", "cm", "m")
#: What a click on the model does.
MODES = ("code", "dot", "select", "origin")
Mode = Literal["code", "dot", "select", "origin"]

UNDO_LIMIT = 200


class DesignError(ValueError):
    """A user-facing problem (bad file, impossible edit). The message says what to do."""


# ------------------------------------------------------------------------------ mesh files


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


# ------------------------------------------------------------------------------ ids


def code_families() -> list[tuple[str, str]]:
    """Code families to choose from: ``(family, label)``; a family's dictionaries share codes.

    ``DICT_4X4`` stands for DICT_4X4_50/100/250/1000 (the size is chosen to hold the ids).
    """
    labels = {
        "DICT_4X4": "4x4 codes (big cells: read from farthest; the thesis's choice)",
        "DICT_5X5": "5x5 codes",
        "DICT_6X6": "6x6 codes",
        "DICT_7X7": "7x7 codes (many ids, small cells)",
    }
    out: list[tuple[str, str]] = []
    seen: set[str] = set()
    for d in aruco_dictionaries():
        fam = aruco_family(d)
        if fam in seen:
            continue
        seen.add(fam)
        out.append((fam, labels.get(fam, d)))
    return out


def _family_dictionaries(family: str) -> list[str]:
    names = [d for d in aruco_dictionaries() if aruco_family(d) == family]
    return sorted(names, key=aruco_dictionary_size)


def dictionary_for_block(family: str, end: int) -> str | None:
    """The smallest dictionary of ``family`` holding ids ``0 .. end-1``, or None."""
    for d in _family_dictionaries(family):
        if aruco_dictionary_size(d) >= end:
            return d
    return None


# ------------------------------------------------------------------------------ geometry


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def rotation_about(axis, angle_rad: float) -> np.ndarray:
    """3x3 rotation by ``angle_rad`` about ``axis`` (right-handed)."""
    k = _unit(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * K + (1 - math.cos(angle_rad)) * K @ K


def _rigid_inv(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _t3(v) -> tuple[float, float, float]:
    a = np.asarray(v, np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class DesignMarker:
    """One marker of the design, in the **mesh frame**, metres.

    Attributes:
        kind: ``"aruco"`` (a printed code) or ``"dot"`` (a colour dot).
        center: centre on the surface.
        normal: unit direction the printed face looks toward (the face's outward normal).
        up: unit in-plane direction toward the printed image's top edge (codes); for dots
            only the reference of the face's grid.
        size: code side (outer black border) or dot diameter.
        slot: the code's slot in the id block (codes only).
        color: dot colour name (dots only).
        face: index of the flat face it lies on (None: not found on the surface).
    """

    kind: Literal["aruco", "dot"]
    center: tuple[float, float, float]
    normal: tuple[float, float, float]
    up: tuple[float, float, float]
    size: float
    slot: int | None = None
    color: str | None = None
    face: int | None = None

    @property
    def c(self) -> np.ndarray:
        return np.array(self.center, np.float64)

    @property
    def n(self) -> np.ndarray:
        return np.array(self.normal, np.float64)

    @property
    def u(self) -> np.ndarray:
        return np.array(self.up, np.float64)

    @property
    def r(self) -> np.ndarray:
        """Unit direction toward the printed image's right edge (``up x normal``)."""
        return np.cross(self.u, self.n)

    def label(self, index: int) -> str:
        """Short name used in the panel and in warnings, e.g. ``"code 0"``, ``"dot 3 (red)"``
        (``index`` counts dots from 1 among all markers)."""
        if self.kind == "aruco":
            return f"code {self.slot}"
        return f"dot {index} ({self.color})"

    def outline(self, samples: int = 8) -> np.ndarray:
        """Points on and inside the marker's printed shape (mesh frame), for face tests."""
        c, r, u = self.c, self.r, self.u
        h = self.size / 2.0
        if self.kind == "aruco":
            t = np.linspace(-1.0, 1.0, samples + 1)
            gx, gy = np.meshgrid(t, t)
            pts = np.stack([gx.ravel(), gy.ravel()], axis=1) * h
        else:
            ang = np.linspace(0, 2 * np.pi, 4 * samples, endpoint=False)
            ring = np.stack([np.cos(ang), np.sin(ang)], axis=1) * h
            pts = np.concatenate([ring, ring * 0.5, [[0.0, 0.0]]])
        return c + pts[:, :1] * r + pts[:, 1:] * u

    def corners(self) -> np.ndarray:
        """A code's corners TL, TR, BR, BL (OpenCV order; mesh frame)."""
        c, r, u, h = self.c, self.r, self.u, self.size / 2.0
        return np.array([c - r * h + u * h, c + r * h + u * h, c + r * h - u * h,
                         c - r * h - u * h])


@dataclass
class _Snapshot:
    units: str
    brick_from_mesh: np.ndarray
    markers: tuple[DesignMarker, ...]
    first_id: int | None
    ids_per_instance: int | None
    instances: int
    symmetry: str
    code_family: str
    name: str
    description: str | None
    selected: int | None


@dataclass
class ClickResult:
    """What a click did: ``action`` in ``added``, ``selected``, ``origin``, ``missed``,
    ``none``; ``marker`` the marker index concerned; ``message`` a sentence for the user."""

    action: str
    message: str
    marker: int | None = None
    point: tuple[float, float, float] | None = None


@dataclass
class DesignDocument:
    """An editable marker design (see the module docstring).

    Attributes set by the caller: ``others`` (layouts whose ids must not be reused, e.g. the
    shipped ones) and ``palette`` (dot colours).
    """

    name: str = "new-brick"
    description: str | None = None
    mesh_name: str | None = None
    units: str = "m"
    units_guessed: bool = False
    brick_from_mesh: np.ndarray = field(default_factory=lambda: np.eye(4))
    markers: list[DesignMarker] = field(default_factory=list)
    first_id: int | None = None  # None: automatic (no clash with `others`)
    ids_per_instance: int | None = None  # None: automatic (highest slot + 1)
    instances: int = 10
    symmetry: str = "none"
    code_family: str = "DICT_4X4"
    code_size: float = 0.065
    dot_diameter: float = 0.02
    dot_color: str = "red"
    grid: float = 0.005
    snap_radius: float = 0.01
    mode: str = "code"
    selected: int | None = None
    source_layout: Path | None = None
    colors: dict[str, ColorSpec] | None = None
    others: list[MarkerLayout] = field(default_factory=list)
    version: int = 0
    mesh_version: int = 0
    _mesh_raw: trimesh.Trimesh | None = field(default=None, repr=False)
    _undo: list[_Snapshot] = field(default_factory=list, repr=False)
    _redo: list[_Snapshot] = field(default_factory=list, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ loading

    @classmethod
    def from_mesh_bytes(cls, data: bytes, filename: str, units: str = "auto",
                        **kwargs) -> DesignDocument:
        """A new design on an uploaded mesh (see :func:`read_mesh`).

        Args:
            data, filename: the uploaded file.
            units: ``mm``, ``cm``, ``m`` or ``auto`` (guessed from the size).
            **kwargs: other fields (``others``, ``name`` ...).
        """
        mesh = read_mesh(data, filename)
        return cls.from_mesh(mesh, filename, units, **kwargs)

    @classmethod
    def from_mesh(cls, mesh: trimesh.Trimesh, filename: str, units: str = "auto",
                  **kwargs) -> DesignDocument:
        """A new design on a mesh already loaded (file units)."""
        if units not in (*UNITS, "auto"):
            raise DesignError(f"unknown unit {units!r}: choose mm, cm or m")
        doc = cls(**kwargs)
        doc._mesh_raw = mesh
        doc.mesh_name = Path(filename).name
        extent = float(np.max(mesh.extents))
        doc.units_guessed = units == "auto"
        doc.units = guess_units(extent) if units == "auto" else units
        if "name" not in kwargs:
            stem = re.sub(r"[^a-z0-9]+", "-", Path(filename).stem.lower()).strip("-")
            doc.name = stem or "new-brick"
        doc._mesh_changed()
        return doc

    @classmethod
    def from_layout(cls, layout: MarkerLayout, **kwargs) -> DesignDocument:
        """A design that edits an existing layout (its mesh, brick frame and markers).

        The mesh is the layout's mesh file (or the shipped procedural one, or a box of the
        layout's dimensions when it names none), in metres, already in the brick frame.
        """
        from drovisio.meshes import load_layout_mesh

        mesh = load_layout_mesh(layout)
        if mesh is None:
            dims = layout.dimensions_m
            mesh = trimesh.creation.box(extents=dims)
            mesh.apply_translation([0, 0, -dims[2] / 2])
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64),
                               np.asarray(mesh.faces, np.int64), process=True)
        kwargs.setdefault("name", layout.name)
        kwargs.setdefault("description", layout.description)
        mesh_name = Path(layout.mesh).name if layout.mesh else f"{layout.name}-box.stl"
        doc = cls.from_mesh(mesh, mesh_name, "m", **kwargs)
        doc.source_layout = layout.source
        doc.colors = dict(layout.colors) if layout.colors else None
        codes = layout.code_markers()
        if codes:
            doc.code_family = aruco_family(codes[0].dictionary)
            doc.first_id = layout.first_id
            doc.ids_per_instance = layout.ids_per_instance
            doc.instances = layout.instances or doc.instances
        doc.symmetry = layout.symmetry
        s = layout.scale_to_m
        for m in layout.markers:
            if m.kind == "aruco":
                n = m.normal_array()
                mk = DesignMarker("aruco", _t3(m.center_array() * s), _t3(n),
                                  _t3(m.up_array()), float(m.size * s), slot=m.id)
            else:
                n = m.normal_array()
                mk = DesignMarker("dot", _t3(m.center_array() * s), _t3(n),
                                  _t3(doc._default_up(n)), float(m.diameter * s),
                                  color=m.color)
            doc.markers.append(replace(mk, face=doc._face_under(mk.c, n)))
        return doc

    def _mesh_changed(self) -> None:
        self._cache.clear()
        self.mesh_version += 1
        self.version += 1

    # ------------------------------------------------------------------ derived

    @property
    def has_mesh(self) -> bool:
        return self._mesh_raw is not None

    @property
    def mesh_raw(self) -> trimesh.Trimesh | None:
        """The mesh as loaded (file units, file axes)."""
        return self._mesh_raw

    @property
    def scale(self) -> float:
        """Metres per mesh-file unit."""
        return UNITS_TO_M[self.units]

    @property
    def mesh(self) -> trimesh.Trimesh:
        """The mesh in metres, mesh frame (cached)."""
        if self._mesh_raw is None:
            raise DesignError("no 3D model loaded yet: upload one or open an example first")
        key = ("mesh", self.units)
        if key not in self._cache:
            m = self._mesh_raw.copy()
            m.apply_scale(self.scale)
            self._cache[key] = m
        return self._cache[key]

    @property
    def faces(self) -> FlatFaces:
        """The mesh's flat faces (metres, mesh frame; cached)."""
        key = ("faces", self.units)
        if key not in self._cache:
            self._cache[key] = FlatFaces(self.mesh)
        return self._cache[key]

    @property
    def extent_file_units(self) -> float:
        """Largest extent of the mesh in file numbers."""
        return float(np.max(self._mesh_raw.extents)) if self._mesh_raw is not None else 0.0

    def units_warning(self) -> tuple[str, str] | None:
        """``(message, suggested unit)`` when the declared unit gives an absurd size."""
        if self._mesh_raw is None:
            return None
        return units_problem(self.extent_file_units, self.units)

    @property
    def mesh_from_brick(self) -> np.ndarray:
        return _rigid_inv(self.brick_from_mesh)

    def to_brick(self, p) -> np.ndarray:
        """Points (N, 3) or (3,) from the mesh frame to the brick frame."""
        p = np.asarray(p, np.float64)
        T = self.brick_from_mesh
        return p @ T[:3, :3].T + T[:3, 3]

    def dir_to_brick(self, v) -> np.ndarray:
        return np.asarray(v, np.float64) @ self.brick_from_mesh[:3, :3].T

    def brick_markers(self) -> list[DesignMarker]:
        """The markers in the brick frame (what the layout file holds)."""
        out = []
        for m in self.markers:
            out.append(replace(m, center=_t3(self.to_brick(m.c)),
                               normal=_t3(self.dir_to_brick(m.n)),
                               up=_t3(self.dir_to_brick(m.u))))
        return out

    def brick_mesh(self) -> trimesh.Trimesh:
        """The mesh in metres in the brick frame (what gets exported with the layout)."""
        m = self.mesh.copy()
        m.apply_transform(self.brick_from_mesh)
        return m

    def dimensions(self) -> np.ndarray:
        """Bounding-box size of the brick along the brick axes, metres."""
        V = self.to_brick(self.mesh.vertices)
        return V.max(axis=0) - V.min(axis=0)

    def palette(self) -> dict[str, ColorSpec]:
        return {**DEFAULT_PALETTE, **(self.colors or {})}

    def codes(self) -> list[tuple[int, DesignMarker]]:
        return [(i, m) for i, m in enumerate(self.markers) if m.kind == "aruco"]

    def dots(self) -> list[tuple[int, DesignMarker]]:
        return [(i, m) for i, m in enumerate(self.markers) if m.kind == "dot"]

    def marker_label(self, index: int) -> str:
        m = self.markers[index]
        if m.kind == "aruco":
            return m.label(index)
        k = sum(1 for j in range(index + 1) if self.markers[j].kind == "dot")
        return m.label(k)

    # ---- ids

    def effective_ids_per_instance(self) -> int:
        if self.ids_per_instance is not None:
            return self.ids_per_instance
        slots = [m.slot for _, m in self.codes() if m.slot is not None]
        return max(slots) + 1 if slots else 1

    def _taken_blocks(self) -> list[tuple[range, str]]:
        out = []
        for lay in self.others:
            if lay.name == self.name:
                continue
            if self.code_family in {aruco_family(d) for d in lay.dictionaries()}:
                out.append((lay.id_block(), lay.name))
        return out

    def free_first_id(self, span: int | None = None) -> int:
        """The lowest first id whose block (``span`` ids) clashes with no other layout."""
        span = span if span is not None else self.effective_ids_per_instance() * self.instances
        taken = sorted(self._taken_blocks(), key=lambda b: b[0].start)
        start = 0
        moved = True
        while moved:
            moved = False
            for block, _ in taken:
                if block.start < start + span and start < block.stop:
                    start = block.stop
                    moved = True
        return start

    def effective_first_id(self) -> int:
        return self.first_id if self.first_id is not None else self.free_first_id()

    def id_block(self) -> range:
        if not self.codes():
            return range(0)
        first = self.effective_first_id()
        return range(first, first + self.effective_ids_per_instance() * self.instances)

    def dictionary(self) -> str | None:
        """The dictionary the codes use: the smallest of the family holding the block (None if
        none does, or no codes)."""
        block = self.id_block()
        if not block:
            fams = _family_dictionaries(self.code_family)
            return fams[0] if fams else None
        return dictionary_for_block(self.code_family, block.stop)

    # ------------------------------------------------------------------ undo

    def _snapshot(self) -> _Snapshot:
        return _Snapshot(self.units, self.brick_from_mesh.copy(), tuple(self.markers),
                         self.first_id, self.ids_per_instance, self.instances, self.symmetry,
                         self.code_family, self.name, self.description, self.selected)

    def _restore(self, s: _Snapshot) -> None:
        units_changed = s.units != self.units
        self.units = s.units
        self.brick_from_mesh = s.brick_from_mesh.copy()
        self.markers = list(s.markers)
        self.first_id, self.ids_per_instance = s.first_id, s.ids_per_instance
        self.instances, self.symmetry, self.code_family = s.instances, s.symmetry, s.code_family
        self.name, self.description = s.name, s.description
        self.selected = s.selected if s.selected is None or s.selected < len(self.markers) \
            else None
        if units_changed:
            self._mesh_changed()
        else:
            self.version += 1

    def _push(self) -> None:
        self._undo.append(self._snapshot())
        del self._undo[:-UNDO_LIMIT]
        self._redo.clear()

    def _changed(self) -> None:
        self.version += 1

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    def undo(self) -> bool:
        """Undo the last edit. Returns False when there is nothing to undo."""
        if not self._undo:
            return False
        self._redo.append(self._snapshot())
        self._restore(self._undo.pop())
        return True

    def redo(self) -> bool:
        """Redo the last undone edit. Returns False when there is nothing to redo."""
        if not self._redo:
            return False
        self._undo.append(self._snapshot())
        self._restore(self._redo.pop())
        return True

    def checkpoint(self) -> None:
        """Record the current state for undo (before a multi-step edit such as a drag)."""
        self._push()

    # ------------------------------------------------------------------ frame

    def _brick_axes_in_mesh(self) -> np.ndarray:
        """Columns: the brick's x, y, z axes expressed in the mesh frame."""
        return self.brick_from_mesh[:3, :3].T

    def _set_mesh_from_brick(self, origin_m, x_m, z_m) -> None:
        z = _unit(z_m)
        x = np.asarray(x_m, np.float64) - (np.asarray(x_m) @ z) * z
        x = _unit(x)
        y = np.cross(z, x)
        M = np.eye(4)
        M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, y, z, origin_m
        B = _rigid_inv(M)
        B[np.abs(B) < 1e-12] = 0.0
        self.brick_from_mesh = B

    def _pick_x(self, z: np.ndarray) -> np.ndarray:
        axes = self._brick_axes_in_mesh()
        for cand in (axes[:, 0], axes[:, 1], -axes[:, 2], np.array([1.0, 0, 0]),
                     np.array([0, 1.0, 0])):
            p = cand - (cand @ z) * z
            if np.linalg.norm(p) > 0.2:
                return p
        return np.array([1.0, 0, 0])  # pragma: no cover

    def set_origin_on_face(self, face: int) -> None:
        """Put the brick origin at the centre of a flat face, z along its outward normal
        (x: the current x axis laid on the face)."""
        f = self.faces.faces[face]
        self._push()
        self._set_mesh_from_brick(self.faces.centre(f), self._pick_x(f.normal), f.normal)
        self._changed()

    def origin_to_top_centre(self) -> None:
        """Origin at the centre of the brick's bounding box in x and y, on its top (max z)."""
        V = self.to_brick(self.mesh.vertices)
        lo, hi = V.min(axis=0), V.max(axis=0)
        target_b = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]])
        self._push()
        axes = self._brick_axes_in_mesh()
        origin_m = self.mesh_from_brick[:3, :3] @ target_b + self.mesh_from_brick[:3, 3]
        self._set_mesh_from_brick(origin_m, axes[:, 0], axes[:, 2])
        self._changed()

    def longest_edge_direction(self) -> np.ndarray | None:
        """Brick-frame direction (unit, in the xy plane) of the mesh's longest *feature* edge
        (between two faces meeting at an angle; triangulation diagonals inside a flat face do
        not count) that is perpendicular to z (within 1 deg), or None."""
        mesh = self.mesh
        E = np.asarray(mesh.face_adjacency_edges, np.int64).reshape(-1, 2)
        if len(E):
            E = E[np.asarray(mesh.face_adjacency_angles) > np.radians(1.0)]
        # plus the open boundary of a mesh that is not closed (edges of a single face)
        boundary = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
        if len(boundary):
            E = np.vstack([E, mesh.edges_sorted[np.asarray(boundary).ravel()]])
        if len(E) == 0:
            return None
        V = self.to_brick(mesh.vertices)
        d = V[E[:, 1]] - V[E[:, 0]]
        length = np.linalg.norm(d, axis=1)
        flat = np.abs(d[:, 2]) <= np.sin(np.radians(1.0)) * length
        if not np.any(flat & (length > 0)):
            return None
        L = np.where(flat, length, -1.0)
        best = L.max()
        cands = np.flatnonzero(L >= best * (1 - 1e-6))
        # among equally long edges, the one closest to the current x axis
        dirs = d[cands, :2] / length[cands, None]
        k = cands[int(np.argmax(np.abs(dirs[:, 0])))]
        v = np.array([d[k, 0], d[k, 1], 0.0])
        v = _unit(v)
        return v if v[0] >= 0 else -v

    def align_x_with_longest_edge(self) -> bool:
        """Turn the brick frame about z so that x runs along the longest horizontal edge.
        Returns False when the mesh has no edge perpendicular to z."""
        v = self.longest_edge_direction()
        if v is None:
            return False
        self._push()
        angle = math.atan2(v[1], v[0])
        self._rotate_frame(rotation_about([0, 0, 1], angle))
        self._changed()
        return True

    def _rotate_frame(self, R_old_from_new: np.ndarray) -> None:
        """New brick axes = old axes rotated by R (expressed in the old brick frame)."""
        T = np.eye(4)
        T[:3, :3] = R_old_from_new.T  # new_from_old
        B = T @ self.brick_from_mesh
        B[np.abs(B) < 1e-12] = 0.0
        self.brick_from_mesh = B

    def turn_frame(self, angle_deg: float = 90.0) -> None:
        """Turn the brick's x and y axes about z by ``angle_deg``."""
        self._push()
        self._rotate_frame(rotation_about([0, 0, 1], math.radians(angle_deg)))
        self._changed()

    def flip_frame(self) -> None:
        """Turn the brick frame upside down (half-turn about x: z and y reverse)."""
        self._push()
        self._rotate_frame(rotation_about([1, 0, 0], math.pi))
        self._changed()

    def reset_frame(self) -> None:
        """The brick frame back to the model file's own origin and axes."""
        self._push()
        self.brick_from_mesh = np.eye(4)
        self._changed()

    # ------------------------------------------------------------------ units

    def set_units(self, units: str) -> None:
        """Say what the mesh file's numbers are (``mm``, ``cm``, ``m``). Markers stay where
        they are on the model; their sizes stay the same."""
        if units not in UNITS:
            raise DesignError(f"unknown unit {units!r}: choose mm, cm or m")
        if units == self.units:
            self.units_guessed = False
            return
        self._push()
        k = UNITS_TO_M[units] / UNITS_TO_M[self.units]
        self.markers = [replace(m, center=_t3(m.c * k)) for m in self.markers]
        B = self.brick_from_mesh.copy()
        B[:3, 3] *= k
        self.brick_from_mesh = B
        self.units = units
        self.units_guessed = False
        self._mesh_changed()

    # ------------------------------------------------------------------ placing

    def _default_up(self, normal_m) -> np.ndarray:
        """In-plane 'up' of a face: the brick's z laid on the face, or the brick's y for a
        face looking along z."""
        n = _unit(normal_m)
        axes = self._brick_axes_in_mesh()
        for cand in (axes[:, 2], axes[:, 1], axes[:, 0]):
            p = cand - (cand @ n) * n
            if np.linalg.norm(p) > 0.3:
                return _unit(p)
        return _unit(np.cross(n, [1.0, 0, 0]))  # pragma: no cover

    def _face_axes(self, face: FlatFace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centre, right, up) of a face's grid (mesh frame)."""
        up = self._default_up(face.normal)
        return self.faces.centre(face), np.cross(up, face.normal), up

    def snap(self, face: FlatFace, point) -> np.ndarray:
        """Snap a point on a face: to the face centre within ``snap_radius``, else to the
        face's grid (step ``grid`` from the face centre, along the face's right/up axes)."""
        c, r, u = self._face_axes(face)
        p = np.asarray(point, np.float64)
        p = p - ((p - c) @ face.normal) * face.normal  # onto the plane
        if np.linalg.norm(p - c) <= self.snap_radius:
            return c
        if self.grid > 0:
            a = round(float((p - c) @ r) / self.grid) * self.grid
            b = round(float((p - c) @ u) / self.grid) * self.grid
            return c + a * r + b * u
        return p

    def _face_under(self, point, normal, reach: float = 0.002) -> int | None:
        """Flat face a point lies on (ray from just above it along -normal)."""
        n = _unit(normal)
        hit = cast_ray(self.mesh, np.asarray(point) + n * reach, -n)
        if hit is None or hit.distance > 2 * reach:
            return None
        return self.faces.of_triangle(hit.face_index).index

    def hit(self, origin, direction, world_from_mesh: np.ndarray | None = None
            ) -> RayHit | None:
        """Cast a world-frame click ray on the mesh drawn with pose ``world_from_mesh``
        (default: the brick frame is the world, i.e. ``brick_from_mesh``)."""
        pose = self.brick_from_mesh if world_from_mesh is None else world_from_mesh
        return cast_ray(self.mesh, origin, direction, pose)

    def click(self, origin, direction, world_from_mesh: np.ndarray | None = None
              ) -> ClickResult:
        """Handle a click ray from the 3D view according to :attr:`mode`.

        ``code``/``dot``: add a marker where the ray meets the model; ``select``: select the
        marker nearest to the hit point; ``origin``: put the brick origin on the clicked face.
        """
        if not self.has_mesh:
            return ClickResult("none", "Load a 3D model first (upload it, or open an example).")
        h = self.hit(origin, direction, world_from_mesh)
        if h is None:
            if self.mode == "select":
                self.select(None)
            return ClickResult("missed", "The click missed the model: click on the brick "
                                         "itself.")
        face = self.faces.of_triangle(h.face_index)
        if self.mode == "origin":
            self.set_origin_on_face(face.index)
            return ClickResult("origin", "The brick origin is now at the centre of the clicked "
                                         "face, z pointing out of it.", point=_t3(h.point))
        if self.mode == "select":
            idx = self.marker_at(h.point)
            self.select(idx)
            if idx is None:
                return ClickResult("selected", "No marker there: nothing selected.")
            return ClickResult("selected", f"Selected {self.marker_label(idx)}.", idx)
        kind = "aruco" if self.mode == "code" else "dot"
        idx = self.add_marker(kind, face.index, h.point)
        return ClickResult("added", f"Added {self.marker_label(idx)}.", idx,
                           point=self.markers[idx].center)

    def marker_at(self, point) -> int | None:
        """Index of the marker covering a point (mesh frame), nearest centre first."""
        p = np.asarray(point, np.float64)
        best, best_d = None, np.inf
        for i, m in enumerate(self.markers):
            d = float(np.linalg.norm(p - m.c))
            reach = m.size * (0.75 if m.kind == "aruco" else 0.6)
            if d <= reach and d < best_d:
                best, best_d = i, d
        return best

    def _next_slot(self) -> int:
        used = {m.slot for _, m in self.codes()}
        s = 0
        while s in used:
            s += 1
        return s

    def add_marker(self, kind: str, face: int, point, size: float | None = None,
                   color: str | None = None, snap: bool = True) -> int:
        """Add a code or a dot on a flat face at a point (mesh frame, snapped unless
        ``snap`` is False). Returns its index; it becomes the selection."""
        if kind not in ("aruco", "dot"):
            raise DesignError(f"unknown marker kind {kind!r}")
        f = self.faces.faces[face]
        p = self.snap(f, point) if snap else np.asarray(point, np.float64)
        up = self._default_up(f.normal)
        self._push()
        if kind == "aruco":
            m = DesignMarker("aruco", _t3(p), _t3(f.normal), _t3(up),
                             float(size or self.code_size), slot=self._next_slot(), face=face)
        else:
            colour = color or self.dot_color
            if colour not in self.palette():
                raise DesignError(f"unknown colour {colour!r}: use one of "
                                  f"{', '.join(self.palette())}")
            m = DesignMarker("dot", _t3(p), _t3(f.normal), _t3(up),
                             float(size or self.dot_diameter), color=colour, face=face)
        self.markers.append(m)
        self.selected = len(self.markers) - 1
        self._changed()
        return self.selected

    def _check_index(self, index: int) -> DesignMarker:
        if not isinstance(index, int) or not 0 <= index < len(self.markers):
            raise DesignError(f"there is no marker number {index}")
        return self.markers[index]

    def select(self, index: int | None) -> None:
        if index is not None:
            self._check_index(index)
        if index != self.selected:
            self.selected = index
            self._changed()

    def move_marker(self, index: int, origin, direction, world_from_mesh=None,
                    record: bool = True) -> bool:
        """Move a marker to where a ray meets the model (it may change face). Returns False
        if the ray misses. ``record=False`` during a drag (call :meth:`checkpoint` once)."""
        m = self._check_index(index)
        h = self.hit(origin, direction, world_from_mesh)
        if h is None:
            return False
        f = self.faces.of_triangle(h.face_index)
        p = self.snap(f, h.point)
        if record:
            self._push()
        up = m.u
        if f.index != m.face:
            up = self._default_up(f.normal)
        self.markers[index] = replace(m, center=_t3(p), normal=_t3(f.normal), up=_t3(up),
                                      face=f.index)
        self._changed()
        return True

    def nudge_marker(self, index: int, right: float, up: float) -> None:
        """Move a marker on its face plane by ``right``/``up`` metres along the face grid."""
        m = self._check_index(index)
        if m.face is not None:
            _, r, u = self._face_axes(self.faces.faces[m.face])
        else:
            r, u = m.r, m.u
        self._push()
        p = m.c + right * r + up * u
        self.markers[index] = replace(m, center=_t3(p))
        self._changed()

    def centre_marker(self, index: int) -> None:
        """Move a marker to the centre of its face."""
        m = self._check_index(index)
        if m.face is None:
            raise DesignError(f"{self.marker_label(index)} is not on a face of the model: "
                              "move it onto the model first")
        self._push()
        c = self.faces.centre(self.faces.faces[m.face])
        self.markers[index] = replace(m, center=_t3(c))
        self._changed()

    def rotate_marker(self, index: int, angle_deg: float) -> None:
        """Turn a code about its normal by ``angle_deg`` (counter-clockwise seen from the
        front)."""
        m = self._check_index(index)
        self._push()
        R = rotation_about(m.n, math.radians(angle_deg))
        up = R @ m.u
        up[np.abs(up) < 1e-12] = 0.0
        self.markers[index] = replace(m, up=_t3(_unit(up)))
        self._changed()

    def set_marker(self, index: int, *, size: float | None = None, color: str | None = None,
                   slot: int | None = None) -> None:
        """Change a marker's size (code side / dot diameter, metres), colour (dots) or slot
        (codes; a slot already used by another code is swapped with it)."""
        m = self._check_index(index)
        changes: dict = {}
        if size is not None:
            if not (isinstance(size, (int, float)) and math.isfinite(size) and size > 0):
                raise DesignError("the size must be a positive number")
            if size > 5.0:
                raise DesignError("the size is given in metres and must be below 5 m")
            changes["size"] = float(size)
        if color is not None:
            if m.kind != "dot":
                raise DesignError("only dots have a colour")
            if color not in self.palette():
                raise DesignError(f"unknown colour {color!r}: use one of "
                                  f"{', '.join(self.palette())}")
            changes["color"] = color
        swap = None
        if slot is not None:
            if m.kind != "aruco":
                raise DesignError("only codes have a slot")
            if not isinstance(slot, int) or slot < 0 or slot > 999:
                raise DesignError("the slot must be a whole number from 0 to 999")
            changes["slot"] = slot
            swap = next((i for i, o in self.codes() if o.slot == slot and i != index), None)
        if not changes:
            return
        self._push()
        if swap is not None:
            self.markers[swap] = replace(self.markers[swap], slot=m.slot)
        self.markers[index] = replace(m, **changes)
        self._changed()

    def delete_marker(self, index: int) -> None:
        self._check_index(index)
        self._push()
        del self.markers[index]
        if self.selected is not None:
            if self.selected == index:
                self.selected = None
            elif self.selected > index:
                self.selected -= 1
        self._changed()

    # ------------------------------------------------------------------ layout settings

    def set_mode(self, mode: str) -> None:
        if mode not in MODES:
            raise DesignError(f"unknown click mode {mode!r}: use one of {', '.join(MODES)}")
        if mode != self.mode:
            self.mode = mode
            self._changed()

    def set_defaults(self, *, code_size: float | None = None, dot_diameter: float | None = None,
                     dot_color: str | None = None, grid: float | None = None,
                     snap_radius: float | None = None) -> None:
        """Sizes/colour for the next markers and the snapping (metres; no undo)."""
        for name, v in (("code size", code_size), ("dot diameter", dot_diameter)):
            if v is not None and not (math.isfinite(v) and 0 < v <= 5):
                raise DesignError(f"the {name} must be between 0 and 5 m")
        for name, v in (("grid step", grid), ("snap distance", snap_radius)):
            if v is not None and not (math.isfinite(v) and 0 <= v <= 1):
                raise DesignError(f"the {name} must be between 0 and 1 m (0 turns it off)")
        if dot_color is not None and dot_color not in self.palette():
            raise DesignError(f"unknown colour {dot_color!r}: use one of "
                              f"{', '.join(self.palette())}")
        if code_size is not None:
            self.code_size = float(code_size)
        if dot_diameter is not None:
            self.dot_diameter = float(dot_diameter)
        if dot_color is not None:
            self.dot_color = dot_color
        if grid is not None:
            self.grid = float(grid)
        if snap_radius is not None:
            self.snap_radius = float(snap_radius)
        self._changed()

    def set_layout_fields(self, *, name: str | None = None, description: str | None = None,
                          first_id: int | None | str = "keep",
                          ids_per_instance: int | None | str = "keep",
                          instances: int | None = None, symmetry: str | None = None,
                          code_family: str | None = None) -> None:
        """Change the layout-level fields (undoable). ``first_id``/``ids_per_instance``
        ``None`` means automatic; ``"keep"`` leaves them."""
        if name is not None:
            name = name.strip()
            if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", name):
                raise DesignError("the name may use letters, digits, '-', '_' and '.', start "
                                  "with a letter or digit, and be at most 64 characters "
                                  "(it becomes the file name)")
        for label, v, lo in (("first id", first_id, 0), ("ids per brick", ids_per_instance, 1),
                             ("number of bricks", instances, 1)):
            if v not in (None, "keep") and (not isinstance(v, int) or isinstance(v, bool)
                                            or v < lo or v > 100000):
                raise DesignError(f"the {label} must be a whole number from {lo}")
        if symmetry is not None and symmetry not in ("none", "rot180_z"):
            raise DesignError("symmetry must be 'none' or 'rot180_z'")
        if code_family is not None and code_family not in dict(code_families()):
            raise DesignError(f"unknown code family {code_family!r}")
        self._push()
        if name is not None:
            self.name = name
        if description is not None:
            self.description = description.strip() or None
        if first_id != "keep":
            self.first_id = first_id  # type: ignore[assignment]
        if ids_per_instance != "keep":
            self.ids_per_instance = ids_per_instance  # type: ignore[assignment]
        if instances is not None:
            self.instances = instances
        if symmetry is not None:
            self.symmetry = symmetry
        if code_family is not None:
            self.code_family = code_family
        self._changed()

    # ------------------------------------------------------------------ layout

    def layout_data(self, mesh_ref: str | None = None) -> dict:
        """The design as layout-file data (brick frame, metres), not yet validated: send
        it through :func:`drovisio.layout.parse_layout` (see :mod:`.export`).

        Args:
            mesh_ref: the ``mesh`` field (path relative to the layout file), or None.
        """

        def r(v, nd: int = 7) -> list[float]:
            return [float(round(float(x), nd)) + 0.0 for x in np.ravel(v)]

        markers = []
        dictionary = self.dictionary() or _family_dictionaries(self.code_family)[-1]
        for m in self.brick_markers():
            if m.kind == "aruco":
                markers.append({"kind": "aruco", "dictionary": dictionary, "id": m.slot,
                                "size": float(round(m.size, 7)), "center": r(m.center),
                                "normal": r(_unit(m.normal), 9), "up": r(_unit(m.up), 9)})
            else:
                markers.append({"kind": "dot", "color": m.color,
                                "diameter": float(round(m.size, 7)), "center": r(m.center),
                                "normal": r(_unit(m.normal), 9)})
        dims = [max(float(round(d, 6)), 1e-6) for d in self.dimensions()]
        data: dict = {
            "schema": "drovisio/marker-layout@1",
            "name": self.name,
            "description": self.description or (
                f"Designed with the Drovisio marker designer on {self.mesh_name or 'a mesh'}: "
                f"{len(self.codes())} code(s), {len(self.dots())} dot(s)."),
            "units": "m",
            "dimensions": dims,
            "mesh": mesh_ref,
            "first_id": None, "ids_per_instance": None, "instances": None,
            "symmetry": self.symmetry,
            "markers": markers,
        }
        if self.codes():
            data["first_id"] = self.effective_first_id()
            data["ids_per_instance"] = self.effective_ids_per_instance()
            data["instances"] = self.instances
        if self.colors:
            data["colors"] = {k: v.model_dump(mode="json", exclude_none=True)
                              for k, v in self.colors.items()}
        if mesh_ref is None:
            del data["mesh"]
        return data

    def copy(self) -> DesignDocument:
        """A deep copy (sharing the read-only raw mesh and the other layouts)."""
        new = copy.copy(self)
        new.brick_from_mesh = self.brick_from_mesh.copy()
        new.markers = list(self.markers)
        new._undo, new._redo = list(self._undo), list(self._redo)
        new._cache = dict(self._cache)
        return new
