"""The state of a marker design: fields, derived views, ids and undo (see
:mod:`drovisio.designer.model.document` for the whole picture and the edits)."""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Self

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from drovisio.designer.model.codes import dictionary_for_block, family_dictionaries
from drovisio.designer.model.errors import DesignError
from drovisio.designer.model.frame import face_up, t3, unit
from drovisio.designer.model.history import Snapshot, UndoHistory
from drovisio.designer.model.marker import DesignMarker
from drovisio.designer.model.meshfile import UNITS, guess_units, read_mesh, units_problem
from drovisio.designer.raycast import FlatFaces, cast_ray
from drovisio.geometry import invert
from drovisio.layout import DEFAULT_PALETTE, UNITS_TO_M, ColorSpec, MarkerLayout, aruco_family
from drovisio.mesh_file import load_layout_mesh

__all__ = ["DesignState"]


@dataclass
class DesignState:
    """What a marker design is: its fields, the views derived from them (the mesh in metres,
    the markers in the brick frame), its id block and its undo history. The edits live on
    :class:`drovisio.designer.model.document.DesignDocument`.

    Attributes set by the caller: ``others`` (layouts whose ids must not be reused, e.g. the
    shipped ones) and ``colors`` (dot colours added to the default palette).
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
    _history: UndoHistory = field(default_factory=UndoHistory, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ loading

    @classmethod
    def from_mesh_bytes(cls, data: bytes, filename: str, units: str = "auto",
                        **kwargs: Any) -> Self:
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
                  **kwargs: Any) -> Self:
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
    def from_layout(cls, layout: MarkerLayout, **kwargs: Any) -> Self:
        """A design that edits an existing layout (its mesh, brick frame and markers).

        The mesh is the layout's mesh file (or the shipped procedural one, or a box of the
        layout's dimensions when it names none), in metres, already in the brick frame.
        """
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
                mk = DesignMarker("aruco", t3(m.center_array() * s), t3(n),
                                  t3(m.up_array()), float(m.size * s), slot=m.id)
            else:
                n = m.normal_array()
                mk = DesignMarker("dot", t3(m.center_array() * s), t3(n),
                                  t3(doc._default_up(n)), float(m.diameter * s),
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
        """The inverse of ``brick_from_mesh`` (4x4)."""
        return invert(self.brick_from_mesh)

    def to_brick(self, p: ArrayLike) -> np.ndarray:
        """Points (N, 3) or (3,) from the mesh frame to the brick frame."""
        p = np.asarray(p, np.float64)
        T = self.brick_from_mesh
        return p @ T[:3, :3].T + T[:3, 3]

    def dir_to_brick(self, v: ArrayLike) -> np.ndarray:
        """Directions (N, 3) or (3,) from the mesh frame to the brick frame."""
        return np.asarray(v, np.float64) @ self.brick_from_mesh[:3, :3].T

    def brick_markers(self) -> list[DesignMarker]:
        """The markers in the brick frame (what the layout file holds)."""
        out = []
        for m in self.markers:
            out.append(replace(m, center=t3(self.to_brick(m.c)),
                               normal=t3(self.dir_to_brick(m.n)),
                               up=t3(self.dir_to_brick(m.u))))
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

    def taken_blocks(self) -> list[tuple[range, str]]:
        """Id blocks of the other layouts in this design's code family: ``(block, name)``."""
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
        taken = sorted(self.taken_blocks(), key=lambda b: b[0].start)
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
            fams = family_dictionaries(self.code_family)
            return fams[0] if fams else None
        return dictionary_for_block(self.code_family, block.stop)

    # ------------------------------------------------------------------ undo

    def _snapshot(self) -> Snapshot:
        return Snapshot(self.units, self.brick_from_mesh.copy(), tuple(self.markers),
                        self.first_id, self.ids_per_instance, self.instances, self.symmetry,
                        self.code_family, self.name, self.description, self.selected)

    def _restore(self, s: Snapshot) -> None:
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
        self._history.record(self._snapshot())

    def _changed(self) -> None:
        self.version += 1

    @property
    def can_undo(self) -> bool:
        return self._history.can_undo

    @property
    def can_redo(self) -> bool:
        return self._history.can_redo

    def undo(self) -> bool:
        """Undo the last edit. Returns False when there is nothing to undo."""
        previous = self._history.undo(self._snapshot())
        if previous is None:
            return False
        self._restore(previous)
        return True

    def redo(self) -> bool:
        """Redo the last undone edit. Returns False when there is nothing to redo."""
        following = self._history.redo(self._snapshot())
        if following is None:
            return False
        self._restore(following)
        return True

    def checkpoint(self) -> None:
        """Record the current state for undo (before a multi-step edit such as a drag)."""
        self._push()

    # ------------------------------------------------------------------ faces

    def _default_up(self, normal_m: np.ndarray) -> np.ndarray:
        return face_up(self.brick_from_mesh, normal_m)

    def _face_under(self, point: ArrayLike, normal: np.ndarray, reach: float = 0.002
                    ) -> int | None:
        """Flat face a point lies on (ray from just above it along -normal)."""
        n = unit(normal)
        hit = cast_ray(self.mesh, np.asarray(point) + n * reach, -n)
        if hit is None or hit.distance > 2 * reach:
            return None
        return self.faces.of_triangle(hit.face_index).index

    def copy(self) -> Self:
        """A deep copy (sharing the read-only raw mesh and the other layouts)."""
        new = copy.copy(self)
        new.brick_from_mesh = self.brick_from_mesh.copy()
        new.markers = list(self.markers)
        new._history = self._history.copy()
        new._cache = dict(self._cache)
        return new
