"""The calibration page's server side: one live calibration session, fed by the server's camera.

A :class:`CalibrationService` per app (``app.state.calibration``, made on first use) owns:

* a **camera** (:mod:`webtool.calibration.camera`): the server's camera (``--source``: a V4L2
  index such as ``0``, shared with the live view, a stream URL or a video file, which loops), a
  folder of images, or — with no source — the sample calibration session played *as if live*
  (:class:`~drovisio.sources.PlaybackReader`), read by a :class:`~drovisio.sources.FrameSource`;
* a **worker thread** that takes the frames, offers each to the
  :class:`~drovisio.calibration.session.CalibrationSession` (auto-capture: sharp + still + novel
  frames are kept) or only detects the board (auto-capture off), draws the detected corners and
  keeps the latest frame as a JPEG for the page. When the camera gives no frame, the page is told
  "camera disconnected — retrying" and the source is reopened with a growing pause (0.5 s → 4 s);
  everything captured stays. The thread stops and releases the camera after ``idle_timeout`` s
  without a request (so the camera is free for other parts of the tool) and restarts on the next
  one;
* **persistence** (:mod:`webtool.calibration.store`): every kept view is written at once — its
  image first, then ``session.json`` — under ``calibration_dir/<session-id>/``. On start the
  last session of the same source is resumed; images that a crash left without an entry in
  ``session.json`` are detected again and added back. Deleted views are moved to ``deleted/``,
  not erased;
* **uploads** (:mod:`webtool.calibration.upload`): images taken elsewhere, each kept or
  rejected with a message;
* **solves in the background**: after each change (≥ the solve's minimum views) the session's own
  worker solves; the next-pose hint, the verdict and the report are derived from the latest
  solve and cached, so that requests never wait for a solve.

Tests give their own readers through ``source_factory``.
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from drovisio._threads import join_thread
from drovisio.calibration.board import BoardSpec, BoardSpecError, parse_board, to_gray
from drovisio.calibration.report import _clean
from drovisio.calibration.session import CalibrationSession, FrameResult, SessionConfig
from drovisio.calibration.solve import MODEL_CHOICES, SolveOptions
from drovisio.calibration.uncertainty import lens_key
from drovisio.calibration.verdict import Verdict
from drovisio.camera import Camera
from drovisio.camera_file import load_camera, save_camera
from drovisio.errors import InputError
from drovisio.images import ImageError, read_image
from drovisio.sources import Reader
from webtool.calibration import page_state, results, store
from webtool.calibration.camera import default_source_factory, source_label
from webtool.calibration.feed import CameraFeed
from webtool.calibration.feedback import frame_feedback, next_step, plain_reason
from webtool.calibration.pictures import decode, draw_corners, jpeg, png, thumbnail_jpeg
from webtool.calibration.results import KeyedCache
from webtool.calibration.store import (
    SESSION_SCHEMA,
    atomic_write_bytes,
    camera_in_use,
    default_calibration_dir,
)
from webtool.calibration.upload import (
    Row,
    measure,
    probe_board,
    read_upload,
    summary,
    target_size,
    upload_label,
    wrong_size,
)
from webtool.errors import BadInput, Conflict, DiskFull, NotFound

__all__ = [
    "SESSION_SCHEMA",
    "CalibrationService",
    "atomic_write_bytes",
    "camera_in_use",
    "default_calibration_dir",
]

log = logging.getLogger(__name__)


class CalibrationService:
    """See the module docstring.

    Args:
        settings: The web tool's :class:`~webtool.settings.Settings` (``calibration_dir``,
            board, source, sample playback speed; ``camera`` is set by :meth:`use_result`).
        source_factory: Makes a frame source (default: from ``settings``).
        idle_timeout: Seconds without a request after which the camera is released.
    """

    def __init__(self, settings: Any, source_factory: Callable[[], Reader] | None = None,
                 idle_timeout: float = 45.0) -> None:
        self.settings = settings
        self.root = store.calibration_root(settings)
        self.source_key = source_label(settings)
        self._lock = threading.RLock()        # session swap, state file, caches
        self._keep_lock = threading.RLock()   # offering / adding views and persisting them
        self._feed = CameraFeed(source_factory or default_source_factory(settings),
                                self._process, lambda: len(self.session.views),
                                self._read_error, idle_timeout)
        self._feedback: dict[str, Any] = frame_feedback(None, True)
        self._gen = 0                 # bumps whenever the kept views change
        self._result_seq = 0          # bumps whenever a solve finishes
        self._solve_pending = False
        self._derived_cache: KeyedCache[dict[str, Any]] = KeyedCache()
        self._report_cache: KeyedCache[dict[str, Any]] = KeyedCache()
        self._png_cache: KeyedCache[bytes] = KeyedCache()
        self._thumbs: dict[tuple[str, int], bytes] = {}
        self._capture_counter = 1
        self._closed = False
        self._closers: list[threading.Thread] = []   # previous sessions closing (see close)
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
        for sid in store.session_candidates(self.root):
            if sid and self._try_resume(sid):
                return
        self._new_session(self._board_from_settings())

    def _read_saved(self, sid: str) -> tuple[dict[str, Any], CalibrationSession] | None:
        """The saved session ``sid`` of this source, or None (another source's, or broken:
        then set aside and said on the page)."""
        path = self.root / sid / "session.json"
        try:
            data = store.read_session_file(path)
            if data.get("schema") != SESSION_SCHEMA or data.get("source") != self.source_key:
                return None
            sess = CalibrationSession.from_state(data["session"], self._config(sid),
                                                 self._camera_guess())
            store.check_view_names(sess)
        except (OSError, ValueError, KeyError, TypeError) as e:
            store.set_aside_broken(path)
            self._feedback = {**frame_feedback(None, True),
                              "message": f"Session {sid} could not be read ({e}); started anew."}
            return None
        return data, sess

    def _try_resume(self, sid: str) -> bool:
        folder = self.root / sid
        if not (folder / "session.json").is_file():
            return False
        saved = self._read_saved(sid)
        if saved is None:
            return False
        data, sess = saved
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
        self._gen += store.recover_orphans(self.session, self.images_dir)
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
            self._retire(old)

    def _retire(self, old: CalibrationSession) -> None:
        """Close a previous session aside (it waits for its solve in progress, which a new
        session's page need not); :meth:`close` waits for it."""
        with self._lock:
            self._closers = [t for t in self._closers if t.is_alive()]
            if not self._closed:
                t = threading.Thread(target=old.close, daemon=True,
                                     name="calibration-session-close")
                self._closers.append(t)
                t.start()
                return
        old.close()

    def _after_session_change(self) -> None:
        self._gen += 1
        for cache in (self._derived_cache, self._report_cache, self._png_cache):
            cache.clear()
        self._thumbs.clear()
        self._capture_counter = store.next_capture_number(self.folder)
        atomic_write_bytes(self.root / "current", self.session_id.encode())

    def _save(self) -> None:
        """Write session.json atomically (after the images it names)."""
        with self._lock:
            store.write_session_file(self.folder, {
                "schema": SESSION_SCHEMA, "id": self.session_id, "created": self.created,
                "saved": time.time(), "source": self.source_key,
                "auto_capture": self.auto_capture, "show_result": self.show_result,
                "square_measured": self.square_measured,
                "lens_model": self.session.config.solve.model,
                "used_camera": self.used_camera, "session": self.session.state()})

    # ----------------------------------------------------------------------- camera
    @property
    def idle_timeout(self) -> float:
        return self._feed.idle_timeout

    def touch(self) -> None:
        """A request came in: keep the camera running (start it if it was stopped)."""
        self._feed.touch()

    def close(self) -> None:
        """Stop the camera and the session's solver, and wait for previous sessions to
        close (app shutdown): no solve is left in OpenCV as the interpreter exits."""
        with self._lock:
            self._closed = True
            closers, self._closers = self._closers, []
        self._feed.close()
        self.session.close()
        for t in closers:
            join_thread(t, "closing a previous calibration session (its solve)")

    @property
    def camera_message(self) -> str:
        """What the camera is doing, for people ("Camera disconnected — retrying…")."""
        return self._feed.message

    def _read_error(self, error: str) -> None:
        self._feedback = {**self._feedback, "detail": error}

    def _offer(self, frame: np.ndarray) -> tuple[CalibrationSession, FrameResult | None, bool]:
        """Offer a camera frame to the session (kept when auto-capture is on and it passes
        the gates) or only detect the board: (session, what happened, auto-capture)."""
        with self._keep_lock:
            sess = self.session
            auto = self.auto_capture
            if not auto:
                return sess, sess.evaluate(frame), auto
            fr: FrameResult | None = sess.offer_frame(
                frame, f"capture-{self._capture_counter:04d}.png")
            if fr is not None and fr.kept:
                self._capture_counter += 1
                if not self._persist_view(sess, fr, png(frame)):
                    fr = None
            return sess, fr, auto

    def _process(self, frame: np.ndarray) -> None:
        sess, fr, auto = self._offer(frame)
        annotated = frame.copy()
        if fr is not None:
            draw_corners(annotated, sess.board, fr.detection,
                         (0, 220, 0) if fr.usable else (0, 140, 255))
        self._feed.publish(frame, jpeg(annotated), lambda: self._show_feedback(fr, auto))

    def _show_feedback(self, fr: FrameResult | None, auto: bool) -> None:
        if fr is None:
            return
        fb = frame_feedback(fr, auto)
        # a capture message stays readable for a moment
        if not (self._feedback.get("kept") and not fb["kept"]
                and time.monotonic() - self._feedback.get("_at", 0) < 1.5):
            self._feedback = {**fb, "_at": time.monotonic()}

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
            if fr.view_id is not None:
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

    def _solved(self, sess: CalibrationSession, fut: Future[Any]) -> None:
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

    def request_solve(self) -> dict[str, Any]:
        """The page's Solve button: show the result, solving first if needed."""
        sess = self.session
        n = len(sess.views)
        need = sess.config.solve.min_views
        if n < need:
            raise Conflict(f"Keep going: a solve needs at least {need} views and you have "
                               f"{n}. Show the board at the place shown in yellow.")
        with self._lock:
            self.show_result = True
        self._save()
        if not sess.result_is_current and not sess.solving:
            self._maybe_solve()
        return {"solving": sess.solving or not sess.result_is_current,
                "has_result": sess.result is not None}

    # -------------------------------------------------------------------------- derived
    def _derived(self) -> dict[str, Any]:
        """Coverage, next-pose hint and verdict of the current views and solve (cached)."""
        sess = self.session
        key = (self.session_id, self._gen, self._result_seq, id(sess.result))
        hit = self._derived_cache.get(key)
        if hit is not None:
            return hit
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
        return self._derived_cache.put(key, {"coverage": cov, "suggestion": sug,
                                             "verdict": verdict})

    # ----------------------------------------------------------------------------- views
    def _view_rows(self) -> list[dict[str, Any]]:
        with self._keep_lock:  # a view is listed once its image is on disk
            sess = self.session
            views = sess.views
        return page_state.view_rows(views, sess.result, self.session_id)

    def thumbnail(self, view_id: int) -> bytes:
        key = (self.session_id, int(view_id))
        if key in self._thumbs:
            return self._thumbs[key]
        v = next((v for v in self.session.views if v.id == view_id), None)
        if v is None:
            raise NotFound(f"view #{view_id} is not in this session")
        try:
            img: np.ndarray | None = read_image(self.images_dir / store.safe_name(v.name))[0]
        except ImageError:
            img = None
        data = thumbnail_jpeg(img, self.session.board, v.detection)
        if img is not None:  # only the corners, on grey: not cached (the image may be coming)
            self._thumbs[key] = data
        return data

    def delete_view(self, view_id: int) -> None:
        with self._keep_lock:
            sess = self.session
            v = next((v for v in sess.views if v.id == view_id), None)
            if v is None or not sess.remove_view(view_id):
                raise NotFound(f"view #{view_id} is not in this session")
            store.move_to_deleted(self.folder, v.name)
            with self._lock:
                self._gen += 1
                self._thumbs.pop((self.session_id, view_id), None)
            self._save()
        self._maybe_solve()

    def set_auto(self, on: bool) -> None:
        with self._lock:
            self.auto_capture = bool(on)
        self._save()

    def set_square(self, square_m: float) -> dict[str, Any]:
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

    def set_lens_model(self, model: str) -> dict[str, Any]:
        """The page's lens choice: solve again with it (when there is enough to solve)."""
        self.session.set_model(model)
        self._save()
        if len(self.session.views) >= self.session.config.solve.min_views:
            self._maybe_solve()
        return {"lens_model": model}

    def capture(self) -> dict[str, Any]:
        """Keep the current camera frame (the manual Capture button)."""
        # a camera that has given no frame for 3 s is not "right now"; a busy machine that is
        # slow to process the frames it gives is
        frame, waited = self._feed.latest()
        if frame is None or self._feed.status.state != "ok" or waited > 3.0:
            raise Conflict("No picture from the camera right now, so nothing to capture. "
                           + (self._feed.message or ""))
        with self._keep_lock:
            sess = self.session
            name = f"capture-{self._capture_counter:04d}.png"
            fr = sess.evaluate(frame, name, still=True)   # the user chose this picture
            dup = sess.duplicate_of(fr.detection) \
                if fr.usable and fr.detection is not None else None
            if dup is not None:
                raise Conflict(f"This view is already kept (view #{dup}): move the board "
                               "first.")
            fr = sess.keep(fr) if fr.usable else fr
            if not fr.kept:
                raise BadInput(frame_feedback(fr, False)["message"] + (
                    f" ({'; '.join(fr.reasons)})" if fr.reasons else ""))
            self._capture_counter += 1
            if not self._persist_view(sess, fr, png(frame)):
                raise DiskFull(self._feedback["message"])
        self._feedback = {**frame_feedback(fr, False), "_at": time.monotonic()}
        return {"view_id": fr.view_id, "message": f"Captured view #{fr.view_id}."}

    # ---------------------------------------------------------------------------- upload
    def upload(self, files: Iterable[tuple[str, BinaryIO]]) -> dict[str, Any]:
        """Images taken elsewhere: each kept (detected, sharp, right size) or rejected with a
        message. Reads the files twice (sizes first) so that big folders never sit decoded in
        memory at once."""
        files = list(files)
        results, sizes = measure(files, self.session)
        sess = self.session
        target = target_size(sess.image_size, sizes)
        mixed = len(set(sizes.values())) > 1
        kept = 0
        found_any = False
        boardless: list[tuple[str, np.ndarray]] = []
        for i, size in sizes.items():
            name, fh = files[i]
            label = upload_label(name, i)
            if target is not None and tuple(size) != tuple(target):
                msg = wrong_size(size, target, mixed=mixed,
                                 session_sized=sess.image_size is not None)
                results[i] = {"file": label, "ok": False, "message": msg}
                sess.add_rejected(label, msg)
                continue
            row, fr, img = self._take_upload(sess, label, fh)
            results[i] = row
            kept += bool(row["ok"])
            if fr.detection is not None:
                found_any = True
            elif len(boardless) < 3:
                boardless.append((label, to_gray(img)))
            del img
        no_board = bool(sizes) and not found_any
        hint = probe_board(self.session.board, boardless) if no_board else None
        text = summary(results, kept, no_board, sess.board, hint)
        self._save()
        return {"summary": text, "kept": kept, "files": results, "hint": hint}

    def _take_upload(self, sess: CalibrationSession, label: str, fh: BinaryIO
                     ) -> tuple[Row, FrameResult, np.ndarray]:
        """The second pass over one uploaded image of the right size: detected, judged, kept
        or rejected: (its answer row, what happened, the image)."""
        data = read_upload(fh)
        img = decode(data, label)[0] if data is not None else None
        if data is None or img is None:  # the first pass read and decoded this very file
            raise RuntimeError(f"{label} changed during the upload")
        fr = sess.evaluate(img, self._upload_name(label), still=True)
        msg = None
        if fr.usable and fr.detection is not None:
            with self._keep_lock:
                if sess is not self.session:
                    raise Conflict("A new session was started during the upload.")
                # named where it is written: uploads of one name at once each get their own
                fr.name = self._upload_name(label)
                dup = sess.duplicate_of(fr.detection)
                if dup is not None:
                    msg = f"already in this session (the same picture as view #{dup})"
                else:
                    fr = sess.keep(fr)
                    if fr.kept and self._persist_view(sess, fr, data):
                        n = fr.detection.n if fr.detection is not None else 0
                        return {"file": label, "ok": True, "view_id": fr.view_id,
                                "message": f"kept as view #{fr.view_id} ({n} corners)"}, fr, img
                    msg = self._feedback.get("message") if fr.kept else None
        msg = msg or plain_reason(fr, self.session.board)
        sess.add_rejected(label, msg)
        return {"file": label, "ok": False, "message": msg}, fr, img

    def _upload_name(self, label: str) -> str:
        return store.unique_upload_name(label, (v.name for v in self.session.views),
                                        self.images_dir)

    # ----------------------------------------------------------------------- new session
    def new_session(self, board: str | None = None, square_m: float | None = None) -> None:
        try:
            b = parse_board(board or self.session.board.spec(),
                            square_m if square_m is not None else self.session.board.square)
        except BoardSpecError as e:
            raise BadInput(str(e)) from None
        self._new_session(b)

    # ---------------------------------------------------------------------------- result
    def report(self) -> dict[str, Any]:
        sess = self.session
        res = sess.result
        if res is None:
            raise NotFound(sess.last_error and f"The solve failed: {sess.last_error}"
                           or "Not solved yet.")
        key = (self.session_id, self._gen, self._result_seq, id(res))
        hit = self._report_cache.get(key)
        if hit is not None:
            return hit
        return self._report_cache.put(key, results.report(sess, self.session_id,
                                                          self._result_seq))

    def uncertainty_png(self) -> bytes:
        res = self.session.result
        if res is None:
            raise NotFound("Not solved yet.")
        key = (self.session_id, self._result_seq, id(res))
        hit = self._png_cache.get(key)
        if hit is not None:
            return hit
        return self._png_cache.put(key, results.uncertainty_png(
            res, self.session.config.verdict.max_uncertainty_p95_px))

    def camera_file(self, fmt: str = "opencv") -> tuple[bytes, str]:
        res = self.session.result
        if res is None:
            raise NotFound("Not solved yet: there is no camera file to download.")
        got = results.camera_file_bytes(res.camera, fmt)
        if got is None:
            raise BadInput(f"unknown format {fmt!r}: use opencv, ros or json")
        data, ext = got
        return data, f"camera-{self.session_id}{ext}"

    def use_result(self) -> dict[str, Any]:
        """Make the last result the server's current camera (``settings.camera``)."""
        res = self.session.result
        if res is None:
            raise Conflict("Not solved yet: solve first, then use the calibration.")
        path = self.folder / "camera.yaml"
        save_camera(res.camera, path)
        save_camera(res.camera, self.folder / "camera.ros.yaml", fmt="ros")
        self.settings.camera = path
        with self._lock:
            self.used_camera = str(path)
        self._save()
        # remembered for the next start of the web tool (webtool.app.create_app)
        store.remember_in_use(self.root, path, self.session_id)
        return {"camera_file": str(path),
                "message": f"In use: this server's camera file is now {path}."}

    # ----------------------------------------------------------------------------- state
    async def latest_frame(self, after: int = -1, wait: float = 1.0) -> tuple[bytes | None, int]:
        """The latest annotated frame (JPEG), waiting up to ``wait`` s for one newer than
        ``after`` (on the event loop); (None, seq) when there is no live picture (camera lost
        or not started)."""
        return await self._feed.latest_frame(after, wait)

    def state(self) -> dict[str, Any]:
        """Everything the page shows (see ``GET /api/calibration/state``)."""
        sess = self.session
        d = self._derived()
        cov, sug, verdict = d["coverage"], d["suggestion"], d["verdict"]
        res = sess.result
        n = len(sess.views)
        current = sess.result_is_current
        good = bool(verdict.ok and current)
        nxt = next_step(disconnected=self._feed.status.state == "disconnected", views=n,
                        good=good, show_result=self.show_result, suggestion=sug)
        state = {
            "session": page_state.session_json(
                sess, self.session_id, self.folder, self.created, self._feed.source_label,
                self.settings.source, square_measured=self.square_measured),
            "camera": page_state.camera_json(self._feed.status, self._feed.seq,
                                             sess.image_size or self._feed.frame_size),
            "auto_capture": self.auto_capture,
            "lens": {"model": sess.config.solve.model,
                     "solved_with": lens_key(res.camera) if res is not None else None,
                     "choice": res.model_choice if res is not None else None},
            "feedback": {k: v for k, v in self._feedback.items() if not k.startswith("_")},
            "generation": self._gen,
            "views": self._view_rows(),
            "coverage": page_state.coverage_json(cov),
            "suggestion": sug,
            "progress": page_state.progress_json(sess, n, cov, verdict, good, nxt),
            "solve": {"solving": sess.solving, "has_result": res is not None,
                      "current": current,
                      "error": None if res is not None or n < sess.config.solve.min_views
                      else sess.last_error,
                      "show_result": self.show_result, "result_seq": self._result_seq},
            "in_use": page_state.in_use_json(self.used_camera,
                                             getattr(self.settings, "camera", None)),
        }
        return _clean(state)
