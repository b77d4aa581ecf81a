"""The marker designer's session (one design per web tool) and its 3D view in viser.

:class:`DesignerSession` owns the :class:`drovisio.designer.model.DesignDocument`, a lock, the
change notifications the page long-polls, and, once the page asks for it, a
:class:`DesignerViewer`: a viser server of its own (own port on 127.0.0.1, started lazily,
stopped with the app; browsers reach it through the app at ``/designer/3d/``, under the
access token) that shows the mesh, the brick axes and the markers (codes with their real pattern as a
texture, dots in their colour) and carries a small panel (what a click does, undo/redo, the
selected marker, the checks).

Clicks: viser reports a click on the mesh as a world-frame ray. The world frame of the scene
is the brick frame; the mesh is drawn under a frame node posed ``brick_from_mesh``, so the
click handler casts the ray with that pose undone (:meth:`DesignDocument.click`). The JSON
endpoint ``POST /api/designer/click`` calls the very same :meth:`DesignerSession.click`.
Markers can be dragged over the model (the drag ray goes from the viewer's camera through
the pointer) and clicked to select them.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.designer.checks import Finding, apply_fix, blocking, check_design
from drovisio.designer.model import (
    MODES,
    ClickResult,
    DesignDocument,
    DesignError,
    code_families,
)
from drovisio.layout import (
    LayoutError,
    MarkerLayout,
    list_shipped_layouts,
    load_layout,
    shipped_layouts_dir,
)

__all__ = ["DesignerSession", "DesignerViewer", "viewer_url"]

MODE_LABELS = {"code": "Add codes", "dot": "Add dots", "select": "Select / move",
               "origin": "Set origin"}
_LABEL_MODES = {v: k for k, v in MODE_LABELS.items()}


def viewer_url(request_host: str | None, port: int, scheme: str = "http") -> str:
    """The URL of the viser viewer as seen by the browser that asked: the host the page was
    reached at (never 127.0.0.1 unless the page was), on the viewer's port."""
    host = request_host or "127.0.0.1"
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"
    return f"{scheme}://{host}:{port}/"


def _rgb(palette, color: str) -> tuple[int, int, int]:
    b, g, r = palette[color].display_bgr()
    return int(r), int(g), int(b)


