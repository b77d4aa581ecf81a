"""The calibration page's server side: one live calibration session, fed by the server's camera.

A :class:`CalibrationService` per app (``app.state.calibration``, made on first use by
``webtool.routes.calibration``) owns:

* a **frame source** (a :mod:`drovisio.sources` reader): the server's camera (``--source``: a
  V4L2 index such as ``0``, shared with the live view, a stream URL or a video file, which
  loops), a folder of images, or — with no source — the sample calibration session played *as
  if live* (:class:`~drovisio.sources.PlaybackReader`);
* a **worker thread** that pulls frames, offers each to the
  :class:`~drovisio.calibration.session.CalibrationSession` (auto-capture: sharp + still + novel
  frames are kept) or only detects the board (auto-capture off), draws the detected corners and
  keeps the latest frame as a JPEG for the page. When the camera gives no frame, the page is told
  "camera disconnected — retrying" and the source is reopened with a growing pause (0.5 s → 4 s);
  everything captured stays. The thread stops and releases the camera after ``idle_timeout`` s
  without a request (so the camera is free for other parts of the tool) and restarts on the next
  one;
* **persistence**: every kept view is written at once — its image first (``images/NAME``), then
  ``session.json`` (the session's state: board, image size, detections), each through a
  temporary file renamed over the target — under ``calibration_dir/<session-id>/``. On start the
  last session of the same source is resumed (``calibration_dir/current`` names it); images that
  a crash left without an entry in ``session.json`` are detected again and added back. Deleted
  views are moved to ``deleted/``, not erased;
* **solves in the background**: after each change (≥ the solve's minimum views) the session's own
  worker solves; the next-pose hint, the verdict and the report are derived from the latest
  solve and cached, so that requests never wait for a solve.

Tests give their own readers through ``source_factory``.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np

from drovisio.calibration.board import BoardSpec, BoardSpecError, parse_board, to_gray
from drovisio.calibration.report import _clean, build_report, uncertainty_image
from drovisio.calibration.session import CalibrationSession, FrameResult, SessionConfig
from drovisio.calibration.solve import MODEL_CHOICES, SolveOptions
from drovisio.calibration.uncertainty import lens_key
from drovisio.calibration.verdict import Verdict
from drovisio.camera import Camera
from drovisio.camera_file import load_camera, save_camera
from drovisio.errors import InputError
from drovisio.fileio import atomic_write_bytes as _atomic_write_bytes
from drovisio.images import IMAGE_SUFFIXES, ImageError, decode_image, is_image_file, read_image
from drovisio.resources import user_data_dir
from drovisio.sources import PlaybackReader, Reader, list_folder, reader_for
from drovisio.textfile import parse_json, read_text
from webtool.errors import ServiceError

__all__ = [
    "SESSION_SCHEMA",
    "CalibrationService",
    "atomic_write_bytes",
    "camera_in_use",
    "default_calibration_dir",
]

log = logging.getLogger(__name__)

SESSION_SCHEMA = "drovisio/calibration-web-session@1"
MAX_UPLOAD_BYTES = 64 * 1024 * 1024  # per file
THUMB_WIDTH = 200


# ==================================================================================== helpers
def default_calibration_dir() -> Path:
    return user_data_dir("calibration")


def _calibration_root(settings) -> Path:
    if hasattr(settings, "user_folder"):
        return Path(settings.user_folder("calibration"))
    return Path(settings.calibration_dir) if getattr(settings, "calibration_dir", None) \
        else default_calibration_dir()


IN_USE_FILE = "in-use.json"


def _print_squares(board) -> dict[str, float]:
    """The square each paper's printout of the board has (the PDF prints exactly this)."""
    from drovisio.calibration.printout import print_square_mm

    return {paper: print_square_mm(board, paper) for paper in ("A4", "A3", "Letter")}


