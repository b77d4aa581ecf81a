"""A calibration session: views added one at a time, queried at any moment, solved in the
background. Used by ``drovisio calibrate`` (a folder of images) and the web page (a live camera).

Typical live use::

    s = CalibrationSession(parse_board("chessboard:9x6", 0.025))
    for frame in camera:
        r = s.offer_frame(frame)          # detect + gates (sharp, still, novel) → auto-keep
        draw(r.detection, s.coverage(), s.suggestion())
        if r.kept:
            s.solve_async()               # non-blocking; s.result when done
    s.verdict(), s.report()

Thread safety: every public method may be called from any thread. Views are guarded by a lock;
a solve works on a snapshot and runs in the session's single worker thread
(:meth:`solve_async`), so the caller never blocks on it. ``result_is_current`` tells whether the
last result includes every kept view.

The session holds no images, only detections (a few kB per view). Persisting the images and
:meth:`state` is the caller's business; :meth:`from_state` resumes a session.
"""

from __future__ import annotations

import concurrent.futures
import math
import threading
import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from drovisio.calibration.board import BoardSpec, Detection, detect, parse_board, to_gray
from drovisio.calibration.coverage import Coverage, compute_coverage
from drovisio.calibration.gates import (
    MAX_EDGE_WIDTH_PX,
    MAX_MOTION_PX,
    NOVELTY_FRACTION,
    NOVELTY_TILT_DEG,
    EdgeSharpness,
    GateResult,
    gate_novel,
    gate_sharpness,
    gate_size,
    gate_still,
)
from drovisio.calibration.geometry import board_pose_summary
from drovisio.calibration.report import build_report
from drovisio.calibration.solve import (
    MODELS,
    CalibrationError,
    CalibrationResult,
    SolveOptions,
    ViewInput,
    solve,
    unknown_model,
)
from drovisio.calibration.suggest import Suggestion, suggest_next_pose
from drovisio.calibration.verdict import Verdict, VerdictRules, judge
from drovisio.camera import Camera

__all__ = ["CalibrationSession", "SessionConfig", "View", "FrameCheck", "FrameResult"]


@dataclass
class SessionConfig:
    """Thresholds of a session (defaults: the documented rules of each module)."""

    max_edge_width_px: float = MAX_EDGE_WIDTH_PX
    max_motion_px: float = MAX_MOTION_PX
    novelty_fraction: float = NOVELTY_FRACTION
    novelty_tilt_deg: float = NOVELTY_TILT_DEG
    solve: SolveOptions = field(default_factory=SolveOptions)
    verdict: VerdictRules = field(default_factory=VerdictRules)
    roi: tuple[float, float, float, float] | None = None
    """Image region the detector uses (x0, y0, x1, y1); None: the whole image."""
    camera_name: str = "camera"


@dataclass
class View:
    """A kept view."""

    id: int
    name: str
    detection: Detection
    gates: list[GateResult] = field(default_factory=list)
    edge_width_px: float = math.nan
    added_at: float = field(default_factory=time.time)

    def to_json(self) -> dict:
        return {"id": self.id, "name": self.name, "detection": self.detection.to_json(),
                "gates": [g.to_json() for g in self.gates],
                "edge_width_px": None if not math.isfinite(self.edge_width_px)
                else round(self.edge_width_px, 3), "added_at": self.added_at}

    @classmethod
    def from_json(cls, d: dict) -> View:
        ew = d.get("edge_width_px")
        return cls(int(d["id"]), str(d["name"]), Detection.from_json(d["detection"]),
                   [GateResult(g["gate"], g["ok"], math.nan if g["value"] is None
                               else g["value"], math.nan if g["limit"] is None else g["limit"],
                               g.get("reason", "")) for g in d.get("gates", [])],
                   math.nan if ew is None else float(ew), float(d.get("added_at", 0.0)))


@dataclass
class FrameCheck:
    """What happened to one image or frame offered to the calibration: its detection, its
    gates, kept or why not."""

    name: str
    detection: Detection | None
    gates: list[GateResult]
    kept: bool = False
    view_id: int | None = None
    reasons: list[str] = field(default_factory=list)
    """Why it was not kept (empty when kept)."""
    sharpness: EdgeSharpness | None = None
    image_size: tuple[int, int] | None = None

    @property
    def usable(self) -> bool:
        """Detected and passed the per-image gates (size, sharpness)."""
        return self.detection is not None and all(
            g.ok for g in self.gates if g.name in ("size", "sharpness"))

    def to_json(self) -> dict:
        return {"name": self.name, "detected": self.detection is not None,
                "corners": None if self.detection is None else self.detection.n,
                "kept": self.kept, "view_id": self.view_id, "reasons": list(self.reasons),
                "gates": [g.to_json() for g in self.gates]}


