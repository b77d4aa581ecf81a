"""The marker designer's 3D view (viser): the brick's mesh, its axes and the markers.

:class:`DesignerScene` is a :class:`webtool.viewer.scene.ViserScene` (127.0.0.1, own port,
started when the page asks for it, stopped with the app; browsers reach it through the app at
``/designer/3d/``, under the access token) that shows the mesh, the brick axes and the markers
(codes with their real pattern as a texture, dots in their colour). The controls are the
page's own (one set): viser's panel stays empty and folded.

Clicks: viser reports a click on the mesh as a world-frame ray. The world frame of the scene
is the brick frame; the mesh is drawn under a frame node posed ``brick_from_mesh``, so the
click handler casts the ray with that pose undone (:meth:`DesignDocument.click`). The JSON
endpoint ``POST /api/designer/click`` calls the very same :meth:`DesignerService.click`.
Markers can be dragged over the model (the drag ray goes from the viewer's camera through
the pointer) and clicked to select them.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from drovisio.designer.export import code_image_rgb
from drovisio.designer.model import (
    DesignDocument,
    DesignError,
)
from webtool.viewer.scene import ViserScene

__all__ = ["DesignerScene", "DesignSession"]


class DesignSession(Protocol):
    """What the 3D view needs of the design it shows (the designer's service): the document,
    the page's message, and where clicks and drags go."""

    doc: DesignDocument
    message: str

    def click(self, origin: Any, direction: Any) -> Any: ...

    def marker_clicked(self, index: int, origin: Any, direction: Any) -> None: ...

    def drag_marker(self, index: int, phase: str, origin: Any, direction: Any) -> None: ...


class DesignerScene(ViserScene):
    """The viser server and scene of the designer (see the module docstring)."""

    label = "Drovisio marker designer"
    up = "+z"

    def __init__(self, session: DesignSession):
        super().__init__()
        self.session = session
        self._mesh_version = -1
        self._marker_handles: list = []
        self._marker_keys: list = []
        self._extra_handles: list = []
        self.mesh_handle = None
        self.axes = None

    def setup(self) -> None:
        self.model = self.server.scene.add_frame("/model", show_axes=False)

    # ---- scene

    def sync(self, session: DesignSession) -> None:
        """Bring the scene in line with the document (called under the
        session lock after every change)."""
        doc = session.doc
        if doc.mesh_version != self._mesh_version:
            self._mesh_version = doc.mesh_version
            self._rebuild_mesh(doc)
        B = doc.brick_from_mesh
        from viser import transforms as vtf  # deferred: viser loads with the 3D view

        self.model.wxyz = vtf.SO3.from_matrix(B[:3, :3]).wxyz
        self.model.position = tuple(float(v) for v in B[:3, 3])
        self._sync_markers(doc)

    def _rebuild_mesh(self, doc: DesignDocument) -> None:
        scene = self.server.scene
        for h in self._extra_handles:
            h.remove()
        self._extra_handles = []
        if self.mesh_handle is not None:
            self.mesh_handle.remove()
            self.mesh_handle = None
        if not doc.has_mesh:
            return
        mesh = doc.mesh
        handle = self.mesh_handle = scene.add_mesh_simple(
            "/model/mesh", np.asarray(mesh.vertices, np.float32),
            np.asarray(mesh.faces, np.uint32), color=(178, 182, 190), flat_shading=True,
            side="double")

        @handle.on_click
        def _(event) -> None:
            try:
                self.session.click(event.ray_origin, event.ray_direction)
            except DesignError as e:
                self.session.message = str(e)

        size = float(np.max(doc.dimensions()))
        self.axes = scene.add_frame("/brick_axes", axes_length=0.35 * size,
                                    axes_radius=0.008 * size, origin_radius=0.015 * size)
        self._extra_handles.append(self.axes)
        V = doc.to_brick(mesh.vertices)
        zmin = float(V[:, 2].min())
        step = 10 ** math.floor(math.log10(max(size, 1e-6)) - 1)
        self._extra_handles.append(scene.add_grid(
            "/ground", width=2.5 * size, height=2.5 * size, cell_size=step,
            section_size=10 * step,
            position=(0.0, 0.0, zmin - 1e-4)))
        centre = (V.max(axis=0) + V.min(axis=0)) / 2
        eye = centre + np.array([0.45, -0.85, 0.95]) * size
        self.server.initial_camera.position = tuple(float(v) for v in eye)
        self.server.initial_camera.look_at = tuple(float(v) for v in centre)
        for client in self.server.get_clients().values():
            client.camera.position = tuple(float(v) for v in eye)
            client.camera.look_at = tuple(float(v) for v in centre)

    def _sync_markers(self, doc: DesignDocument) -> None:
        """Add, replace or remove only the marker nodes whose marker changed."""
        dictionary = doc.dictionary()
        first = doc.effective_first_id() if doc.codes() else 0
        keys = [(m, dictionary, first, doc.selected == i, doc.marker_label(i))
                for i, m in enumerate(doc.markers)]
        for i in range(len(keys), len(self._marker_keys)):
            for h in self._marker_handles[i]:
                h.remove()
        del self._marker_handles[len(keys):]
        del self._marker_keys[len(keys):]
        pal = doc.palette()
        for i, key in enumerate(keys):
            if i < len(self._marker_keys) and self._marker_keys[i] == key:
                continue
            if i < len(self._marker_handles):
                for h in self._marker_handles[i]:
                    h.remove()
            handles = self._marker_nodes(i, doc.markers[i], dictionary, first, key[3], key[4],
                                         pal)
            if i < len(self._marker_keys):
                self._marker_keys[i], self._marker_handles[i] = key, handles
            else:
                self._marker_keys.append(key)
                self._marker_handles.append(handles)

    def _marker_nodes(self, i: int, m, dictionary, first: int, selected: bool, label: str,
                      pal) -> list:
        from viser import transforms as vtf  # deferred: viser loads with the 3D view

        scene = self.server.scene
        lift = 0.0006
        name = f"/model/markers/m{i}"
        out = []
        if m.kind == "aruco" and dictionary is not None:
            R = np.stack([m.r, -m.u, -m.n], axis=1)
            k = 0.5  # half a cell of white paper around the code
            img = code_image_rgb(dictionary, first + m.slot, 16, margin_cells=k)
            if selected:
                img = img.copy()
                w = max(2, img.shape[0] // 40)
                orange = (255, 140, 0)
                img[:w], img[-w:], img[:, :w], img[:, -w:] = orange, orange, orange, orange
            cells = img.shape[0] / 16 - 2 * k
            side = m.size * (cells + 2 * k) / cells
            h = scene.add_image(name, img, render_width=side, render_height=side,
                                wxyz=vtf.SO3.from_matrix(R).wxyz,
                                position=tuple(m.c + m.n * lift))
        else:
            seg = 40
            ang = np.linspace(0, 2 * np.pi, seg, endpoint=False)
            rad = m.size / 2
            ring = np.outer(np.cos(ang), m.r) * rad + np.outer(np.sin(ang), m.u) * rad
            V = np.vstack([[0, 0, 0], ring]) + m.c + m.n * lift
            F = np.array([[0, 1 + j, 1 + (j + 1) % seg] for j in range(seg)])
            color = pal[m.color].display_rgb() if m.color in pal else (200, 40, 40)
            h = scene.add_mesh_simple(name, V.astype(np.float32), F.astype(np.uint32),
                                      color=color, side="double")
            if selected:
                ring2 = ring * 1.25 + m.c + m.n * lift * 0.5
                pts = np.stack([ring2, np.roll(ring2, -1, axis=0)], axis=1)
                out.append(scene.add_line_segments(
                    f"/model/markers/sel{i}", pts.astype(np.float32), colors=(255, 140, 0),
                    thickness=3.0, thickness_units="screen"))
        self._attach(h, i)
        out.append(h)
        out.append(scene.add_label(f"/model/markers/label{i}", label,
                                   position=tuple(m.c + m.n * (m.size * 0.3 + 0.002)),
                                   font_screen_scale=0.7))
        return out

    def _attach(self, handle, index: int) -> None:
        @handle.on_click
        def _(event) -> None:
            try:
                self.session.marker_clicked(index, event.ray_origin, event.ray_direction)
            except DesignError as e:
                self.session.message = str(e)

        @handle.on_drag
        def _(event) -> None:
            cam = np.asarray(event.client.camera.position, np.float64)
            target = np.asarray(event.end_position, np.float64)
            self.session.drag_marker(index, event.phase, cam, target - cam)

    def close(self) -> None:
        self.stop()