def camera_in_use(settings) -> Path | None:
    """The camera file last chosen with "Use this calibration" (``calibration_dir/in-use.json``),
    if it still loads; None otherwise (a broken choice is logged and ignored)."""
    f = _calibration_root(settings) / IN_USE_FILE
    if not f.is_file():
        return None
    try:
        path = Path(json.loads(f.read_text(encoding="utf-8"))["camera_file"])
        load_camera(path)
    except Exception as e:  # noqa: BLE001 - any failure: keep the default camera
        log.warning("calibration in use (%s) not restored: %s", f, e)
        return None
    return path


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:mod:`drovisio.fileio`), making its folder."""
    _atomic_write_bytes(path, data, make_parents=True)


def _decode(data: bytes, name: str = "") -> tuple[np.ndarray | None, str | None]:
    """(BGR image, None), or (None, why it cannot be used) in plain words."""
    try:
        return decode_image(data, name)[0], None
    except ImageError as e:
        return None, str(e)


def _safe_name(name: str) -> str:
    base = re.split(r"[\\/]", name or "")[-1]
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", base).strip("._") or "image"
    return base[:80]


def _jpeg(img: np.ndarray, quality: int = 80) -> bytes:
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover - OpenCV always encodes a BGR uint8 image
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def _draw_corners(img: np.ndarray, board: BoardSpec, det, colour=(0, 220, 0)) -> None:
    if det is None:
        return
    if board.kind == "chessboard" and det.n == board.n_corners:
        cv2.drawChessboardCorners(img, board.pattern_size,
                                  det.corners.astype(np.float32).reshape(-1, 1, 2), True)
    else:
        r = max(2, round(img.shape[1] / 200))
        for x, y in det.corners:
            cv2.circle(img, (round(x), round(y)), r, colour, -1, cv2.LINE_AA)


# ============================================================================= frame sources
def sample_files(settings) -> list[Path]:
    folder = Path(settings.sample_session)
    for cand in (folder / "calibration", folder):
        if cand.is_dir():
            files = [f for f in list_folder(cand) if is_image_file(f)]
            if files:
                return files
    return []


def default_source_factory(settings) -> Callable[[], Reader]:
    """The frame source ``settings`` ask for (a fresh reader per call): the sample session or
    a folder of photos played as if live, else the camera, stream or video (which loops)."""
    if settings.source is None:
        def sample() -> Reader:
            files = sample_files(settings)
            if not files:
                raise FileNotFoundError(f"no sample calibration images in "
                                        f"{settings.sample_session}")
            return PlaybackReader(files, settings.sample_seconds_per_view,
                                  label="sample session (no camera)")
        return sample
    if Path(settings.source).is_dir():
        return lambda: PlaybackReader.from_folder(
            Path(settings.source), seconds_per_view=settings.sample_seconds_per_view)
    return lambda: reader_for(settings.source, loop=True)


def source_label(settings) -> str:
    return "sample" if settings.source is None else f"source:{settings.source}"


# ================================================================================== feedback
def _saved_views(n: int) -> str:
    if n == 0:
        return ""
    return f"The {n} view{'s' if n != 1 else ''} captured so far {'are' if n != 1 else 'is'} saved."


def frame_feedback(fr: FrameResult | None, auto: bool) -> dict:
    """What the last frame means, in plain words, for the page."""
    if fr is None:
        return {"detected": False, "kept": False, "message": "Waiting for the camera…",
                "detail": ""}
    detail = "; ".join(fr.reasons)
    if fr.kept:
        return {"detected": True, "kept": True, "view_id": fr.view_id,
                "message": f"Captured view #{fr.view_id}. Move the board to the next place.",
                "detail": ""}
    if fr.detection is None:
        if any("image size" in r for r in fr.reasons):
            msg = ("The camera's image size differs from this session's: start a new session "
                   "(below) to calibrate this camera.")
        else:
            msg = "No board in view: show the whole chessboard to the camera."
        return {"detected": False, "kept": False, "message": msg, "detail": detail}
    failed = [g.name for g in fr.gates if not g.ok]
    n = fr.detection.n
    if "size" in failed:
        msg = "The board looks too small: bring it closer to the camera."
    elif "sharpness" in failed:
        msg = "The image is blurred: hold the board steady (or add light)."
    elif "still" in failed:
        msg = "Board found. Hold it still…"
    elif "novel" in failed:
        msg = ("You already have a view like this one: move the board to the place shown in "
               "yellow.")
    elif not auto:
        msg = f"Board found ({n} corners). Press Capture to keep this view."
    else:
        msg = f"Board found ({n} corners)."
    return {"detected": True, "kept": False, "message": msg, "detail": detail}


# =================================================================================== service
@dataclass
class _CameraStatus:
    state: str = "stopped"  # stopped | starting | ok | disconnected
    message: str = ""
    since: float = 0.0
    failures: int = 0


class CalibrationService:
    """See the module docstring.

    Args:
        settings: The web tool's :class:`~webtool.settings.Settings` (``calibration_dir``,
            board, source, sample playback speed; ``camera`` is set by :meth:`use_result`).
        source_factory: Makes a frame source (default: from ``settings``).
        idle_timeout: Seconds without a request after which the camera is released.
    """

    def __init__(self, settings, source_factory: Callable[[], Reader] | None = None,
                 idle_timeout: float = 45.0) -> None:
        self.settings = settings
        self.root = _calibration_root(settings)
        self._factory = source_factory or default_source_factory(settings)
        self.idle_timeout = float(idle_timeout)
        self.source_key = source_label(settings)
        self._lock = threading.RLock()        # session swap, state file, caches
        self._keep_lock = threading.RLock()   # offering / adding views and persisting them
        self._frame_cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self._last_request = time.monotonic()
        self._camera = _CameraStatus()
        self._source_label = ""
        self._latest_raw: np.ndarray | None = None
        self._latest_raw_at = 0.0
        self._latest_jpeg: bytes | None = None
        self._frame_seq = 0
        self._frame_size: tuple[int, int] | None = None
        self._feedback = frame_feedback(None, True)
        self._gen = 0                 # bumps whenever the kept views change
        self._result_seq = 0          # bumps whenever a solve finishes
        self._solve_pending = False
        self._derived_cache: tuple | None = None
        self._report_cache: tuple | None = None
        self._png_cache: tuple | None = None
        self._thumbs: dict[tuple[str, int], bytes] = {}
        self._capture_counter = 1
        # session fields (set by _open_session)
        self.session: CalibrationSession
        self.session_id = ""
        self.folder = Path()
        self.created = 0.0
        self.auto_capture = True
        self.show_result = False
        self.used_camera: str | None = None
        # printers scale pages: the square size is asked for (measured) before the first solve
        # of a camera's session; the sample's board is known
        self.square_measured = settings.source is None
        self._open_session()

    # ----------------------------------------------------------------------- session files
    @property
    def images_dir(self) -> Path:
        return self.folder / "images"

    def _board_from_settings(self) -> BoardSpec:
        return parse_board(self.settings.calibration_board, self.settings.calibration_square_m)

    def _camera_guess(self) -> Camera | None:
        cam = getattr(self.settings, "camera", None)
        if cam:
            try:
                return load_camera(cam)
            except Exception:  # noqa: BLE001 - a bad --camera file is reported elsewhere
                return None
        return None

    def _config(self, session_id: str) -> SessionConfig:
        # the page always says how flat the printed board was (a fraction of a second)
        return SessionConfig(camera_name=f"drovisio-{session_id}",
                             solve=SolveOptions(board_flatness=True))

    def _open_session(self) -> None:
        """Resume the last session of this source, or start a new one."""
        self.root.mkdir(parents=True, exist_ok=True)
        candidates = []
        cur = self.root / "current"
        try:
            candidates.append(cur.read_text(encoding="utf-8").strip())
        except OSError:
            pass
        others = sorted((p for p in self.root.iterdir() if (p / "session.json").is_file()),
                        key=lambda p: (p / "session.json").stat().st_mtime, reverse=True)
        candidates += [p.name for p in others]
        for sid in candidates:
            if sid and self._try_resume(sid):
                return
        self._new_session(self._board_from_settings())

    def _try_resume(self, sid: str) -> bool:
        folder = self.root / sid
        path = folder / "session.json"
        if not path.is_file():
            return False
        try:
            data = parse_json(read_text(path, "calibration session"), str(path))
            if not isinstance(data, dict):
                raise ValueError("not a session")
            if data.get("schema") != SESSION_SCHEMA or data.get("source") != self.source_key:
                return False
            sess = CalibrationSession.from_state(data["session"], self._config(sid),
                                                 self._camera_guess())
            # the image names inside session.json name files in this session's folder only
            for name in [v.name for v in sess.views]:
                if not isinstance(name, str) or _safe_name(name) != name:
                    raise ValueError(f"images: {name!r} is not a plain file name")
        except (OSError, ValueError, KeyError, TypeError) as e:
            # keep the broken file for inspection; the images are still there
            try:
                os.replace(path, folder / f"session.json.broken-{int(time.time())}")
            except OSError:
                pass
            self._feedback = {**frame_feedback(None, True),
                              "message": f"Session {sid} could not be read ({e}); started anew."}
            return False
        with self._lock:
            self.session = sess
            self.session_id = sid
            self.folder = folder
            self.created = float(data.get("created", time.time()))
            self.auto_capture = bool(data.get("auto_capture", True))
            self.show_result = bool(data.get("show_result", False))
            self.square_measured = bool(data.get("square_measured",
                                                 self.settings.source is None))
            self.used_camera = data.get("used_camera")
            lens = data.get("lens_model", "plumb_bob")
            if lens in MODEL_CHOICES:
                sess.set_model(lens)
            self._after_session_change()
        self._recover_orphans()
        self._save()
        self._maybe_solve()
        return True

    def _new_session(self, board: BoardSpec) -> None:
        sid = time.strftime("%Y%m%d-%H%M%S") + "-" + secrets.token_hex(2)
        sess = CalibrationSession(board, config=self._config(sid),
                                  camera_guess=self._camera_guess())
        old = getattr(self, "session", None)
        with self._keep_lock, self._lock:
            self.session = sess
            self.session_id = sid
            self.folder = self.root / sid
            self.created = time.time()
            self.auto_capture = True
            self.show_result = False
            self.square_measured = self.settings.source is None
            self.used_camera = None
            self._after_session_change()
            self.images_dir.mkdir(parents=True, exist_ok=True)
            self._save()
        if old is not None:
            threading.Thread(target=old.close, daemon=True).start()

    def _after_session_change(self) -> None:
        self._gen += 1
        self._derived_cache = self._report_cache = self._png_cache = None
        self._thumbs.clear()
        nums = [0]
        for d in (self.folder / "images", self.folder / "deleted"):
            if d.is_dir():
                nums += [int(m.group(1)) for f in d.iterdir()
                         if (m := re.match(r"capture-(\d{1,9})(?!\d)", f.name))]
        self._capture_counter = max(nums) + 1
        atomic_write_bytes(self.root / "current", self.session_id.encode())

    def _recover_orphans(self) -> None:
        """Images written just before a crash, whose view never reached session.json."""
        if not self.images_dir.is_dir():
            return
        known = {v.name for v in self.session.views}
        known |= {r.get("file") for r in self.session.rejected}
        for f in sorted(self.images_dir.iterdir()):
            if f.name in known or f.name.startswith(".") or \
                    f.suffix.lower() not in IMAGE_SUFFIXES:
                continue
            try:   # bounded: a FIFO or a 20 GB file named like an image is not read
                img, why = read_image(f)[0], None
            except ImageError as e:
                img, why = None, str(e)
            if img is None:
                self.session.add_rejected(f.name, why)
                continue
            fr = self.session.add_image(img, f.name)
            if fr.kept:
                self._gen += 1

    def _save(self) -> None:
        """Write session.json atomically (after the images it names)."""
        with self._lock:
            data = {"schema": SESSION_SCHEMA, "id": self.session_id, "created": self.created,
                    "saved": time.time(), "source": self.source_key,
                    "auto_capture": self.auto_capture, "show_result": self.show_result,
                    "square_measured": self.square_measured,
                    "lens_model": self.session.config.solve.model,
                    "used_camera": self.used_camera, "session": self.session.state()}
            atomic_write_bytes(self.folder / "session.json",
                               json.dumps(_clean(data), indent=1).encode())

    # ----------------------------------------------------------------------- worker thread
    def touch(self) -> None:
        """A request came in: keep the camera running (start it if it was stopped)."""
        self._last_request = time.monotonic()
        if self._closed:
            return
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._stop.clear()
                self._camera = _CameraStatus("starting", "Starting the camera…", time.time())
                self._thread = threading.Thread(target=self._run, daemon=True,
                                                name="calibration-camera")
                self._thread.start()

    def close(self) -> None:
        """Stop the worker and the session's solver (app shutdown)."""
        self._closed = True
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=5)
        with self._frame_cond:
            self._frame_cond.notify_all()
        self.session.close()

    @property
    def camera_message(self) -> str:
        """What the camera is doing, for people ("Camera disconnected — retrying…")."""
        return self._camera.message

    def _set_camera(self, state: str, message: str) -> None:
        with self._lock:
            c = self._camera
            if c.state != state:
                self._camera = _CameraStatus(state, message, time.time(),
                                             c.failures if state == "disconnected" else 0)
            else:
                c.message = message

    def _run(self) -> None:
        from drovisio.sources import EndOfStream

        src: Reader | None = None
        try:
            while not self._stop.is_set():
                if time.monotonic() - self._last_request > self.idle_timeout:
                    self._set_camera("stopped", "Camera paused: nobody is watching this page.")
                    break
                if src is None:
                    try:
                        src = self._factory()
                        self._source_label = getattr(src, "label", "")
                        src.open()
                    except Exception as e:  # noqa: BLE001 - any failure: retry later
                        if src is not None:
                            src.close()
                        src = None
                        self._lost(f"cannot open the camera ({e})")
                        continue
                frame = None
                try:
                    raw = src.read()
                    frame = None if raw is None else raw.image
                except EndOfStream:
                    raw = None
                except Exception as e:  # noqa: BLE001
                    raw = None
                    self._feedback = {**self._feedback, "detail": str(e)}
                if raw is not None and frame is None:   # one bad frame: not a lost camera
                    continue
                if frame is None:
                    try:
                        src.close()
                    except Exception:
                        log.debug("closing the lost camera failed", exc_info=True)
                    src = None
                    self._lost("")
                    continue
                if self._camera.state != "ok":
                    self._set_camera("ok", "Camera connected.")
                self._process(frame)
        finally:
            if src is not None:
                src.close()
            with self._frame_cond:
                self._frame_cond.notify_all()

    def _lost(self, why: str) -> None:
        with self._lock:
            fails = self._camera.failures + 1
        detail = f" ({why})" if why else ""
        if self._frame_seq:
            msg = f"Camera disconnected — retrying…{detail}."
        else:
            msg = (f"No picture from {self._source_label or 'the camera'} — retrying…{detail}. "
                   "Check that the camera is plugged in.")
        self._set_camera("disconnected", (msg + " " + _saved_views(len(self.session.views)))
                         .strip())
        with self._lock:
            self._camera.failures = fails
        with self._frame_cond:
            self._frame_cond.notify_all()
        self._stop.wait(min(4.0, 0.5 * 2 ** min(fails - 1, 3)))

    def _process(self, frame: np.ndarray) -> None:
        with self._keep_lock:
            sess = self.session
            auto = self.auto_capture
            if auto:
                name = f"capture-{self._capture_counter:04d}.png"
                fr = sess.offer_frame(frame, name)
                if fr.kept:
                    self._capture_counter += 1
                    if not self._persist_view(sess, fr, self._png(frame)):
                        fr = None
            else:
                fr = sess.evaluate(frame)
        annotated = frame.copy()
        if fr is not None:
            _draw_corners(annotated, sess.board, fr.detection,
                          (0, 220, 0) if fr.usable else (0, 140, 255))
        jpeg = _jpeg(annotated)
        with self._frame_cond:
            self._latest_raw = frame
            self._latest_raw_at = time.monotonic()
            self._latest_jpeg = jpeg
            self._frame_seq += 1
            self._frame_size = (frame.shape[1], frame.shape[0])
            if fr is not None:
                fb = frame_feedback(fr, auto)
                # a capture message stays readable for a moment
                if not (self._feedback.get("kept") and not fb["kept"]
                        and time.monotonic() - self._feedback.get("_at", 0) < 1.5):
                    self._feedback = {**fb, "_at": time.monotonic()}
            self._frame_cond.notify_all()

    @staticmethod
    def _png(frame: np.ndarray) -> bytes:
        _, buf = cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return buf.tobytes()

    def _persist_view(self, sess: CalibrationSession, fr: FrameResult, data: bytes) -> bool:
        """Write a just-kept view's image, then the state; on failure take the view back."""
        try:
            atomic_write_bytes(self.images_dir / fr.name, data)
            with self._lock:
                if sess is not self.session:
                    return False
                self._gen += 1
            self._save()
        except OSError as e:
            sess.remove_view(fr.view_id)
            self._feedback = {"detected": True, "kept": False,
                              "message": f"Could not save the capture: {e.strerror or e}. "
                                         "Check the disk space of the server.",
                              "detail": str(e), "_at": time.monotonic()}
            return False
        self._maybe_solve()
        return True

    # ---------------------------------------------------------------------------- solving
    def _maybe_solve(self) -> None:
        sess = self.session
        with self._lock:
            if sess.solving:
                self._solve_pending = True
                return
            if len(sess.views) < sess.config.solve.min_views:
                return
            self._solve_pending = False
        sess.solve_async(lambda f, s=sess: self._solved(s, f))

    def _solved(self, sess: CalibrationSession, fut) -> None:
        if sess is not self.session:
            return
        with self._lock:
            self._result_seq += 1
            again = self._solve_pending or not sess.result_is_current
        if fut.exception() is None:
            try:  # warm the caches (hint, verdict) here, not in a request
                self._derived()
            except Exception:
                log.debug("deriving hint and verdict failed", exc_info=True)
        if again and sess.views and fut.exception() is None:
            self._maybe_solve()
        elif again:
            with self._lock:
                self._solve_pending = False

    def request_solve(self) -> dict:
        """The page's Solve button: show the result, solving first if needed."""
        sess = self.session
        n = len(sess.views)
        need = sess.config.solve.min_views
        if n < need:
            raise ServiceError(f"Keep going: a solve needs at least {need} views and you have "
                               f"{n}. Show the board at the place shown in yellow.")
        with self._lock:
            self.show_result = True
        self._save()
        if not sess.result_is_current and not sess.solving:
            self._maybe_solve()
        return {"solving": sess.solving or not sess.result_is_current,
                "has_result": sess.result is not None}

    # -------------------------------------------------------------------------- derived
    def _derived(self) -> dict:
        sess = self.session
        key = (self.session_id, self._gen, self._result_seq, id(sess.result))
        with self._lock:
            if self._derived_cache is not None and self._derived_cache[0] == key:
                return self._derived_cache[1]
        cov = sess.coverage()
        try:
            sug = sess.suggestion().to_json()
        except ValueError as e:  # the board cannot fit in the image
            sug = {"sentence": str(e)}
        except Exception:  # noqa: BLE001 - a degenerate solve must not break the page
            sug = {"sentence": "Move the board to a part of the picture it has not covered yet."}
        try:
            verdict = sess.verdict()
        except Exception as e:  # noqa: BLE001
            verdict = Verdict(False, [f"the calibration could not be judged ({e})"])
        out = {"coverage": cov, "suggestion": sug, "verdict": verdict}
        with self._lock:
            self._derived_cache = (key, out)
        return out

    # ----------------------------------------------------------------------------- views
    def _view_rows(self) -> list[dict]:
        with self._keep_lock:  # a view is listed once its image is on disk
            sess = self.session
            views = sess.views
        res = sess.result
        fits = {f.name: f for f in res.per_view} if res is not None else {}
        rejected = {r["file"]: r["reason"] for r in (res.rejected if res is not None else [])}
        rows = []
        for v in views:
            f = fits.get(v.name)
            rows.append({
                "id": v.id, "name": v.name, "corners": v.detection.n,
                "origin": "upload" if v.name.startswith("upload-") else "camera",
                "rms_px": None if f is None else round(float(f.rms_px), 3),
                "max_px": None if f is None else round(float(f.max_px), 3),
                "note": rejected.get(v.name, ""),
                "thumb": f"/api/calibration/views/{v.id}/thumb.jpg?s={self.session_id}",
            })
        return rows

    def thumbnail(self, view_id: int) -> bytes:
        key = (self.session_id, int(view_id))
        if key in self._thumbs:
            return self._thumbs[key]
        v = next((v for v in self.session.views if v.id == view_id), None)
        if v is None:
            raise ServiceError(f"view #{view_id} is not in this session", 404)
        try:
            img = read_image(self.images_dir / _safe_name(v.name))[0]
        except ImageError:
            img = None
        missing = img is None
        if missing:  # only the corners, on grey (not cached: the image may still be coming)
            img = np.full((v.detection.image_size[1], v.detection.image_size[0], 3), 200,
                          np.uint8)
        _draw_corners(img, self.session.board, v.detection)
        scale = THUMB_WIDTH / img.shape[1]
        img = cv2.resize(img, (THUMB_WIDTH, max(1, round(img.shape[0] * scale))),
                         interpolation=cv2.INTER_AREA)
        data = _jpeg(img, 75)
        if not missing:
            self._thumbs[key] = data
        return data

    def delete_view(self, view_id: int) -> None:
        with self._keep_lock:
            sess = self.session
            v = next((v for v in sess.views if v.id == view_id), None)
            if v is None or not sess.remove_view(view_id):
                raise ServiceError(f"view #{view_id} is not in this session", 404)
            src = self.images_dir / v.name
            if src.exists():
                (self.folder / "deleted").mkdir(exist_ok=True)
                os.replace(src, self.folder / "deleted" / v.name)
            with self._lock:
                self._gen += 1
                self._thumbs.pop((self.session_id, view_id), None)
            self._save()
        self._maybe_solve()

    def set_auto(self, on: bool) -> None:
        with self._lock:
            self.auto_capture = bool(on)
        self._save()

    def set_square(self, square_m: float) -> dict:
        """The square size measured on the print (metres): kept views stay, solved again."""
        try:
            parse_board(self.session.board.spec(), square_m)
        except BoardSpecError as e:
            raise InputError(f"square_m: {e}") from None
        self.session.set_square(square_m)
        with self._lock:
            self.square_measured = True
            self._gen += 1
        self._save()
        if len(self.session.views) >= self.session.config.solve.min_views:
            self._maybe_solve()
        return {"square_mm": round(self.session.board.square * 1000, 3), "square_measured": True}

    def set_lens_model(self, model: str) -> dict:
        """The page's lens choice: solve again with it (when there is enough to solve)."""
        self.session.set_model(model)
        self._save()
        if len(self.session.views) >= self.session.config.solve.min_views:
            self._maybe_solve()
        return {"lens_model": model}

    def capture(self) -> dict:
        """Keep the current camera frame (the manual Capture button)."""
        with self._frame_cond:
            frame, at = self._latest_raw, self._latest_raw_at
        if frame is None or self._camera.state != "ok" or time.monotonic() - at > 3.0:
            raise ServiceError("No picture from the camera right now, so nothing to capture. "
                               + (self._camera.message or ""), 409)
        with self._keep_lock:
            sess = self.session
            name = f"capture-{self._capture_counter:04d}.png"
            fr = sess.evaluate(frame, name)
            dup = sess.duplicate_of(fr.detection) if fr.usable else None
            if dup is not None:
                raise ServiceError(f"This view is already kept (view #{dup}): move the board "
                                   "first.", 409)
            fr = sess.keep(fr) if fr.usable else fr
            if not fr.kept:
                raise ServiceError(frame_feedback(fr, False)["message"] + (
                    f" ({'; '.join(fr.reasons)})" if fr.reasons else ""), 422)
            self._capture_counter += 1
            if not self._persist_view(sess, fr, self._png(frame)):
                raise ServiceError(self._feedback["message"], 507)
        self._feedback = {**frame_feedback(fr, False), "_at": time.monotonic()}
        return {"view_id": fr.view_id, "message": f"Captured view #{fr.view_id}."}

    # ---------------------------------------------------------------------------- upload
    def upload(self, files: Iterable[tuple[str, BinaryIO]]) -> dict:
        """Images taken elsewhere: each kept (detected, sharp, right size) or rejected with a
        message. Reads the files twice (sizes first) so that big folders never sit decoded in
        memory at once."""
        files = list(files)
        results: list[dict | None] = [None] * len(files)
        sizes: dict[int, tuple[int, int]] = {}
        for i, (name, fh) in enumerate(files):
            label = name or f"file {i + 1}"
            if Path(label).suffix.lower() not in IMAGE_SUFFIXES:
                results[i] = {"file": label, "ok": False, "skipped": True,
                              "message": "skipped: not an image file"}
                continue
            data = self._read(fh)
            if data is None:
                results[i] = {"file": label, "ok": False, "message": "too large (over "
                              f"{MAX_UPLOAD_BYTES // (1024 * 1024)} MB): not a camera image?"}
                continue
            img, why = _decode(data, label)
            if img is None:
                results[i] = {"file": label, "ok": False, "message": why}
                self.session.add_rejected(label, why)
                continue
            sizes[i] = (img.shape[1], img.shape[0])
            del img, data
        sess = self.session
        target = sess.image_size
        if target is None and sizes:
            target = Counter(sizes.values()).most_common(1)[0][0]
        mixed = len(set(sizes.values())) > 1
        kept = 0
        found_any = False
        boardless: list[tuple[str, np.ndarray]] = []
        for i, size in sizes.items():
            name, fh = files[i]
            label = name or f"file {i + 1}"
            if tuple(size) != tuple(target):
                msg = (f"wrong size: {size[0]}×{size[1]}, but this session's images are "
                       f"{target[0]}×{target[1]} (a calibration belongs to one image size"
                       + ("; the most common size of this upload was kept" if mixed and
                          sess.image_size is None else "; start a new session for these")
                       + ")")
                results[i] = {"file": label, "ok": False, "message": msg}
                sess.add_rejected(label, msg)
                continue
            data = self._read(fh)
            img, _ = _decode(data, label)
            fr = sess.evaluate(img, self._upload_name(label))
            if fr.detection is not None:
                found_any = True
            elif len(boardless) < 3:
                boardless.append((label, to_gray(img)))
            msg = None
            if fr.usable:
                with self._keep_lock:
                    if sess is not self.session:
                        raise ServiceError("A new session was started during the upload.")
                    dup = sess.duplicate_of(fr.detection)
                    if dup is not None:
                        msg = f"already in this session (the same picture as view #{dup})"
                    else:
                        fr = sess.keep(fr)
                        if fr.kept and self._persist_view(sess, fr, data):
                            kept += 1
                            results[i] = {"file": label, "ok": True, "view_id": fr.view_id,
                                          "message": f"kept as view #{fr.view_id} "
                                                     f"({fr.detection.n} corners)"}
                            continue
                        msg = self._feedback.get("message") if fr.kept else None
            msg = msg or self._plain_reason(fr)
            results[i] = {"file": label, "ok": False, "message": msg}
            sess.add_rejected(label, msg)
            del img, data
        hint = None
        if sizes and not found_any:
            hint = self._probe_board(boardless)
        n_images = sum(1 for r in results if not (r or {}).get("skipped"))
        summary = (f"{kept} of {n_images} image{'s' if n_images != 1 else ''} kept"
                   if n_images else "No images in this upload (.jpg, .png …).")
        if sizes and not found_any:
            summary += f". No {sess.board.spec()} board was found in any of them"
            summary += f": {hint}" if hint else (
                f" — check that the whole board is visible and that it has "
                f"{sess.board.cols + 1}×{sess.board.rows + 1} squares")
        self._save()
        return {"summary": summary, "kept": kept, "files": results, "hint": hint}

    @staticmethod
    def _read(fh: BinaryIO) -> bytes | None:
        fh.seek(0)
        data = fh.read(MAX_UPLOAD_BYTES + 1)
        return None if len(data) > MAX_UPLOAD_BYTES else data

    def _upload_name(self, label: str) -> str:
        base = "upload-" + _safe_name(label)
        stem, suf = os.path.splitext(base)
        names = {v.name for v in self.session.views}
        cand, k = base, 2
        while cand in names or (self.images_dir / cand).exists():
            cand, k = f"{stem}-{k}{suf}", k + 1
        return cand

    def _plain_reason(self, fr: FrameResult) -> str:
        b = self.session.board
        if fr.detection is None:
            if fr.reasons and "image size" in fr.reasons[0]:
                return fr.reasons[0]
            return (f"no board found (looking for a chessboard with {b.cols}×{b.rows} inner "
                    f"corners, i.e. {b.cols + 1}×{b.rows + 1} squares, fully visible)")
        return "; ".join(fr.reasons) or "not usable"

    def _probe_board(self, grays: list[tuple[str, np.ndarray]]) -> str | None:
        """Which other chessboard size is visible (at most ~3 s)."""
        b = self.session.board
        if b.kind != "chessboard":
            return None
        # the usual printed boards first (each wrong size costs ~0.15 s), then near misses
        cands = [(9, 6), (7, 6), (8, 6), (7, 5), (6, 4), (10, 7), (11, 8), (8, 5)]
        cands += [(b.cols + dc, b.rows + dr) for dc in (-1, 0, 1, -2, 2)
                  for dr in (-1, 0, 1, -2, 2)
                  if (dc or dr) and b.cols + dc >= 3 and b.rows + dr >= 3]
        cands = [c for i, c in enumerate(cands) if c not in cands[:i] and c != (b.cols, b.rows)]
        deadline = time.monotonic() + 3.0
        for label, gray in grays:
            for c in cands:
                if time.monotonic() > deadline:
                    return None
                found, _ = cv2.findChessboardCorners(
                    gray, c, None, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                    | cv2.CALIB_CB_FAST_CHECK)
                if found:
                    return (f"a chessboard with {c[0]}×{c[1]} inner corners is visible in "
                            f"{label}: start a new session with that board size")
        return None

    # ----------------------------------------------------------------------- new session
    def new_session(self, board: str | None = None, square_m: float | None = None) -> None:
        try:
            b = parse_board(board or self.session.board.spec(),
                            square_m if square_m is not None else self.session.board.square)
        except BoardSpecError as e:
            raise ServiceError(str(e), 422) from None
        self._new_session(b)

    # ---------------------------------------------------------------------------- result
    def report(self) -> dict:
        sess = self.session
        res = sess.result
        if res is None:
            raise ServiceError(sess.last_error and f"The solve failed: {sess.last_error}"
                               or "Not solved yet.", 404)
        key = (self.session_id, self._gen, self._result_seq, id(res))
        with self._lock:
            if self._report_cache is not None and self._report_cache[0] == key:
                return self._report_cache[1]
        rep = build_report(sess)
        rep["current"] = sess.result_is_current
        rep["session_id"] = self.session_id
        rep["result_seq"] = self._result_seq
        with self._lock:
            self._report_cache = (key, rep)
        return rep

    def uncertainty_png(self) -> bytes:
        res = self.session.result
        if res is None:
            raise ServiceError("Not solved yet.", 404)
        key = (self.session_id, self._result_seq, id(res))
        with self._lock:
            if self._png_cache is not None and self._png_cache[0] == key:
                return self._png_cache[1]
        img = uncertainty_image(res, threshold_px=self.session.config.verdict
                                .max_uncertainty_p95_px)
        _, buf = cv2.imencode(".png", img)
        data = buf.tobytes()
        with self._lock:
            self._png_cache = (key, data)
        return data

    def camera_file(self, fmt: str = "opencv") -> tuple[bytes, str]:
        res = self.session.result
        if res is None:
            raise ServiceError("Not solved yet: there is no camera file to download.", 404)
        ext = {"opencv": ".yaml", "ros": ".ros.yaml", "json": ".json"}.get(fmt)
        if ext is None:
            raise ServiceError(f"unknown format {fmt!r}: use opencv, ros or json", 422)
        with tempfile.TemporaryDirectory() as d:
            p = save_camera(res.camera, Path(d) / f"camera{ext}", fmt=fmt)
            data = p.read_bytes()
        return data, f"camera-{self.session_id}{ext}"

    def use_result(self) -> dict:
        """Make the last result the server's current camera (``settings.camera``)."""
        res = self.session.result
        if res is None:
            raise ServiceError("Not solved yet: solve first, then use the calibration.", 409)
        path = self.folder / "camera.yaml"
        save_camera(res.camera, path)
        save_camera(res.camera, self.folder / "camera.ros.yaml", fmt="ros")
        self.settings.camera = path
        with self._lock:
            self.used_camera = str(path)
        self._save()
        # remembered for the next start of the web tool (webtool.app.create_app)
        atomic_write_bytes(self.root / IN_USE_FILE, json.dumps(
            {"camera_file": str(path), "session": self.session_id, "at": time.time()},
            indent=2).encode())
        return {"camera_file": str(path),
                "message": f"In use: this server's camera file is now {path}."}

    # ----------------------------------------------------------------------------- state
    def latest_frame(self, after: int = -1, wait: float = 1.0) -> tuple[bytes | None, int]:
        """The latest annotated frame (JPEG), waiting up to ``wait`` s for one newer than
        ``after``; (None, seq) when there is no live picture (camera lost or not started)."""
        deadline = time.monotonic() + wait
        with self._frame_cond:
            while (self._frame_seq <= after and self._camera.state in ("ok", "starting")
                   and not self._closed):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._frame_cond.wait(left)
            if self._camera.state != "ok":
                return None, self._frame_seq
            return self._latest_jpeg, self._frame_seq

    def state(self) -> dict:
        sess = self.session
        d = self._derived()
        cov, sug, verdict = d["coverage"], d["suggestion"], d["verdict"]
        res = sess.result
        rules = sess.config.verdict
        p95 = res.uncertainty.stats(sess.config.roi)["p95"] if res is not None else None
        n = len(sess.views)
        cam = self._camera
        solving = sess.solving
        current = sess.result_is_current
        if cam.state == "disconnected":
            nxt = ("The camera is disconnected. Check its cable or connection; Drovisio keeps "
                   "trying. " + _saved_views(n)).strip()
        elif n == 0:
            nxt = ("Hold the printed chessboard in front of the camera, the whole board "
                   "visible and still.")
        elif verdict.ok and current:
            nxt = ("The calibration is good: download the camera file, or press “Use this "
                   "calibration”." if self.show_result
                   else "The calibration is good. Press Solve to see the result.")
        else:
            nxt = sug.get("sentence", "")
        cov_json = cov.to_json()
        grid = cov_json["grid"]
        used = self.used_camera
        in_use = bool(used) and str(getattr(self.settings, "camera", "") or "") == used
        state = {
            "session": {"id": self.session_id, "folder": str(self.folder),
                        "board": sess.board.spec(), "square_mm": round(sess.board.square * 1000,
                                                                      3),
                        "cols": sess.board.cols, "rows": sess.board.rows,
                        "square_measured": self.square_measured,
                        "print_square_mm": _print_squares(sess.board),
                        "created": self.created, "source": self._source_label or (
                            "sample session (no camera)" if self.settings.source is None
                            else f"camera {self.settings.source}"),
                        "sample": self.settings.source is None},
            "camera": {"state": cam.state, "message": cam.message, "since": cam.since,
                       "frame_seq": self._frame_seq,
                       "image_size": list(sess.image_size or self._frame_size or (640, 480))},
            "auto_capture": self.auto_capture,
            "lens": {"model": sess.config.solve.model,
                     "solved_with": lens_key(res.camera) if res is not None else None,
                     "choice": res.model_choice if res is not None else None},
            "feedback": {k: v for k, v in self._feedback.items() if not k.startswith("_")},
            "generation": self._gen,
            "views": self._view_rows(),
            "coverage": {"cols": grid["cols"], "rows": grid["rows"],
                         "covered": grid["covered_fraction"],
                         "image_covered_fraction": round(cov.covered_fraction, 4),
                         "uncovered_regions": cov.uncovered_regions(),
                         "distance_spread": cov_json["distance_spread"],
                         "tilt_spread": cov_json["tilt_spread"]},
            "suggestion": sug,
            "progress": {"views": n, "views_needed": rules.min_views,
                         "solve_needs": sess.config.solve.min_views,
                         "covered_fraction": round(cov.covered_fraction, 4),
                         "p95_px": None if p95 is None else round(p95, 4),
                         "p95_limit_px": rules.max_uncertainty_p95_px,
                         "ok": bool(verdict.ok and current),
                         "reasons": list(verdict.reasons), "next": nxt},
            "solve": {"solving": solving, "has_result": res is not None, "current": current,
                      "error": None if res is not None or n < sess.config.solve.min_views
                      else sess.last_error,
                      "show_result": self.show_result, "result_seq": self._result_seq},
            "in_use": {"camera_file": str(self.settings.camera) if getattr(
                self.settings, "camera", None) else None, "this_session": in_use},
        }
        return _clean(state)