#: The former name, still imported by the web tool's calibration page (the detector's
#: :class:`drovisio.detect.result.FrameResult` is another thing).
FrameResult = FrameCheck


class CalibrationSession:
    """See the module docstring.

    Args:
        board: The calibration target.
        image_size: (width, height); taken from the first image if None.
        config: Thresholds.
        camera_guess: A camera to estimate board poses with before the first solve (tilts and
            distances for coverage, novelty and hints); default: a 60° pinhole.
    """

    def __init__(self, board: BoardSpec, image_size: tuple[int, int] | None = None,
                 config: SessionConfig | None = None, camera_guess: Camera | None = None):
        self.board = board
        self.config = config or SessionConfig()
        self._size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        self._guess = camera_guess
        self._lock = threading.RLock()
        self._views: list[View] = []
        self._rejected: list[dict] = []
        self._next_id = 0
        self._generation = 0  # bumped whenever the kept views change
        self._previous: Detection | None = None
        self._result: CalibrationResult | None = None
        self._result_generation = -1
        self._result_error: str | None = None
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._future: concurrent.futures.Future | None = None
        self._suggestion_cache: tuple[int, Suggestion] | None = None

    # ------------------------------------------------------------------------ properties
    @property
    def image_size(self) -> tuple[int, int] | None:
        return self._size

    @property
    def views(self) -> list[View]:
        with self._lock:
            return list(self._views)

    @property
    def rejected(self) -> list[dict]:
        with self._lock:
            return list(self._rejected)

    @property
    def result(self) -> CalibrationResult | None:
        """The last finished solve (possibly older than the current views)."""
        with self._lock:
            return self._result

    @property
    def result_is_current(self) -> bool:
        with self._lock:
            return self._result is not None and self._result_generation == self._generation

    @property
    def solving(self) -> bool:
        f = self._future
        return f is not None and not f.done()

    @property
    def last_error(self) -> str | None:
        """Why the last solve failed (None if it succeeded)."""
        return self._result_error

    # ------------------------------------------------------------------------ adding views
    def evaluate(self, image: np.ndarray, name: str = "", still: bool = False) -> FrameCheck:
        """Detect the board and apply the per-image gates (size, sharpness). Changes nothing.

        ``still``: a still image said to hold the board, searched further than a live frame
        (:func:`drovisio.calibration.board.detect`)."""
        gray = to_gray(image)
        h, w = gray.shape
        fr = FrameCheck(name, None, [], image_size=(w, h))
        if self._size is not None and (w, h) != self._size:
            fr.reasons.append(f"image size {w}x{h} differs from the session's "
                              f"{self._size[0]}x{self._size[1]} (intrinsics belong to one "
                              "resolution)")
            return fr
        det = detect(gray, self.board, still=still)
        if det is None:
            fr.reasons.append(f"no {self.board.spec()} board found")
            return fr
        fr.detection = det
        g_size = gate_size(det)
        g_sharp, es = gate_sharpness(gray, det, self.board, self.config.max_edge_width_px)
        fr.gates += [g_size, g_sharp]
        fr.sharpness = es
        fr.reasons += [g.reason for g in (g_size, g_sharp) if not g.ok]
        return fr

    def add_image(self, image: np.ndarray, name: str | None = None) -> FrameCheck:
        """Add a still image (a file, a manual capture): kept when detected, big enough and
        sharp. No stillness or novelty check."""
        fr = self.evaluate(image, name or f"capture-{self._next_id:03d}", still=True)
        return self.keep(fr) if fr.usable else self._reject(fr)

    def offer_frame(self, image: np.ndarray, name: str | None = None) -> FrameCheck:
        """A live frame: kept automatically when detected, sharp, still since the previous
        frame and novel against the kept views."""
        fr = self.evaluate(image, name or f"capture-{self._next_id:03d}")
        with self._lock:
            prev, self._previous = self._previous, fr.detection
        if fr.detection is None:
            return fr
        still = gate_still(prev, fr.detection, self.config.max_motion_px)
        fr.gates.append(still)
        if not still.ok:
            fr.reasons.append(still.reason)
        if not fr.usable or not still.ok:
            return fr
        novel = self._novelty(fr.detection)
        fr.gates.append(novel)
        if not novel.ok:
            fr.reasons.append(novel.reason)
            return fr
        return self.keep(fr)

    def _novelty(self, det: Detection) -> GateResult:
        with self._lock:
            kept = [v.detection for v in self._views]
        cam = self.camera_estimate()
        tilt = self._pose(det, cam)
        kept_tilts = [self._pose(k, cam) for k in kept]
        return gate_novel(det, kept, None if tilt is None else tilt[1],
                          [None if t is None else t[1] for t in kept_tilts],
                          self.config.novelty_fraction, self.config.novelty_tilt_deg)

    def duplicate_of(self, det: Detection, tol_px: float = 0.5) -> int | None:
        """The id of a kept view showing the board where ``det`` does (the same corners
        within ``tol_px`` on average): the same picture twice adds no information but makes
        the solve look certain."""
        with self._lock:
            views = list(self._views)
        for v in views:
            d = v.detection
            if d.n == det.n and np.array_equal(d.ids, det.ids) and \
                    float(np.mean(np.hypot(*(d.corners - det.corners).T))) < tol_px:
                return v.id
        return None

    def keep(self, fr: FrameCheck) -> FrameCheck:
        """Keep an evaluated frame as a view (also used for a manual capture)."""
        if fr.detection is None:
            raise ValueError("cannot keep a frame without a detection")
        with self._lock:
            if self._size is None:
                self._size = fr.detection.image_size
            elif tuple(fr.detection.image_size) != self._size:
                fr.reasons.append("image size differs from the session's")
                return self._reject(fr)
            v = View(self._next_id, fr.name, fr.detection, list(fr.gates),
                     fr.sharpness.width_px if fr.sharpness else math.nan)
            self._next_id += 1
            self._views.append(v)
            self._generation += 1
        fr.kept, fr.view_id, fr.reasons = True, v.id, []
        return fr

    def _reject(self, fr: FrameCheck) -> FrameCheck:
        with self._lock:
            self._rejected.append({"file": fr.name, "reason": "; ".join(fr.reasons)
                                   or "not usable"})
        return fr

    def add_rejected(self, name: str, reason: str) -> None:
        """Record an input that could not be used at all (unreadable file...)."""
        with self._lock:
            self._rejected.append({"file": name, "reason": reason})

    def set_model(self, model: str) -> None:
        """The lens model of the next solves (one of
        :data:`drovisio.calibration.solve.MODEL_CHOICES`); a result of another model is no
        longer current."""
        if model != "auto" and model not in MODELS:
            raise CalibrationError(unknown_model(model))
        with self._lock:
            if self.config.solve.model != model:
                self.config.solve = replace(self.config.solve, model=model)
                self._generation += 1

    def set_square(self, square_m: float) -> None:
        """The board's square size as measured on the print (metres). The views stay: the
        size scales the board poses only, never the intrinsics; the result is solved again."""
        with self._lock:
            if abs(square_m - self.board.square) > 1e-12:
                self.board = parse_board(self.board.spec(), square_m)
                self._generation += 1

    def remove_view(self, view_id: int) -> bool:
        with self._lock:
            n = len(self._views)
            self._views = [v for v in self._views if v.id != view_id]
            if len(self._views) != n:
                self._generation += 1
                return True
            return False

    # ------------------------------------------------------------------------ estimates
    def camera_estimate(self) -> Camera:
        """The best camera known now: last solve, else a homography-based guess from the kept
        views (3 or more), else ``camera_guess``, else a 60° pinhole."""
        with self._lock:
            if self._result is not None:
                return self._result.camera
            views = list(self._views)
            size = self._size
        if size is None:
            return self._guess or Camera.from_fov(640, 480, 60.0)
        if self._guess is not None and self._guess.size == size:
            base = self._guess
        else:
            base = Camera.from_fov(size[0], size[1], 60.0)
        if len(views) >= 3:
            try:
                obj = self.board.object_points()
                K = cv2.initCameraMatrix2D(
                    [obj[v.detection.ids].astype(np.float32) for v in views],
                    [v.detection.corners.astype(np.float32) for v in views], size)
                if np.all(np.isfinite(K)) and 0.2 * base.fx < K[0, 0] < 5 * base.fx:
                    return Camera(K=K, dist=np.zeros(5), width=size[0], height=size[1])
            except cv2.error:
                pass
        return base

    def _pose(self, det: Detection, cam: Camera) -> tuple[float, float] | None:
        obj = self.board.object_points()[det.ids]
        xn = cam.normalize(det.corners)    # every lens model: PnP on normalised points
        if not np.all(np.isfinite(xn)):
            return None
        ok, rvec, tvec = cv2.solvePnP(obj, xn, np.eye(3), None)
        if not ok:
            return None
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = np.asarray(tvec).ravel()
        return board_pose_summary(T, self.board)

    def _poses(self, views: list[View]) -> list[tuple[float, float]]:
        res = self.result
        out = []
        fits = {}
        if res is not None:
            fits = {f.name: f for f in res.per_view}
        cam = self.camera_estimate()
        for v in views:
            f = fits.get(v.name)
            if f is not None:
                T = np.eye(4)
                T[:3, :3] = cv2.Rodrigues(f.rvec)[0]
                T[:3, 3] = f.tvec
                out.append(board_pose_summary(T, self.board))
            else:
                p = self._pose(v.detection, cam)
                out.append(p if p is not None else (math.nan, math.nan))
        return out

    # ------------------------------------------------------------------------ queries
    def coverage(self, grid: tuple[int, int] = (8, 6)) -> Coverage:
        views = self.views
        size = self._size or (640, 480)
        return compute_coverage([v.detection for v in views], size, self._poses(views), grid)

    def view_inputs(self) -> list[ViewInput]:
        obj = self.board.object_points()
        return [ViewInput(v.name, v.detection.corners, obj[v.detection.ids]) for v in self.views]

    def solve(self) -> CalibrationResult:
        """Solve now, in the calling thread; stores and returns the result.

        Raises:
            CalibrationError: too few or degenerate views.
        """
        with self._lock:
            gen = self._generation
            inputs = self.view_inputs()
            size = self._size
        if size is None or not inputs:
            self._result_error = "no views kept yet"
            raise CalibrationError("no views kept yet: show the board to the camera")
        opt = self.config.solve
        if self.config.roi is not None and opt.roi is None:
            opt = SolveOptions(**{**opt.__dict__, "roi": self.config.roi})
        try:
            res = solve(inputs, size, opt, camera_name=self.config.camera_name)
        except CalibrationError as e:
            self._result_error = str(e)
            raise
        with self._lock:
            if gen >= self._result_generation:
                self._result, self._result_generation = res, gen
                self._result_error = None
                self._suggestion_cache = None
        return res

    def solve_async(self, callback=None) -> concurrent.futures.Future:
        """Solve in the session's worker thread; returns a Future of the result (or of the
        :class:`CalibrationError`). ``callback(future)`` is called when done."""
        with self._lock:
            if self._executor is None:
                self._executor = concurrent.futures.ThreadPoolExecutor(
                    max_workers=1, thread_name_prefix="calibration-solve")
            fut = self._executor.submit(self.solve)
            self._future = fut
        if callback is not None:
            fut.add_done_callback(callback)
        return fut

    def verdict(self) -> Verdict:
        """The verdict on the last solve (see :mod:`verdict`)."""
        res = self.result
        region = None
        if res is not None:
            try:
                region = self.suggestion().region
            except ValueError:
                region = None
        return judge(res, self.coverage(), self.config.verdict, self.config.roi,
                     n_views=len(self._views), suggested_region=region)

    def suggestion(self) -> Suggestion:
        """Where to put the board next (see :mod:`suggest`); cached per solve."""
        with self._lock:
            res = self._result
            gen = self._result_generation
            cache = self._suggestion_cache
        if res is not None and cache is not None and cache[0] == gen:
            return cache[1]
        cam = self.camera_estimate()
        if res is None:
            return suggest_next_pose(cam, self.board, self.coverage())
        s = suggest_next_pose(cam, self.board, self.coverage(), res.views, res.per_view,
                              res.model.sigma2, self.config.roi,
                              self.config.solve.grid_step_px, res.model.free)
        with self._lock:
            if self._result_generation == gen:
                self._suggestion_cache = (gen, s)
        return s

    def report(self) -> dict:
        """The report dict (see :func:`drovisio.calibration.report.build_report`)."""
        return build_report(self)

    # ------------------------------------------------------------------------ persistence
    def state(self) -> dict:
        """JSON-serialisable state: board, size, kept views (detections), rejected inputs."""
        with self._lock:
            return {"schema": "drovisio/calibration-session@1", "board": self.board.to_json(),
                    "image_size": None if self._size is None else list(self._size),
                    "next_id": self._next_id, "views": [v.to_json() for v in self._views],
                    "rejected": list(self._rejected)}

    @classmethod
    def from_state(cls, state: dict, config: SessionConfig | None = None,
                   camera_guess: Camera | None = None) -> CalibrationSession:
        b = state["board"]
        s = cls(parse_board(b["spec"], b["square_m"]), state.get("image_size"), config,
                camera_guess)
        s._views = [View.from_json(v) for v in state.get("views", [])]
        s._rejected = list(state.get("rejected", []))
        s._next_id = max([int(state.get("next_id", 0))] + [v.id + 1 for v in s._views])
        s._generation = 1
        return s

    def close(self) -> None:
        """Stop the worker thread (waits for a running solve)."""
        ex = self._executor
        self._executor = None
        if ex is not None:
            ex.shutdown(wait=True)
