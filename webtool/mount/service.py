"""The camera mount page's service: the mount as tilt, pan, roll and offsets, its preview, the
mount file, and measuring it from pictures of a code lying flat.

The mount edited is, in order: the ``--mount`` file of ``drovisio serve`` (saved back to it),
the one saved earlier from this page (``mount_dir/mount.json``), the sample session's (with no
source; saved to ``mount_dir``), or a camera looking straight down. Saving writes both forms
(angles and matrix, :meth:`drovisio.mount.Mount.to_file`) through the verified atomic writer,
then reads the file back; the live view uses it from its next start.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import BinaryIO

import numpy as np

from drovisio.autopilot.blind import blind_height
from drovisio.calibration.mount import measure_from_images
from drovisio.camera_file import load_camera
from drovisio.errors import InputError
from drovisio.fileio import atomic_write_text
from drovisio.images import ImageError, decode_image
from drovisio.layout import list_shipped_layouts, load_layout
from drovisio.mount import Mount, MountAngles, down_camera_mount, ground_footprint, load_mount
from drovisio.sources import SourceState
from webtool.errors import Conflict
from webtool.mount.scene import MountScene

__all__ = ["MountService", "mount_in_use"]

MOUNT_FILE = "mount.json"
MAX_UPLOAD_BYTES = 64 * 1024 * 1024     # per picture
MAX_PICTURES = 20


def _saved_path(settings) -> Path:
    return Path(settings.user_folder("mount")) / MOUNT_FILE


def mount_in_use(settings) -> Path | None:
    """The mount saved from the page, if it still loads (for any source, the sample session's
    too; a ``--mount`` given to ``drovisio serve`` takes precedence)."""
    f = _saved_path(settings)
    if not f.is_file():
        return None
    try:
        load_mount(f)
    except InputError:
        return None
    return f


class MountService:
    """See the module doc.

    Args:
        settings: The web tool's settings (mount, mount_dir, camera, sample session).
    """

    def __init__(self, settings) -> None:
        self.settings = settings
        self._lock = threading.RLock()
        self.scene = None
        self.save_path = Path(settings.mount) if settings.mount else _saved_path(settings)
        self.loaded_from, mount = self._initial()
        self.angles = MountAngles(**mount.angles())
        self.height_m = 1.5
        self.saved = self.loaded_from == str(self.save_path)
        self._camera = None
        self._blind_layouts: list | None = None

    def _initial(self) -> tuple[str | None, Mount]:
        s = self.settings
        candidates = [Path(s.mount)] if s.mount else [_saved_path(s)]
        if s.source is None and not s.mount:
            candidates.append(Path(s.sample_session) / "approach" / "mount.json")
        for f in candidates:
            if f.is_file():
                try:
                    return str(f), load_mount(f)
                except InputError:
                    continue
        return None, down_camera_mount()

    # ------------------------------------------------------------------ the camera
    def camera(self):
        """The camera in use (its field of view draws the frustum and the footprint)."""
        if self._camera is None:
            s = self.settings
            path = Path(s.camera) if s.camera else Path(s.sample_session) / "camera.yaml"
            self._camera = load_camera(path)
        return self._camera

    # ------------------------------------------------------------------ state
    def mount(self) -> Mount:
        return Mount.from_angles(**self.angles.model_dump())

    def state(self) -> dict:
        m = self.mount()
        cam = self.camera()
        fp = ground_footprint(m, cam, self.height_m)
        return {"angles": self.angles.model_dump(), "height_m": self.height_m,
                "body_from_camera": [[round(v, 6) + 0.0 for v in row]
                                     for row in m.body_from_camera.tolist()],
                "footprint": fp, "blind": self._blind(m, cam),
                "file": str(self.save_path), "loaded_from": self.loaded_from,
                "saved": self.saved, "camera": {"width": cam.width, "height": cam.height,
                                                "hfov_deg": round(cam.hfov_deg(), 1)}}

    def _blind(self, m: Mount, cam) -> list[dict]:
        """Per layout: the camera height above the brick at which a straight descent onto it
        loses it from the picture, with this mount and looking straight down."""
        if not cam.size_known:
            return []
        if self._blind_layouts is None:
            self._blind_layouts = self._layouts()
        a = m.angles()
        down = Mount.from_angles(0.0, 0.0, a["roll_deg"], a["offset_m"])
        out = []
        for lay in self._blind_layouts:
            b, d = blind_height(cam, m, lay), blind_height(cam, down, lay)
            out.append({"layout": lay.name, "leaves_at_m": b.leaves_at_m,
                        "straight_down_leaves_at_m": d.leaves_at_m,
                        "seen": b.highest_seen_m is not None})
        return out

    def preview(self, angles: MountAngles, height_m: float) -> dict:
        """Show ``angles`` (not saved yet) with the ground ``height_m`` below."""
        with self._lock:
            if angles != self.angles:
                self.saved = False
            self.angles, self.height_m = angles, height_m
            st = self.state()
            if self.scene is not None:
                self.scene.show(self.mount(), height_m, st["footprint"])
            return st

    def save(self) -> dict:
        """Write the mount file (both forms; read back before it replaces the old one) and
        make it the one in use."""
        with self._lock:
            m = self.mount()
            m.note = "set on the camera mount page"
            def same_mount(tmp: Path) -> None:     # checked before it replaces anything
                back = load_mount(tmp)
                if abs(back.body_from_camera - m.body_from_camera).max() > 1e-6:
                    raise ValueError("the mount read back differs from the mount written")

            atomic_write_text(self.save_path, json.dumps(m.to_file(), indent=1) + "\n",
                              make_parents=True, verify=same_mount)
            self.saved, self.loaded_from = True, str(self.save_path)
            self.settings.mount = self.save_path
            return self.state()

    # ------------------------------------------------------------------ measuring
    def _layouts(self):
        paths = list(self.settings.layouts) or list_shipped_layouts()
        return [load_layout(p) for p in paths]

    def _result(self, measured, aligned: bool) -> dict:
        m = measured.result
        a = self.angles
        pan_known = m["pan_deg"] is not None
        proposed = MountAngles(tilt_deg=min(max(m["tilt_deg"], 0.0), 180.0),
                               pan_deg=m["pan_deg"] if pan_known else a.pan_deg,
                               roll_deg=m["roll_deg"], offset_m=a.offset_m)
        return {"proposed": proposed.model_dump(), "pictures": m["n"],
                "spread_deg": round(m["spread_deg"], 3), "pan_measured": pan_known,
                "pan_refused": m.get("pan_refused"), "lines": measured.lines}

    def measure_pictures(self, files: list[tuple[str, BinaryIO]], aligned: bool) -> dict:
        """Measure from uploaded pictures (the drone level, a code lying flat in view)."""
        if not files:
            raise InputError("no pictures: choose one or more photos from the drone's camera")
        if len(files) > MAX_PICTURES:
            raise InputError(f"{len(files)} pictures: at most {MAX_PICTURES} at once")

        def pictures():
            for i, (name, fh) in enumerate(files):
                label = name or f"picture {i + 1}"
                data = fh.read(MAX_UPLOAD_BYTES + 1)
                if len(data) > MAX_UPLOAD_BYTES:
                    yield label, f"too large (over {MAX_UPLOAD_BYTES // 2**20} MB)"
                    continue
                try:
                    yield label, decode_image(data, label)[0]
                except ImageError as e:
                    yield label, str(e)

        measured = measure_from_images(pictures(), self.camera(), self._layouts(), aligned)
        return self._result(measured, aligned)

    def measure_live(self, live, aligned: bool, frames: int = 5, timeout: float = 4.0,
                     bound: float = 60.0) -> dict:
        """Measure from the live camera's next ``frames`` frames: waited for while the camera
        starts or gives frames, however slowly a busy machine measures them (up to ``bound``
        seconds in all); a camera that gives none for ``timeout`` seconds is said."""
        live.ensure_started()
        if live.error:
            raise Conflict(f"the camera could not start: {live.error}")
        got: list[tuple[str, np.ndarray | str]] = []
        seen = -1
        start = last = time.monotonic()
        while len(got) < frames:
            now = time.monotonic()
            latest = live.latest_image()
            if latest is not None and latest[0] != seen:
                seen, last = latest[0], now
                got.append((f"live frame {seen}", latest[1]))
                continue
            p = live.pipeline
            delivering = p is not None and p.source.state in (SourceState.STARTING,
                                                              SourceState.LIVE)
            if now - start > bound or (now - last > timeout and not delivering):
                break
            time.sleep(0.05)
        if not got:
            waited = bound if time.monotonic() - start > bound else timeout
            raise Conflict(f"no frame from the camera in {waited:g} s: is it connected?")
        camera = live.camera or self.camera()
        layouts = live.layouts or self._layouts()
        measured = measure_from_images(got, camera, layouts, aligned)
        return self._result(measured, aligned)

    # ------------------------------------------------------------------ 3D preview
    def start_scene(self):
        with self._lock:
            if self.scene is None:
                self.scene = MountScene(self.camera()).start()
                st = self.state()
                self.scene.show(self.mount(), self.height_m, st["footprint"])
            return self.scene

    def close(self) -> None:
        with self._lock:
            if self.scene is not None:
                self.scene.stop()
                self.scene = None
