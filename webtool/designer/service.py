"""The marker designer's server side: the one design edited in this web tool.

:class:`DesignerService` owns the :class:`drovisio.designer.model.DesignDocument`, a lock, the
change notifications the page long-polls (without holding a worker thread: see
:meth:`DesignerService.wait_for_change_async`), and, once the page asks for it, the 3D view
(:class:`webtool.designer.scene.DesignerScene`). Both the JSON endpoint ``POST
/api/designer/click`` and the 3D view's click handler call :meth:`DesignerService.click`.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.designer.checks import Finding, apply_fix, blocking, check_design
from drovisio.designer.export import save_design
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
from drovisio.meshes import shipped_mesh
from drovisio.resources import user_data_dir
from webtool.designer.scene import DesignerScene

__all__ = ["MODE_LABELS", "DesignerService"]

MODE_LABELS = {"code": "Add codes", "dot": "Add dots", "select": "Select / move",
               "origin": "Set origin"}


def _settings_camera(settings) -> Camera | None:
    cam_path = getattr(settings, "camera", None)
    if not cam_path:
        return None
    try:
        return load_camera(cam_path)
    except Exception:  # noqa: BLE001 - the page says which camera is used
        return None


class DesignerService:
    """The one design edited in this web tool, thread-safe.

    Args:
        settings: The web tool's settings (``camera`` for the detection-distance estimate,
            the user's layouts folder, ``designer_max_upload_mb``); None: the defaults.
        layouts_dir: Where designs are saved and the user's layouts are offered (overrides
            the settings). Never the shipped ``marker_layouts/``: those are offered read-only.
        camera: The drone camera (overrides the settings).
    """

    def __init__(self, settings=None, *, layouts_dir: Path | None = None,
                 camera: Camera | None = None):
        if layouts_dir is None and settings is not None and hasattr(settings, "user_folder"):
            layouts_dir = settings.user_folder("layouts")
        camera = camera or _settings_camera(settings)
        max_upload_bytes = int(float(getattr(settings, "designer_max_upload_mb", 50.0))
                               * 1024 * 1024)
        self.layouts_dir = Path(layouts_dir) if layouts_dir else user_data_dir("layouts")
        self.camera = camera or Camera.drone_webcam()
        self.max_upload_bytes = max_upload_bytes
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.message = "Start by uploading the brick's 3D model, or open an example."
        self.notes: list[str] = []
        self.doc = DesignDocument(others=self._other_layouts())
        self._viewer: DesignerScene | None = None
        self._viewer_lock = threading.Lock()
        self._findings: tuple[int, list[Finding]] | None = None
        self._closed = False

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
        shipped = shipped_layouts_dir().resolve()
        for p in self._layout_files():
            label = (f"Start from the shipped layout '{p.stem}' (save it under a new name)"
                     if p.resolve().parent == shipped else f"Edit your layout '{p.stem}'")
            out.append({"id": f"layout:{p.name}", "label": label})
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

    async def wait_for_change_async(self, after_version: int, timeout: float) -> None:
        """:meth:`wait_for_change` for a request handler: the page's long poll must not hold
        one of the server's worker threads (sixty open pages would stall every request)."""
        deadline = time.monotonic() + max(0.0, timeout)
        while (self.doc.version == after_version and not self._closed
               and time.monotonic() < deadline):
            await asyncio.sleep(0.05)

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
        with self.lock:
            shipped = shipped_layouts_dir()
            if self.layouts_dir.resolve() == shipped.resolve():
                raise DesignError(f"{shipped} holds the layouts shipped with Drovisio and is "
                                  "read-only: start the tool with another --data folder")
            if (shipped / f"{self.doc.name}.json").exists():
                raise DesignError(f"'{self.doc.name}' is the name of a shipped layout: choose "
                                  "another name")
            try:
                self.layouts_dir.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise DesignError(f"cannot create the layouts folder {self.layouts_dir}: "
                                  f"{e.strerror or e}; start the tool with another --data "
                                  "folder") from None
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
                "palette": [{"name": n, "rgb": list(doc.palette()[n].display_rgb())}
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
            out["mesh"] = _mesh_json(doc)
            out["ids"] = _ids_json(doc)
            out["layout"] = {"name": doc.name, "description": doc.description or "",
                             "symmetry": doc.symmetry}
            out["markers"] = _markers_json(doc)
            return out

    # ---------------------------------------------------------------- viewer

    def viewer(self) -> DesignerScene:
        """The 3D viewer, started on first use."""
        with self._viewer_lock:
            if self._closed:
                raise DesignError("the designer is shutting down")
            if self._viewer is None:
                v = DesignerScene(self)
                v.start()
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


def _mesh_json(doc: DesignDocument) -> dict[str, Any]:
    """The loaded mesh: name, units, size (mm), triangles, flat faces, brick_from_mesh (4×4)."""
    dims = doc.dimensions()
    B = doc.brick_from_mesh
    return {
        "name": doc.mesh_name, "units": doc.units, "units_guessed": doc.units_guessed,
        "size_mm": [round(float(d) * 1000, 1) for d in dims],
        "triangles": int(len(doc.mesh.faces)), "flat_faces": len(doc.faces),
        "brick_from_mesh": [[round(float(v), 9) for v in row] for row in B],
        "frame_is_file_frame": bool(np.allclose(B, np.eye(4))),
        "source_layout": str(doc.source_layout) if doc.source_layout else None,
    }


def _ids_json(doc: DesignDocument) -> dict[str, Any]:
    """The code ids: first id, ids per instance, instances, family, dictionary, id block."""
    block = doc.id_block()
    return {
        "first_id": doc.effective_first_id() if doc.codes() else doc.first_id,
        "first_id_auto": doc.first_id is None,
        "ids_per_instance": doc.effective_ids_per_instance(),
        "ipi_auto": doc.ids_per_instance is None,
        "instances": doc.instances, "family": doc.code_family,
        "dictionary": doc.dictionary(),
        "block": [block.start, block.stop - 1] if block else None,
    }


def _markers_json(doc: DesignDocument) -> list[dict[str, Any]]:
    """Every marker in the brick frame: kind, label, size and centre (mm), normal; a code's
    slot and id, a dot's colour."""
    first = doc.effective_first_id() if doc.codes() else 0
    out = []
    for i, m in enumerate(doc.brick_markers()):
        item: dict[str, Any] = {"index": i, "kind": m.kind, "label": doc.marker_label(i),
                                "size_mm": round(m.size * 1000, 3),
                                "center_mm": [round(v * 1000, 2) + 0.0 for v in m.center],
                                "normal": [round(v, 4) + 0.0 for v in m.normal],
                                "on_face": doc.markers[i].face is not None}
        if m.kind == "aruco" and m.slot is not None:
            item["slot"] = m.slot
            item["id"] = first + m.slot
        elif m.color is not None:
            item["color"] = m.color
            item["rgb"] = list(doc.palette()[m.color].display_rgb())
        out.append(item)
    return out
