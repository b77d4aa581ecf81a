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

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from drovisio.designer.model.codes import family_dictionaries
from drovisio.designer.model.edits import (
    KEEP,
    check_colour,
    check_defaults,
    check_layout_numbers,
    check_name,
    check_size,
    check_slot,
    check_symmetry_and_family,
)
from drovisio.designer.model.errors import DesignError
from drovisio.designer.model.frame import (
    brick_axes_in_mesh,
    brick_from_axes,
    in_plane_x,
    longest_edge_direction,
    t3,
    turned,
    unit,
)
from drovisio.designer.model.marker import DesignMarker
from drovisio.designer.model.meshfile import UNITS
from drovisio.designer.model.modes import MODES, ClickResult
from drovisio.designer.model.state import DesignState
from drovisio.designer.raycast import FlatFace, RayHit, cast_ray
from drovisio.geometry import rot_x, rot_z, so3_exp
from drovisio.layout import SCHEMA_ID, UNITS_TO_M

__all__ = ["DesignDocument"]


class DesignDocument(DesignState):
    """An editable marker design (see the module docstring): the brick frame, units,
    marker and layout-field edits, each undoable, and the layout data they make.

    Attributes set by the caller: ``others`` (layouts whose ids must not be reused, e.g. the
    shipped ones) and ``colors`` (dot colours added to the default palette).
    """

    # ------------------------------------------------------------------ frame

    def set_origin_on_face(self, face: int) -> None:
        """Put the brick origin at the centre of a flat face, z along its outward normal
        (x: the current x axis laid on the face)."""
        f = self.faces.faces[face]
        self._push()
        self.brick_from_mesh = brick_from_axes(self.faces.centre(f),
                                               in_plane_x(self.brick_from_mesh, f.normal),
                                               f.normal)
        self._changed()

    def origin_to_top_centre(self) -> None:
        """Origin at the centre of the brick's bounding box in x and y, on its top (max z)."""
        V = self.to_brick(self.mesh.vertices)
        lo, hi = V.min(axis=0), V.max(axis=0)
        target_b = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]])
        self._push()
        axes = brick_axes_in_mesh(self.brick_from_mesh)
        origin_m = self.mesh_from_brick[:3, :3] @ target_b + self.mesh_from_brick[:3, 3]
        self.brick_from_mesh = brick_from_axes(origin_m, axes[:, 0], axes[:, 2])
        self._changed()

    def longest_edge_direction(self) -> np.ndarray | None:
        """Brick-frame direction (unit, in the xy plane) of the mesh's longest *feature* edge
        (between two faces meeting at an angle; triangulation diagonals inside a flat face do
        not count) that is perpendicular to z (within 1 deg), or None."""
        return longest_edge_direction(self.mesh, self.brick_from_mesh)

    def align_x_with_longest_edge(self) -> bool:
        """Turn the brick frame about z so that x runs along the longest horizontal edge.
        Returns False when the mesh has no edge perpendicular to z."""
        v = self.longest_edge_direction()
        if v is None:
            return False
        self._push()
        angle = math.atan2(v[1], v[0])
        self.brick_from_mesh = turned(self.brick_from_mesh, rot_z(angle))
        self._changed()
        return True

    def turn_frame(self, angle_deg: float = 90.0) -> None:
        """Turn the brick's x and y axes about z by ``angle_deg``."""
        self._push()
        self.brick_from_mesh = turned(self.brick_from_mesh, rot_z(math.radians(angle_deg)))
        self._changed()

    def flip_frame(self) -> None:
        """Turn the brick frame upside down (half-turn about x: z and y reverse)."""
        self._push()
        self.brick_from_mesh = turned(self.brick_from_mesh, rot_x(math.pi))
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
        self.markers = [replace(m, center=t3(m.c * k)) for m in self.markers]
        B = self.brick_from_mesh.copy()
        B[:3, 3] *= k
        self.brick_from_mesh = B
        self.units = units
        self.units_guessed = False
        self._mesh_changed()

    # ------------------------------------------------------------------ placing

    def _face_axes(self, face: FlatFace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centre, right, up) of a face's grid (mesh frame)."""
        up = self._default_up(face.normal)
        return self.faces.centre(face), np.cross(up, face.normal), up

    def snap(self, face: FlatFace, point: ArrayLike) -> np.ndarray:
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

    def hit(self, origin: ArrayLike, direction: ArrayLike, world_from_mesh: np.ndarray | None = None
            ) -> RayHit | None:
        """Cast a world-frame click ray on the mesh drawn with pose ``world_from_mesh``
        (default: the brick frame is the world, i.e. ``brick_from_mesh``)."""
        pose = self.brick_from_mesh if world_from_mesh is None else world_from_mesh
        return cast_ray(self.mesh, origin, direction, pose)

    def click(self, origin: ArrayLike, direction: ArrayLike, world_from_mesh: np.ndarray | None = None
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
                                         "face, z pointing out of it.", point=t3(h.point))
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

    def marker_at(self, point: ArrayLike) -> int | None:
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

    def add_marker(self, kind: str, face: int, point: ArrayLike, size: float | None = None,
                   color: str | None = None, snap: bool = True) -> int:
        """Add a code or a dot on a flat face at a point (mesh frame, snapped unless
        ``snap`` is False). Returns its index; it becomes the selection."""
        if kind not in ("aruco", "dot"):
            raise DesignError(f"unknown marker kind {kind!r}")
        f = self.faces.faces[face]
        p = self.snap(f, point) if snap else np.asarray(point, np.float64)
        up = self._default_up(f.normal)
        if kind == "aruco":
            m = DesignMarker("aruco", t3(p), t3(f.normal), t3(up),
                             float(size or self.code_size), slot=self._next_slot(), face=face)
        else:
            colour = color or self.dot_color
            check_colour(colour, self.palette())
            m = DesignMarker("dot", t3(p), t3(f.normal), t3(up),
                             float(size or self.dot_diameter), color=colour, face=face)
        # recorded for undo only once the marker is valid: a refused one leaves no step
        self._push()
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

    def move_marker(self, index: int, origin: ArrayLike, direction: ArrayLike,
                    world_from_mesh: np.ndarray | None = None,
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
        self.markers[index] = replace(m, center=t3(p), normal=t3(f.normal), up=t3(up),
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
        self.markers[index] = replace(m, center=t3(p))
        self._changed()

    def centre_marker(self, index: int) -> None:
        """Move a marker to the centre of its face."""
        m = self._check_index(index)
        if m.face is None:
            raise DesignError(f"{self.marker_label(index)} is not on a face of the model: "
                              "move it onto the model first")
        self._push()
        c = self.faces.centre(self.faces.faces[m.face])
        self.markers[index] = replace(m, center=t3(c))
        self._changed()

    def rotate_marker(self, index: int, angle_deg: float) -> None:
        """Turn a code about its normal by ``angle_deg`` (counter-clockwise seen from the
        front)."""
        m = self._check_index(index)
        self._push()
        R = so3_exp(unit(m.n) * math.radians(angle_deg))
        up = R @ m.u
        up[np.abs(up) < 1e-12] = 0.0
        self.markers[index] = replace(m, up=t3(unit(up)))
        self._changed()

    def set_marker(self, index: int, *, size: float | None = None, color: str | None = None,
                   slot: int | None = None) -> None:
        """Change a marker's size (code side / dot diameter, metres), colour (dots) or slot
        (codes; a slot already used by another code is swapped with it)."""
        m = self._check_index(index)
        changes = self._marker_changes(m, size, color, slot)
        if not changes:
            return
        swap = None
        if slot is not None:
            swap = next((i for i, o in self.codes() if o.slot == slot and i != index), None)
        self._push()
        if swap is not None:
            self.markers[swap] = replace(self.markers[swap], slot=m.slot)
        self.markers[index] = replace(m, **changes)
        self._changed()

    def _marker_changes(self, m: DesignMarker, size: float | None, color: str | None,
                        slot: int | None) -> dict[str, Any]:
        """The checked field changes :meth:`set_marker` makes to ``m``."""
        changes: dict[str, Any] = {}
        if size is not None:
            changes["size"] = check_size(size)
        if color is not None:
            if m.kind != "dot":
                raise DesignError("only dots have a colour")
            check_colour(color, self.palette())
            changes["color"] = color
        if slot is not None:
            if m.kind != "aruco":
                raise DesignError("only codes have a slot")
            changes["slot"] = check_slot(slot)
        return changes

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
        check_defaults(code_size=code_size, dot_diameter=dot_diameter, dot_color=dot_color,
                       grid=grid, snap_radius=snap_radius, palette=self.palette())
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
            name = check_name(name)
        check_layout_numbers(first_id, ids_per_instance, instances)
        check_symmetry_and_family(symmetry, code_family)
        self._push()
        if name is not None:
            self.name = name
        if description is not None:
            self.description = description.strip() or None
        if first_id != KEEP:
            self.first_id = first_id  # type: ignore[assignment]
        if ids_per_instance != KEEP:
            self.ids_per_instance = ids_per_instance  # type: ignore[assignment]
        if instances is not None:
            self.instances = instances
        if symmetry is not None:
            self.symmetry = symmetry
        if code_family is not None:
            self.code_family = code_family
        self._changed()

    # ------------------------------------------------------------------ layout

    def layout_data(self, mesh_ref: str | None = None) -> dict[str, Any]:
        """The design as layout-file data (brick frame, metres), not yet validated: send
        it through :func:`drovisio.layout.parse_layout` (see :mod:`drovisio.designer.export`).

        Args:
            mesh_ref: the ``mesh`` field (path relative to the layout file), or None.
        """
        dictionary = self.dictionary() or family_dictionaries(self.code_family)[-1]
        markers = [_marker_data(m, dictionary) for m in self.brick_markers()]
        dims = [max(float(round(d, 6)), 1e-6) for d in self.dimensions()]
        data: dict[str, Any] = {
            "schema": SCHEMA_ID,
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

def _rounded(v: Any, nd: int = 7) -> list[float]:
    """A vector as a list of floats rounded to ``nd`` decimals (no negative zero)."""
    return [float(round(float(x), nd)) + 0.0 for x in np.ravel(v)]


def _marker_data(m: DesignMarker, dictionary: str) -> dict[str, Any]:
    """One marker (brick frame, metres) as a layout file's marker entry."""
    if m.kind == "aruco":
        return {"kind": "aruco", "dictionary": dictionary, "id": m.slot,
                "size": float(round(m.size, 7)), "center": _rounded(m.center),
                "normal": _rounded(unit(m.normal), 9), "up": _rounded(unit(m.up), 9)}
    return {"kind": "dot", "color": m.color,
            "diameter": float(round(m.size, 7)), "center": _rounded(m.center),
            "normal": _rounded(unit(m.normal), 9)}