class DesignerSession:
    """The one design edited in this web tool, thread-safe.

    Args:
        layouts_dir: where designs are saved and existing layouts are offered.
        camera: the drone camera used for the detection-distance estimate.
        viewer_host: the interface the viser viewer listens on.
    """

    def __init__(self, layouts_dir: Path | None = None, camera: Camera | None = None,
                 viewer_host: str = "127.0.0.1", max_upload_bytes: int = 50 << 20):
        self.layouts_dir = Path(layouts_dir) if layouts_dir else shipped_layouts_dir()
        self.camera = camera or Camera.drone_webcam()
        self.viewer_host = viewer_host
        self.max_upload_bytes = max_upload_bytes
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.message = "Start by uploading the brick's 3D model, or open an example."
        self.notes: list[str] = []
        self.doc = DesignDocument(others=self._other_layouts())
        self._viewer: DesignerViewer | None = None
        self._viewer_lock = threading.Lock()
        self._findings: tuple[int, list[Finding]] | None = None
        self._closed = False

    @classmethod
    def from_settings(cls, settings) -> DesignerSession:
        camera = None
        cam_path = getattr(settings, "camera", None)
        if cam_path:
            try:
                camera = load_camera(cam_path)
            except Exception:  # the page says which camera is used
                camera = None
        mb = float(getattr(settings, "designer_max_upload_mb", 50.0))
        return cls(layouts_dir=getattr(settings, "designer_layouts_dir", None), camera=camera,
                   # the app proxies the viewer (/designer/3d), so that the token covers it
                   viewer_host="127.0.0.1",
                   max_upload_bytes=int(mb * 1024 * 1024))

    # ---------------------------------------------------------------- layouts

    def _layout_files(self) -> list[Path]:
        files = {p.resolve(): p for p in list_shipped_layouts()}
        if self.layouts_dir.is_dir():
            for p in sorted(self.layouts_dir.glob("*.json")):
                files.setdefault(p.resolve(), p)
        return sorted(files.values(), key=lambda p: p.name)

    def _other_layouts(self) -> list[MarkerLayout]:
        out, notes = [], []
        for p in self._layout_files():
            try:
                out.append(load_layout(p))
            except LayoutError as e:
                notes.append(f"{p.name} was skipped (not a valid layout): "
                             f"{str(e).splitlines()[0]}")
        self.notes = notes
        return out

    def examples(self) -> list[dict[str, str]]:
        out = [{"id": "mesh:drick.stl", "label": "Drick brick - 3D model only (no markers)"},
               {"id": "mesh:landing-pad.stl", "label": "Landing pad - 3D model only"}]
        for p in self._layout_files():
            out.append({"id": f"layout:{p.name}", "label": f"Edit the layout '{p.stem}'"})
        return out

    # ---------------------------------------------------------------- changes

    def _after_change(self) -> None:
        self._findings = None
        self.changed.notify_all()
        viewer = self._viewer
        if viewer is not None:
            try:
                viewer.sync(self)
            except Exception as e:  # the 3D view must never break an edit
                self.message = f"(3D view not updated: {e})"

    def edit(self, fn: Callable[[DesignDocument], Any], message: str | None = None) -> Any:
        """Run ``fn(doc)`` under the lock, then notify the page and the 3D view."""
        with self.lock:
            try:
                result = fn(self.doc)
            finally:
                self._after_change()
            if message is not None:
                self.message = message
            return result

    def replace_doc(self, doc: DesignDocument, message: str) -> None:
        with self.lock:
            doc.version = self.doc.version + 1
            doc.mesh_version = self.doc.mesh_version + 1
            self.doc = doc
            self.message = message
            self._after_change()

    def wait_for_change(self, after_version: int, timeout: float) -> None:
        """Block until the document's version differs from ``after_version`` (or timeout)."""
        with self.changed:
            self.changed.wait_for(lambda: self.doc.version != after_version or self._closed,
                                  timeout=max(0.0, timeout))

    def findings(self) -> list[Finding]:
        with self.lock:
            if self._findings is None or self._findings[0] != self.doc.version:
                self._findings = (self.doc.version, check_design(self.doc, self.camera))
            return self._findings[1]

    # ---------------------------------------------------------------- actions

    def load_mesh(self, data: bytes, filename: str, units: str = "auto") -> None:
        doc = DesignDocument.from_mesh_bytes(data, filename, units, others=self._other_layouts())
        self.replace_doc(doc, f"Loaded {doc.mesh_name}. Now click on the model to add markers.")

    def open_example(self, example: str) -> None:
        kind, _, name = example.partition(":")
        if kind == "mesh":
            from drovisio.meshes import shipped_mesh

            mesh = shipped_mesh(name)
            if mesh is None:
                raise DesignError(f"no example model called {name!r}")
            doc = DesignDocument.from_mesh(mesh, name, "m", others=self._other_layouts())
            self.replace_doc(doc, f"Opened the example model {name}. Click on it to add "
                                  "markers.")
        elif kind == "layout":
            path = next((p for p in self._layout_files() if p.name == name), None)
            if path is None:
                raise DesignError(f"no layout file called {name!r}")
            try:
                layout = load_layout(path)
            except LayoutError as e:
                raise DesignError(str(e)) from None
            doc = DesignDocument.from_layout(layout, others=self._other_layouts())
            doc.mode = "select"
            self.replace_doc(doc, f"Opened the layout {path.name}. Saving it under the same "
                                  "name needs 'Replace existing files'.")
        else:
            raise DesignError(f"unknown example {example!r}")

    def click(self, origin, direction) -> ClickResult:
        """A click ray from the 3D view (world = brick frame): the viser callback and
        ``POST /api/designer/click`` both come here."""
        o = np.asarray(origin, np.float64).reshape(-1)
        d = np.asarray(direction, np.float64).reshape(-1)
        if o.shape != (3,) or d.shape != (3,) or not (np.all(np.isfinite(o))
                                                      and np.all(np.isfinite(d))):
            raise DesignError("a click needs an origin and a direction of 3 numbers each")
        with self.lock:
            res = self.doc.click(o, d)
            self.message = res.message
            self._after_change()
            return res

    def marker_clicked(self, index: int, origin, direction) -> None:
        """A click on a marker node: select it in 'select' mode, else a click on the model."""
        with self.lock:
            if self.doc.mode == "select" and 0 <= index < len(self.doc.markers):
                self.doc.select(index)
                self.message = f"Selected {self.doc.marker_label(index)}."
                self._after_change()
                return
        self.click(origin, direction)

    def drag_marker(self, index: int, phase: str, origin, direction) -> None:
        with self.lock:
            doc = self.doc
            if not 0 <= index < len(doc.markers):
                return
            if phase == "start":
                doc.checkpoint()
                doc.select(index)
            moved = doc.move_marker(index, origin, direction, record=False)
            if phase == "end":
                self.message = (f"Moved {doc.marker_label(index)}." if moved else
                                "Drop markers on the model.")
            self._after_change()

    def apply_fix(self, action: dict) -> None:
        self.edit(lambda doc: apply_fix(doc, action), "Fixed.")

    def save(self, overwrite: bool = False):
        from drovisio.designer.export import save_design

        with self.lock:
            if not self.layouts_dir.is_dir():
                raise DesignError(f"the layouts folder {self.layouts_dir} does not exist: "
                                  "create it or start the tool with another folder")
            saved = save_design(self.doc, self.layouts_dir, overwrite=overwrite)
            self.doc.others = [o for o in self._other_layouts()]
            self.doc.source_layout = saved.layout_path
            self.message = (f"Saved {saved.layout_path.name} and meshes/{saved.mesh_path.name} "
                            f"in {self.layouts_dir}.")
            self.doc.version += 1
            self._after_change()
            return saved

    # ---------------------------------------------------------------- state

    def state(self) -> dict:
        """Everything the page shows, as JSON-ready data (lengths in mm for people)."""
        with self.lock:
            doc = self.doc
            findings = self.findings()
            out: dict[str, Any] = {
                "version": doc.version,
                "message": self.message,
                "notes": list(self.notes),
                "mode": doc.mode,
                "modes": [{"id": m, "label": MODE_LABELS[m]} for m in MODES],
                "can_undo": doc.can_undo,
                "can_redo": doc.can_redo,
                "layouts_dir": str(self.layouts_dir),
                "max_upload_mb": round(self.max_upload_bytes / (1024 * 1024), 1),
                "camera": f"{self.camera.name} ({self.camera.width}x{self.camera.height}, "
                          f"fx {self.camera.fx:.0f} px)",
                "examples": self.examples(),
                "families": [{"id": f, "label": lab} for f, lab in code_families()],
                "palette": [{"name": n, "rgb": list(_rgb(doc.palette(), n))}
                            for n in doc.palette()],
                "defaults": {"code_size_mm": round(doc.code_size * 1000, 3),
                             "dot_diameter_mm": round(doc.dot_diameter * 1000, 3),
                             "dot_color": doc.dot_color,
                             "grid_mm": round(doc.grid * 1000, 3),
                             "snap_mm": round(doc.snap_radius * 1000, 3)},
                "checks": [f.to_json() for f in findings],
                "can_export": doc.has_mesh and not blocking(findings),
                "viewer_port": self._viewer.port if self._viewer is not None else None,
                "mesh": None,
                "markers": [],
                "selected": doc.selected,
            }
            if not doc.has_mesh:
                return out
            dims = doc.dimensions()
            B = doc.brick_from_mesh
            out["mesh"] = {
                "name": doc.mesh_name, "units": doc.units, "units_guessed": doc.units_guessed,
                "size_mm": [round(float(d) * 1000, 1) for d in dims],
                "triangles": int(len(doc.mesh.faces)), "flat_faces": len(doc.faces),
                "brick_from_mesh": [[round(float(v), 9) for v in row] for row in B],
                "frame_is_file_frame": bool(np.allclose(B, np.eye(4))),
                "source_layout": str(doc.source_layout) if doc.source_layout else None,
            }
            block = doc.id_block()
            out["ids"] = {
                "first_id": doc.effective_first_id() if doc.codes() else doc.first_id,
                "first_id_auto": doc.first_id is None,
                "ids_per_instance": doc.effective_ids_per_instance(),
                "ipi_auto": doc.ids_per_instance is None,
                "instances": doc.instances, "family": doc.code_family,
                "dictionary": doc.dictionary(),
                "block": [block.start, block.stop - 1] if block else None,
            }
            out["layout"] = {"name": doc.name, "description": doc.description or "",
                             "symmetry": doc.symmetry}
            first = doc.effective_first_id() if doc.codes() else 0
            for i, m in enumerate(doc.brick_markers()):
                item = {"index": i, "kind": m.kind, "label": doc.marker_label(i),
                        "size_mm": round(m.size * 1000, 3),
                        "center_mm": [round(v * 1000, 2) + 0.0 for v in m.center],
                        "normal": [round(v, 4) + 0.0 for v in m.normal],
                        "on_face": doc.markers[i].face is not None}
                if m.kind == "aruco":
                    item["slot"] = m.slot
                    item["id"] = first + m.slot
                else:
                    item["color"] = m.color
                    item["rgb"] = list(_rgb(doc.palette(), m.color))
                out["markers"].append(item)
            return out

    # ---------------------------------------------------------------- viewer

    def viewer(self) -> DesignerViewer:
        """The 3D viewer, started on first use."""
        with self._viewer_lock:
            if self._closed:
                raise DesignError("the designer is shutting down")
            if self._viewer is None:
                v = DesignerViewer(self, self.viewer_host)
                with self.lock:
                    self._viewer = v
                    v.sync(self)
            return self._viewer

    def close(self) -> None:
        """Stop the viewer and wake long-polls (app shutdown)."""
        with self._viewer_lock:
            self._closed = True
            v, self._viewer = self._viewer, None
        with self.changed:
            self.changed.notify_all()
        if v is not None:
            v.close()


