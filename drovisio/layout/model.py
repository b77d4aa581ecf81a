"""The layout file's model: :class:`MarkerLayout`, its units and its metre accessors.

The model keeps the numbers in the file's ``units`` (so a layout written in millimetres saves
back in millimetres); the ``*_m`` accessors return metres. Coordinates are in the brick frame
the layout defines.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictInt,
    field_validator,
    model_validator,
)

from drovisio.errors import LIMITS
from drovisio.layout.checks import (
    color_issues,
    coplanar_issues,
    dots_rot180_z_symmetric,
    id_issues,
    symmetry_issues,
)
from drovisio.layout.errors import LocatedIssues
from drovisio.layout.jsontext import layout_json_text
from drovisio.layout.markers import ArucoMarker, DotMarker, Marker, PositiveFloat
from drovisio.layout.palette import DEFAULT_PALETTE, ColorSpec

__all__ = ["SCHEMA_ID", "UNITS_TO_M", "MarkerLayout", "layout_json_schema"]

#: The exact value of a layout file's ``schema`` field.
SCHEMA_ID = "drovisio/marker-layout@1"

#: Metres per file unit.
UNITS_TO_M: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}


class MarkerLayout(BaseModel):
    """A brick type's markers (the ``marker_layouts/*.json`` file format).

    Numbers are stored in ``units``; use the ``*_m`` accessors for metres. Build one from a
    file with :func:`load_layout` or from a dict/JSON text with :func:`parse_layout` (both
    raise :class:`LayoutError`; ``MarkerLayout.model_validate`` raises pydantic's
    ``ValidationError``). Immutable; ``model_copy(update=...)`` does not re-validate, so
    send edited data through :func:`parse_layout`. Equality compares content only.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, populate_by_name=True,
                              frozen=True, title="Drovisio marker layout")

    schema_id: Literal["drovisio/marker-layout@1"] = Field(
        alias="schema", description=f"File format id, exactly {SCHEMA_ID!r}."
    )
    name: str = Field(min_length=1, description="Layout name, used in detection output.")
    description: str | None = Field(
        default=None, description="Free text describing the physical brick."
    )
    units: Literal["m", "cm", "mm"] = Field(
        description="Length unit of every coordinate, size, diameter and of the mesh."
    )
    dimensions: tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = Field(
        default=None,
        description="Bounding box size [x, y, z] of the brick, each > 0; when absent, the "
        "bounding box of the markers (and of the mesh) is used.",
    )
    mesh: str | None = Field(
        default=None,
        description="Mesh file (STL, OBJ, PLY...) relative to the layout file, in 'units'.",
    )
    first_id: StrictInt | None = Field(
        default=None, ge=0, description="First ArUco id of the block (null with no codes)."
    )
    ids_per_instance: StrictInt | None = Field(
        default=None, ge=1, description="Ids (slots) per brick instance (null with no codes)."
    )
    instances: StrictInt | None = Field(
        default=None, ge=1, description="Number of brick instances the block covers "
        "(null with no codes)."
    )
    symmetry: Literal["none", "rot180_z"] = Field(
        default="none",
        description="'rot180_z' when a half-turn about z maps the markers onto themselves "
        "(yaw then is ambiguous by 180 deg).",
    )
    colors: dict[str, ColorSpec] | None = Field(
        default=None, description="Dot colours overriding/adding to the default palette."
    )
    markers: list[Marker] = Field(min_length=1, max_length=LIMITS.max_markers,
                                  description="The markers on the brick (at most "
                                  f"{LIMITS.max_markers}).")

    _source: Path | None = PrivateAttr(default=None)

    def __eq__(self, other: object) -> bool:
        """Equal content (the source file does not matter)."""
        if not isinstance(other, MarkerLayout):
            return NotImplemented
        return self.model_dump() == other.model_dump()

    __hash__ = None  # type: ignore[assignment]

    # ---- validation -------------------------------------------------------------------

    @field_validator("mesh")
    @classmethod
    def _check_mesh(cls, v: str | None) -> str | None:
        if v is not None:
            if not v.strip():
                raise ValueError("mesh path is empty; give a path relative to the layout "
                                 "file or null")
            if Path(v).is_absolute() or v.startswith(("/", "\\")) or ":" in v[:3]:
                raise ValueError(f"mesh path {v!r} is absolute; give it relative to the "
                                 "layout file, e.g. 'meshes/drick.stl'")
        return v

    @field_validator("name")
    @classmethod
    def _check_name(cls, v: str) -> str:
        if v != v.strip():
            raise ValueError("name must not start or end with whitespace")
        return v

    @model_validator(mode="after")
    def _check_layout(self) -> MarkerLayout:
        codes = [(i, m) for i, m in enumerate(self.markers) if isinstance(m, ArucoMarker)]
        dots = [(i, m) for i, m in enumerate(self.markers) if isinstance(m, DotMarker)]
        issues = [
            *id_issues(codes, self.first_id, self.ids_per_instance, self.instances),
            *color_issues(dots, self.palette()),
            *coplanar_issues(dots, self.scale_to_m),
        ]
        # symmetry (dots decide: ArUco ids fix the orientation by themselves)
        if not issues and dots:
            issues = symmetry_issues(self.symmetry, self._dots_rot180_z_symmetric(),
                                     has_codes=bool(codes))
        if issues:
            raise LocatedIssues(issues)
        return self

    def _dots_rot180_z_symmetric(self) -> bool:
        return dots_rot180_z_symmetric(self.dot_markers(), self.dot_centers_m(),
                                       self.scale_to_m)

    # ---- units and geometry (metres) --------------------------------------------------

    @property
    def scale_to_m(self) -> float:
        """Metres per file unit (1, 0.01 or 0.001)."""
        return UNITS_TO_M[self.units]

    @property
    def dimensions_m(self) -> np.ndarray:
        """Bounding box size [x, y, z] in metres, (3,) float64: ``dimensions`` when the file
        gives them, else the bounding box of the markers and of the mesh (each side at
        least 1 mm: a flat tag still has a thickness to draw).

        Raises:
            InputError: the mesh cannot be read
                (:func:`drovisio.mesh_file.load_layout_mesh`).
        """
        if self.dimensions is not None:
            return np.array(self.dimensions, np.float64) * self.scale_to_m
        lo, hi = self._markers_bounds_m()
        mesh = self._mesh_bounds_m()
        if mesh is not None:
            lo, hi = np.minimum(lo, mesh[0]), np.maximum(hi, mesh[1])
        return np.maximum(hi - lo, 0.001)

    def _markers_bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners of the box around every code square and dot disc, metres."""
        pts = [c for c in self.code_corners_m().values()]
        lo = [p.min(axis=0) for p in pts]
        hi = [p.max(axis=0) for p in pts]
        if self.has_dots:
            centres, normals = self.dot_centers_m(), self.dot_normals()
            radii = self.dot_diameters_m() / 2
            # a disc of radius r and normal n reaches r·sqrt(1 − n_e²) along axis e
            reach = radii[:, None] * np.sqrt(np.clip(1 - normals ** 2, 0, 1))
            lo.append((centres - reach).min(axis=0))
            hi.append((centres + reach).max(axis=0))
        return np.min(lo, axis=0), np.max(hi, axis=0)

    def _mesh_bounds_m(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self.mesh is None:
            return None
        try:   # the file's identity keys the cache: an edited mesh is read again
            st = os.stat(self.mesh_path())   # type: ignore[arg-type]
            stamp: tuple[int, ...] | None = (st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size)
        except (OSError, RuntimeError, ValueError):   # nothing there: the reader says why
            stamp = None
        return _mesh_bounds(_MeshName(self.name, self.mesh, self._source, self.scale_to_m),
                            stamp)

    @property
    def source(self) -> Path | None:
        """The file this layout was loaded from (or last saved to), if any."""
        return self._source

    def code_markers(self) -> list[ArucoMarker]:
        """The ArUco markers, in file order."""
        return [m for m in self.markers if isinstance(m, ArucoMarker)]

    def _codes_by_slot(self) -> list[ArucoMarker]:
        return sorted(self.code_markers(), key=lambda m: m.id)

    def dot_markers(self) -> list[DotMarker]:
        """The dot markers, in file order (the row order of the ``dot_*`` arrays)."""
        return [m for m in self.markers if isinstance(m, DotMarker)]

    @property
    def has_codes(self) -> bool:
        """True if the layout carries ArUco codes."""
        return any(isinstance(m, ArucoMarker) for m in self.markers)

    @property
    def has_dots(self) -> bool:
        """True if the layout carries colour dots."""
        return any(isinstance(m, DotMarker) for m in self.markers)

    def code_corners_m(self) -> dict[int, np.ndarray]:
        """Corners of every code in the brick frame, in metres.

        Returns:
            ``{slot: (4, 3) float64}``, corners in OpenCV order TL, TR, BR, BL (the
            ``cv2.aruco.Board`` object-point order), ordered by slot.
        """
        s = self.scale_to_m
        return {m.id: m.corners_array() * s for m in self._codes_by_slot()}

    def code_centers_m(self) -> dict[int, np.ndarray]:
        """Centre of every code in metres: ``{slot: (3,) float64}``."""
        s = self.scale_to_m
        return {m.id: m.center_array() * s for m in self._codes_by_slot()}

    def code_normals(self) -> dict[int, np.ndarray]:
        """Unit facing direction of every code: ``{slot: (3,) float64}`` (unitless)."""
        return {m.id: m.normal_array() for m in self._codes_by_slot()}

    def code_sizes_m(self) -> dict[int, float]:
        """Outer border side of every code in metres: ``{slot: size}``."""
        return {m.id: m.size * self.scale_to_m for m in self._codes_by_slot()}

    def code_dictionaries(self) -> dict[int, str]:
        """Dictionary name of every code: ``{slot: name}``."""
        return {m.id: m.dictionary for m in self._codes_by_slot()}

    def dictionaries(self) -> list[str]:
        """Distinct dictionary names used by the codes, in first-use order."""
        return list(dict.fromkeys(m.dictionary for m in self.code_markers()))

    def dot_centers_m(self) -> np.ndarray:
        """Dot centres in the brick frame, in metres: (N, 3) float64, file order."""
        dots = self.dot_markers()
        if not dots:
            return np.zeros((0, 3), np.float64)
        return np.array([d.center for d in dots], np.float64) * self.scale_to_m

    def dot_normals(self) -> np.ndarray:
        """Unit facing direction of every dot: (N, 3) float64, file order."""
        dots = self.dot_markers()
        return np.array([d.normal_array() for d in dots], np.float64).reshape(-1, 3)

    def dot_diameters_m(self) -> np.ndarray:
        """Dot diameters in metres: (N,) float64, file order."""
        return np.array([d.diameter for d in self.dot_markers()], np.float64) * self.scale_to_m

    def dot_colors(self) -> list[str]:
        """Dot colour names, file order."""
        return [d.color for d in self.dot_markers()]

    def palette(self) -> dict[str, ColorSpec]:
        """The default palette overridden/extended by this layout's ``colors``."""
        return {**DEFAULT_PALETTE, **(self.colors or {})}

    def mesh_path(self) -> Path | None:
        """The mesh file, resolved relative to the layout file (or the working directory
        if the layout has no source file); None if the layout names no mesh. The mesh is in
        the layout's ``units``."""
        if self.mesh is None:
            return None
        base = self._source.parent if self._source is not None else Path.cwd()
        return (base / self.mesh).resolve()

    # ---- ids ----------------------------------------------------------------------------

    def id_block(self) -> range:
        """All ids the layout owns, ``first_id .. first_id + ids_per_instance*instances - 1``
        (an empty range when the layout has no codes)."""
        first, ipi, n = self.first_id, self.ids_per_instance, self.instances
        if not self.has_codes or first is None or ipi is None or n is None:
            return range(0)
        return range(first, first + ipi * n)

    def marker_id(self, instance: int, slot: int) -> int:
        """Full ArUco id of instance ``instance``'s code in slot ``slot``.

        Args:
            instance: brick instance k, ``0 <= k < instances``.
            slot: code slot s, ``0 <= s < ids_per_instance``.

        Returns:
            ``first_id + instance * ids_per_instance + slot``.

        Raises:
            ValueError: the layout has no codes, or instance/slot out of range.
        """
        if not self.has_codes:
            raise ValueError(f"layout {self.name!r} has no ArUco codes, so no ids")
        assert self.first_id is not None and self.ids_per_instance is not None
        assert self.instances is not None
        if not 0 <= instance < self.instances:
            raise ValueError(f"instance {instance} out of range 0..{self.instances - 1}")
        if not 0 <= slot < self.ids_per_instance:
            raise ValueError(f"slot {slot} out of range 0..{self.ids_per_instance - 1}")
        return self.first_id + instance * self.ids_per_instance + slot

    def instance_slot(self, marker_id: int) -> tuple[int, int] | None:
        """Which instance and slot a detected id belongs to.

        Args:
            marker_id: a full ArUco id.

        Returns:
            ``(instance, slot)``, or None when the id is outside this layout's block or
            its slot carries no code in this layout.
        """
        block = self.id_block()
        if marker_id not in block:
            return None
        assert self.ids_per_instance is not None
        instance, slot = divmod(marker_id - block.start, self.ids_per_instance)
        if slot not in {m.id for m in self.code_markers()}:
            return None
        return instance, slot

    def all_ids(self) -> list[int]:
        """Every id a code of this layout can carry, sorted (instances x used slots)."""
        if not self.has_codes:
            return []
        slots = sorted({m.id for m in self.code_markers()})
        assert self.instances is not None
        return sorted(self.marker_id(k, s) for k in range(self.instances) for s in slots)

    # ---- serialisation ----------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The layout as a JSON-ready dict in the file format (file units, nulls dropped
        for optional fields that are unset)."""
        return self.model_dump(mode="json", by_alias=True, exclude_none=True)

    def to_json(self) -> str:
        """The layout as JSON text in the file format (see
        :func:`drovisio.layout.layout_to_json`)."""
        return layout_json_text(self.to_dict())


class _MeshName(NamedTuple):
    """What names a layout's mesh (hashable, unlike the layout): a cache key and what
    :func:`drovisio.mesh_file.load_layout_mesh` reads."""

    name: str
    mesh: str | None
    source: Path | None
    scale_to_m: float


@lru_cache(maxsize=32)
def _mesh_bounds(named: _MeshName, _stamp: tuple[int, ...] | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of a layout's mesh in metres, read by the one reader of a layout's mesh (its
    refusal is the layout's: one line naming the file and the field)."""
    # deferred: trimesh is heavy, and only layouts without dimensions need it
    from drovisio.mesh_file import load_layout_mesh

    mesh = load_layout_mesh(named)
    assert mesh is not None      # the layout names a mesh
    b = np.asarray(mesh.bounds, np.float64)
    return b[0], b[1]


def layout_json_schema() -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of the layout file, generated from :class:`MarkerLayout`.

    Returns:
        A JSON-ready dict; markers are a ``oneOf`` discriminated on ``kind``. Checks that
        need the whole layout (slots, colours, coplanarity, id ranges) are not expressible
        in the schema; :func:`parse_layout` does them.
    """
    schema = MarkerLayout.model_json_schema(by_alias=True, mode="validation")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    return schema
