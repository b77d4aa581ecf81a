"""The live view's server side: the pipeline on the tool's source, the image stream for Wi-Fi,
the 3D scene.

:class:`LiveService` (one per app, ``app.state.live``, made on first use) runs the same
:class:`drovisio.pipeline.Pipeline` as ``drovisio run``: on ``--source`` with ``--camera`` and
every shipped layout, or — with no source — on the sample approach video, looped, with its
camera, layouts and mount. It starts when a page first asks and stops (releasing the camera
for the calibration page) after ``idle_timeout`` seconds with no viewer and no request.

Image stream, made for Wi-Fi: each viewer gets the newest annotated frame (codes and dots
outlined, each brick's axes, name and distance, the target in yellow) as JPEG, through
:class:`AdaptiveStream`:

* the **bandwidth cap** (default 2 Mbit/s) is shared by all viewers (a phone and a tablet on
  the drone's access point get 1 Mbit/s each); a token bucket keeps each viewer's average
  byte rate under its share (bursts of at most two frames);
* at most ``max_fps`` (default 10) images per second per viewer — the pipeline itself runs at
  the camera's rate; for looking at a scene, sharper images beat more of them;
* the **size and JPEG quality adapt**: a ladder of (scale, quality) levels, from full size at
  quality 80 down to a quarter size at 30; after each frame the level steps down when the
  frame was larger than the per-frame budget (share ÷ frame rate) and up when several frames
  fit in half of it;
* **acknowledged frames**: the page acknowledges each image; at most two are in flight, so a
  slow link lowers the frame rate instead of queueing stale images, and a slow
  acknowledgement (moving average > 0.5 s) also steps the level down.

Encoded frames are cached per (frame, level), so viewers at the same level share the work.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from drovisio._threads import join_thread
from drovisio.fusion import so3_log
from drovisio.mount import down_camera_mount
from drovisio.pose.covariance import parent_covariance, uncertainty_words
from drovisio.recording import end_lines
from webtool.live.annotate import annotate
from webtool.live.scene import LiveScene
from webtool.live.stream import DEFAULT_BANDWIDTH_BPS, LEVELS, AdaptiveStream

__all__ = ["DEFAULT_BANDWIDTH_BPS", "LEVELS", "AdaptiveStream", "LiveService", "annotate"]

log = logging.getLogger("webtool")

# ------------------------------------------------------------------------------------------
# The service
# ------------------------------------------------------------------------------------------


@dataclass
class _Config:
    source: str
    loop: bool
    camera_file: Path
    layout_files: list[Path]
    mount_file: Path | None
    sample: bool


class LiveService:
    """See the module doc.

    Args:
        settings: The web tool's settings (source, camera, sample session).
        bandwidth_bps: Cap of all image streams together, bits/s.
        max_fps: Highest image rate per viewer (images/s).
        idle_timeout: Seconds without viewer or request after which the pipeline stops.
        scene: Serve the 3D scene (viser).
        pipeline_factory: ``(service) -> Pipeline`` (tests).
    """

    def __init__(self, settings, bandwidth_bps: float = DEFAULT_BANDWIDTH_BPS,
                 max_fps: float = 10.0, idle_timeout: float = 60.0, scene: bool = True,
                 pipeline_factory=None):
        self.settings = settings
        self.bandwidth_bps = float(bandwidth_bps)
        self.max_fps = max_fps
        self.idle_timeout = idle_timeout
        self.want_scene = scene
        self.pipeline_factory = pipeline_factory
        self.pipeline = None
        self.camera = None
        self.layouts: list = []
        self.mount = None
        self.scene = None
        self.error: str | None = None
        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._watchdog: threading.Thread | None = None
        self._closed = threading.Event()
        self._last_touch = time.monotonic()
        self._viewers: dict[int, AdaptiveStream] = {}
        self._next_viewer = 1
        self._latest: tuple[int, np.ndarray, object] | None = None
        self._seq = 0
        self._annotated: tuple[int, np.ndarray] | None = None
        self._jpegs: dict[tuple[int, int], bytes] = {}
        self._enc_lock = threading.Lock()
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []

    # ------------------------------------------------------------------ configuration
    def config(self) -> _Config:
        if getattr(self, "_config", None) is None:
            self._config: _Config | None = self._make_config()
        assert self._config is not None
        return self._config

    def _make_config(self) -> _Config:
        s = self.settings
        from drovisio.layout import list_shipped_layouts, shipped_layouts_dir

        sample_dir = Path(s.sample_session)
        approach = sample_dir / "approach"
        camera = Path(s.camera) if s.camera else sample_dir / "camera.yaml"
        if s.source is None:
            scene = json.loads((approach / "scene.json").read_text())
            root = shipped_layouts_dir()
            return _Config(str(approach / "approach.mp4"), True, camera,
                           list(s.layouts) or [root / f"{n}.json" for n in scene["layouts"]],
                           s.mount or approach / "mount.json", True)
        return _Config(s.source, False, camera, list(s.layouts) or list_shipped_layouts(),
                       s.mount, False)

    def _build(self):
        """The pipeline ``drovisio run`` would build from the same options (sinks, target,
        mount, recording included): the page watches what the flight controller is fed."""
        if self.pipeline_factory is not None:
            return self.pipeline_factory(self)
        from drovisio.startup import build_pipeline

        c = self.config()
        config = self.settings.pipeline.model_copy(update={
            "source": c.source, "camera": str(c.camera_file),
            "layouts": [str(x) for x in c.layout_files],
            "mount": str(c.mount_file) if c.mount_file else None, "pace": "realtime"})
        p = build_pipeline(config, loop=c.loop, default_sinks=())
        self.camera, self.layouts, self.mount = p.camera, p.layouts, p.mount
        return p

    # ------------------------------------------------------------------ lifecycle
    def touch(self) -> None:
        self._last_touch = time.monotonic()

    def ensure_started(self) -> None:
        """Start the pipeline (and the scene) if they are not running."""
        self.touch()
        with self._lock:
            if self._closed.is_set() or (self._thread is not None and self._thread.is_alive()):
                return
            try:
                p = self.pipeline = self._build()
                self.error = None
            except Exception as e:  # noqa: BLE001 - shown on the page
                self.error = f"{type(e).__name__}: {e}"
                self.pipeline = None
                return
            p.add_listener(self._on_frame)
            self._thread = threading.Thread(target=self._run_pipeline, args=(p,),
                                            daemon=True, name="live-pipeline")
            self._thread.start()
            if self._watchdog is None:
                self._watchdog = threading.Thread(target=self._watch, daemon=True,
                                                  name="live-idle")
                self._watchdog.start()

    def reconfigure(self) -> None:
        """The camera or the mount in use changed ("Use this calibration", a mount saved):
        the pipeline is rebuilt on them at once (restarted if it was running), the 3D
        scene places bricks with the new mount. No restart of the tool."""
        with self._lock:
            running = self._thread is not None and self._thread.is_alive()
            self.stop_pipeline()
            self._config = None
            if running:
                self.ensure_started()
            if self.scene is not None and self.pipeline is not None:
                if self.mount is not None:
                    self.scene.mount = self.mount
                self.scene.camera = self.camera

    def start_scene(self):
        """The 3D scene, started on first use."""
        with self._lock:
            if self.scene is None and self.want_scene and not self._closed.is_set():
                self.scene = LiveScene(self.mount, self.camera, self.layouts).start()
            return self.scene

    def _run_pipeline(self, p) -> None:
        try:
            p.run()
        except Exception as e:  # noqa: BLE001
            self.error = f"{type(e).__name__}: {e}"
        finally:
            p.close()
            # every end of a run passes here (stop_pipeline waits for this thread): what the
            # recording could not record, or that it got no frame and was removed
            rec = getattr(p, "recorder", None)
            for line in end_lines(rec.status()) if rec is not None else []:
                log.warning("live: %s", line)

    def _watch(self) -> None:
        while not self._closed.wait(1.0):
            idle = time.monotonic() - self._last_touch
            if (not self._viewers and idle > self.idle_timeout and self.pipeline is not None
                    and not self.settings.flying):
                self.stop_pipeline()

    def stop_pipeline(self) -> None:
        with self._lock:
            p, th = self.pipeline, self._thread
            if p is not None:
                p.close()   # waits for the frame in progress (a first run compiles kernels)
            join_thread(th, "running the live pipeline")
            self._thread = None

    def close(self) -> None:
        """Stop the pipeline, the idle watch and the scene, waiting for each (app shutdown)."""
        self._closed.set()
        self.stop_pipeline()
        join_thread(self._watchdog, "watching the live view for idleness")
        if self.scene is not None:
            self.scene.stop()
            self.scene = None
        self._wake()

    # ------------------------------------------------------------------ frames
    def _on_frame(self, frame, out) -> None:
        if frame is None or frame.image is None:
            self._wake()
            return
        self._seq += 1
        self._latest = (self._seq, frame.image, out)
        if self.scene is not None:
            self.scene.update(out)
        self._wake()

    def _wake(self) -> None:
        for loop, ev in list(self._waiters):
            try:
                loop.call_soon_threadsafe(ev.set)
            except RuntimeError:  # loop closed
                pass

    async def wait_frame(self, after_seq: int, timeout: float = 1.0) -> int:
        """Wait until a frame newer than ``after_seq`` exists (or timeout); its seq."""
        if self._seq > after_seq:
            return self._seq
        ev = asyncio.Event()
        w = (asyncio.get_running_loop(), ev)
        self._waiters.append(w)
        try:
            deadline = time.monotonic() + timeout
            while self._seq <= after_seq and time.monotonic() < deadline:
                ev.clear()
                try:
                    await asyncio.wait_for(ev.wait(), max(0.0, deadline - time.monotonic()))
                except TimeoutError:
                    break
        finally:
            self._waiters.remove(w)
        return self._seq

    @property
    def seq(self) -> int:
        return self._seq

    def latest_output(self):
        return None if self._latest is None else self._latest[2]

    def latest_image(self) -> tuple[int, np.ndarray] | None:
        """(seq, BGR image) of the newest frame, or None before the first."""
        latest = self._latest
        return None if latest is None else (latest[0], latest[1])

    def jpeg(self, level: int) -> tuple[int, bytes] | None:
        """(seq, JPEG bytes) of the newest frame, annotated, at a :data:`LEVELS` level."""
        latest = self._latest
        if latest is None:
            return None
        seq, image, out = latest
        with self._enc_lock:
            key = (seq, level)
            data = self._jpegs.get(key)
            if data is not None:
                return seq, data
            if self._annotated is None or self._annotated[0] != seq:
                self._annotated = (seq, annotate(image, out, self.camera))
            img = self._annotated[1]
            scale, q = LEVELS[level]
            if scale != 1.0:
                img = cv2.resize(img, (max(16, int(img.shape[1] * scale)),
                                       max(16, int(img.shape[0] * scale))),
                                 interpolation=cv2.INTER_AREA)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, q])
            data = buf.tobytes() if ok else b""
            if len(self._jpegs) > 16 or any(k[0] != seq for k in self._jpegs):
                self._jpegs = {k: v for k, v in self._jpegs.items() if k[0] == seq}
            self._jpegs[key] = data
            return seq, data

    # ------------------------------------------------------------------ viewers
    def add_viewer(self) -> tuple[int, AdaptiveStream]:
        with self._lock:
            vid = self._next_viewer
            self._next_viewer += 1
            st = AdaptiveStream(self.bandwidth_bps, fps=self.stream_fps())
            self._viewers[vid] = st
            self._reshare()
            return vid, st

    def remove_viewer(self, vid: int) -> None:
        with self._lock:
            self._viewers.pop(vid, None)
            self._reshare()
            self.touch()

    def _reshare(self) -> None:
        n = max(1, len(self._viewers))
        for st in self._viewers.values():
            st.set_rate(self.bandwidth_bps / n)

    def stream_fps(self) -> float:
        fps = 0.0
        if self.pipeline is not None:
            fps = self.pipeline.stats.fps()
        return min(self.max_fps, fps) if fps > 1 else self.max_fps

    @property
    def viewers(self) -> int:
        return len(self._viewers)

    # ------------------------------------------------------------------ figures, control
    def status(self) -> dict:
        c = None
        try:
            c = self.config()
        except Exception:  # noqa: BLE001
            pass
        st: dict = {"running": self._thread is not None and self._thread.is_alive(),
                    "error": self.error, "viewers": self.viewers,
                    "bandwidth_kbps": round(self.bandwidth_bps / 1000, 1),
                    "sample": bool(c.sample) if c else None}
        if self.pipeline is not None:
            st.update(self.pipeline.status())
        else:
            st.update({"fps": 0.0, "detect_ms": 0.0, "latency_ms": 0.0, "bricks": 0,
                       "source": {"label": c.source if c else "", "state": "stopped",
                                  "error": None}})
        st["stream_kbps"] = round(sum(v.kbps() for v in self._viewers.values()), 1)
        if self.scene is not None:
            st["scene"] = {"port": self.scene.port, "bricks": self.scene.brick_names(),
                           "updates": self.scene.updates, "clients": self.scene.clients()}
        return st

    def bricks_json(self) -> list[dict]:
        out = self.latest_output()
        if out is None or self.pipeline is None:
            return []
        if self.pipeline.source.now() - out.t_mono > self.pipeline.tracker.config.max_age:
            return []  # never a stale pose, on the page either
        res = []
        for b in out.bricks:
            d = b.to_json()
            T = b.body_from_brick
            if T is None:  # no mount file: show it as if the camera looked straight down
                T = down_camera_mount().body_from(b.camera_from_brick())
                d["body_from_brick"] = {"rvec": [round(float(v), 7) for v in so3_log(T[:3, :3])],
                                        "tvec": [round(float(v), 7) for v in T[:3, 3]]}
                d["mount_assumed"] = True
            R = T[:3, :3]
            d["yaw_deg"] = round(math.degrees(math.atan2(R[1, 0], R[0, 0])), 2)
            d["target"] = out.target is not None and b.track == out.target.track
            d["uncertainty"] = uncertainty_words(
                None if b.covariance is None else parent_covariance(b.rvec, b.covariance))
            res.append(d)
        return res

    def set_target(self, spec) -> dict:
        self.ensure_started()
        if self.pipeline is None:
            raise RuntimeError(self.error or "the live pipeline is not running")
        return self.pipeline.target.set(spec).to_json()