class DesignerViewer:
    """The viser server and scene of the designer (see the module docstring)."""

    def __init__(self, session: DesignerSession, host: str):
        import viser

        self.session = session
        self.server = viser.ViserServer(host=host or "127.0.0.1", port=0,
                                        label="Drovisio marker designer",
                                        verbose=False)
        self.port = int(self.server.get_port())
        self._mesh_version = -1
        self._marker_handles: list = []
        self._marker_keys: list = []
        self._extra_handles: list = []
        self._syncing = False
        self.server.scene.set_up_direction("+z")
        self.server.gui.configure_theme(control_width="small", show_share_button=False,
                                        brand_color=(11, 79, 168))
        self.model = self.server.scene.add_frame("/model", show_axes=False)
        self.mesh_handle = None
        self.axes = None
        self._build_gui()

    # ---- gui

    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.add_markdown("**Click on the model to:**")
        self.mode_buttons = gui.add_button_group("Click", [MODE_LABELS[m] for m in MODES])

        @self.mode_buttons.on_click
        def _(event) -> None:
            if event.client is None:
                return
            mode = _LABEL_MODES.get(event.target.value)
            if mode:
                self.session.edit(lambda d: d.set_mode(mode),
                                  f"A click on the model now does: {MODE_LABELS[mode]}.")

        self.mode_text = gui.add_markdown("")
        undo = gui.add_button("Undo")
        redo = gui.add_button("Redo")

        @undo.on_click
        def _(event) -> None:
            self.session.edit(lambda d: d.undo(), "Undone.")

        @redo.on_click
        def _(event) -> None:
            self.session.edit(lambda d: d.redo(), "Redone.")

        with gui.add_folder("Selected marker"):
            self.sel_text = gui.add_markdown("Nothing selected.")
            self.sel_size = gui.add_number("Size (mm)", initial_value=65.0, min=1.0,
                                           max=2000.0, step=1.0)
            turn = gui.add_button("Turn 90°")
            centre = gui.add_button("Centre on its face")
            delete = gui.add_button("Delete", color="red")

        @self.sel_size.on_update
        def _(event) -> None:
            if event.client is None or self._syncing:
                return
            i = self.session.doc.selected
            if i is not None:
                v = float(event.target.value)
                self.session.edit(lambda d: d.set_marker(i, size=v / 1000.0), "Resized.")

        def on_selected(action: str) -> Callable:
            def cb(event) -> None:
                i = self.session.doc.selected
                if i is None:
                    return
                try:
                    if action == "turn":
                        self.session.edit(lambda d: d.rotate_marker(i, 90.0), "Turned by 90°.")
                    elif action == "centre":
                        self.session.edit(lambda d: d.centre_marker(i), "Centred on its face.")
                    else:
                        self.session.edit(lambda d: d.delete_marker(i), "Deleted.")
                except DesignError as e:
                    self.session.message = str(e)
            return cb

        turn.on_click(on_selected("turn"))
        centre.on_click(on_selected("centre"))
        delete.on_click(on_selected("delete"))
        self.checks_text = gui.add_markdown("")

    # ---- scene

    def sync(self, session: DesignerSession) -> None:
        """Bring the scene and the panel in line with the document (called under the
        session lock after every change)."""
        doc = session.doc
        self._syncing = True
        try:
            if doc.mesh_version != self._mesh_version:
                self._mesh_version = doc.mesh_version
                self._rebuild_mesh(doc)
            B = doc.brick_from_mesh
            from viser import transforms as vtf

            self.model.wxyz = vtf.SO3.from_matrix(B[:3, :3]).wxyz
            self.model.position = tuple(float(v) for v in B[:3, 3])
            self._sync_markers(doc)
            self.mode_buttons.value = MODE_LABELS.get(doc.mode, MODE_LABELS["code"])
            self.mode_text.content = f"Now: **{MODE_LABELS.get(doc.mode, doc.mode)}**. " + \
                (session.message or "")
            sel = doc.selected
            if sel is not None and sel < len(doc.markers):
                m = doc.markers[sel]
                self.sel_text.content = f"**{doc.marker_label(sel)}**, {m.size * 1000:g} mm"
                self.sel_size.value = round(m.size * 1000, 3)
            else:
                self.sel_text.content = "Nothing selected (choose 'Select / move' and click a " \
                                        "marker)."
            findings = session.findings()
            n_err = sum(f.severity == "error" for f in findings)
            n_warn = sum(f.severity == "warning" for f in findings)
            if not doc.has_mesh:
                self.checks_text.content = ""
            elif n_err or n_warn:
                self.checks_text.content = (f"**Checks:** {n_err} error(s), {n_warn} warning(s): "
                                            "see 'Checks' in the page, with one-click fixes.")
            else:
                self.checks_text.content = "**Checks:** no problems." if doc.markers else ""
        finally:
            self._syncing = False

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
        self.mesh_handle = scene.add_mesh_simple(
            "/model/mesh", np.asarray(mesh.vertices, np.float32),
            np.asarray(mesh.faces, np.uint32), color=(178, 182, 190), flat_shading=True,
            side="double")

        @self.mesh_handle.on_click
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
        from viser import transforms as vtf

        from drovisio.designer.export import code_image_rgb

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
            color = _rgb(pal, m.color) if m.color in pal else (200, 40, 40)
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
        try:
            self.server.stop()
        except Exception:  # pragma: no cover - already stopped
            pass

