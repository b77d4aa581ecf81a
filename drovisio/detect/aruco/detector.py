"""The code detector: its stages in order, each timed.

:meth:`ArucoBrickDetector.detect` runs, for one frame:

1. OpenCV's pass per code family (:mod:`.opencv_pass`),
2. the rescue of the quads it could not read (:mod:`.rescue`),
3. the second look at twice the size (:mod:`.second_look`),
4. the corner fit of every code (:mod:`.corner_fit`),
5. the grouping into bricks, duplicated ids apart (:mod:`.grouping`),
6. the joint pose of each brick, flips resolved (:mod:`.pose`),
7. the guided codes: a posed brick's unread codes fitted where its pose puts them, and the
   brick solved again with them (:mod:`.guided`),
8. the output as :class:`BrickPose` records (:mod:`.output`),

and adds each stage's time to :attr:`ArucoBrickDetector.timing`.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from drovisio._threads import one_blas_thread
from drovisio.camera import Camera
from drovisio.detect.aruco.codes import BrickKey, CodeDetection, CodeOwner
from drovisio.detect.aruco.corner_fit import fit_corners
from drovisio.detect.aruco.families import CodeFamily, code_families
from drovisio.detect.aruco.grouping import group_by_brick, split_duplicates
from drovisio.detect.aruco.guided import guided_codes
from drovisio.detect.aruco.opencv_pass import opencv_codes
from drovisio.detect.aruco.output import brick_poses
from drovisio.detect.aruco.params import ArucoParams
from drovisio.detect.aruco.pose import BrickSolver, Solved
from drovisio.detect.aruco.rescue import rescue_codes
from drovisio.detect.aruco.second_look import second_look
from drovisio.detect.base import unit_gravity
from drovisio.detect.result import BrickPose
from drovisio.layout import MarkerLayout
from drovisio.pose import PoseHistory, PoseResult

__all__ = ["ArucoBrickDetector", "ArucoTiming", "detect_aruco"]


@dataclass
class ArucoTiming:
    """Seconds spent in each stage, summed over the frames seen."""

    opencv_s: float = 0.0
    """OpenCV's pass (thresholding, quads, bits)."""
    rescue_s: float = 0.0
    """Reading the quads OpenCV could not read, and the ring quads."""
    second_look_s: float = 0.0
    """Searching around unread quads at twice the size."""
    refine_s: float = 0.0
    """The corner fit."""
    grouping_s: float = 0.0
    """Grouping codes into bricks."""
    pose_s: float = 0.0
    """The bricks' poses and flips."""
    guided_s: float = 0.0
    """The guided codes and the poses solved again with them."""
    output_s: float = 0.0
    """The output records and the stream's history."""
    frames: int = 0

    @property
    def detect_s(self) -> float:
        """The code-finding stages together (OpenCV's pass, rescue, second look)."""
        return self.opencv_s + self.rescue_s + self.second_look_s

    def lap(self, stage: str, since: float) -> float:
        """Add the time since ``since`` (``time.perf_counter``) to ``stage`` (a field
        name); returns now."""
        now = time.perf_counter()
        setattr(self, stage, getattr(self, stage) + now - since)
        return now


class ArucoBrickDetector:
    """Finds bricks of the given layouts by their codes and estimates their poses.

    Args:
        camera: The calibrated camera (its image size must match the frames).
        layouts: Marker layouts (only those with codes are used); load them with
            :func:`drovisio.layout.load_layouts` so that id clashes are rejected.
        params: Detector tuning.
        history: Give a :class:`drovisio.pose.PoseHistory` to use temporal consistency over
            a stream (call :meth:`detect` once per frame, in order).
        stream: Frames come in order from one stream: keep a pose history of its own
            (:meth:`reset` forgets it).
    """

    name = "aruco"

    def __init__(self, camera: Camera, layouts: Iterable[MarkerLayout],
                 params: ArucoParams | None = None, history: PoseHistory | None = None, *,
                 stream: bool = False):
        self.camera = camera
        self.params = params or ArucoParams()
        self.history = history if history is not None else (PoseHistory() if stream else None)
        self.layouts = [lay for lay in layouts if lay.has_codes]
        self.timing = ArucoTiming()
        self.last_codes: list[CodeDetection] = []
        """The codes of the last frame (with their refinement), for inspection."""
        self.last_results: dict[tuple, PoseResult] = {}
        """(layout name, instance) -> :class:`drovisio.pose.PoseResult` of the last frame;
        codes whose id was read more than once: (layout name, instance, copy 1, 2, ...)."""
        self.last_duplicates: dict[int, int] = {}
        """Code id -> how many times it was read in the last frame, for ids read more than
        once (each copy is posed on its own and flagged ``duplicate``)."""
        self.families: list[CodeFamily] = code_families(self.layouts, self.params, camera)
        """One OpenCV detector per dictionary family, over exactly our ids."""
        self._family_of: dict[int, CodeFamily] = {
            int(mid): f for f in self.families for mid in f.ids}
        self._solver = BrickSolver(camera, self.params, self.layouts)

    # ------------------------------------------------------------------ the frame
    def reset(self) -> None:
        """Forget the stream's past poses."""
        if self.history is not None:
            self.history = PoseHistory()

    def detect(self, image: np.ndarray, gravity: np.ndarray | None = None) -> list[BrickPose]:
        """Bricks in one frame (BGR or grey uint8), their poses ``camera_from_brick``.

        Args:
            image: (H, W, 3) BGR or (H, W) grey uint8 frame.
            gravity: (3,) unit gravity vector in the camera frame (pointing down), if known.

        Returns:
            One :class:`BrickPose` per brick found, sorted by layout name and instance.
        """
        gray = self._gray(image)
        if self.history is not None:
            self.history.next_frame()
        self.timing.frames += 1
        codes = self.detect_codes(gray)
        t = time.perf_counter()
        groups, self.last_duplicates = split_duplicates(group_by_brick(codes))
        t = self.timing.lap("grouping_s", t)
        g = unit_gravity(gravity)
        results = self._solver.solve_frame(groups, g, self._previous)
        t = self.timing.lap("pose_s", t)
        if self.params.guided and results:
            codes, results = self._guided(gray, codes, groups, results, g)
            t = self.timing.lap("guided_s", t)
        self.last_codes = codes
        self.last_results = {(key[:2] if key[2] == 0 else key): r[0]
                             for key, r in results.items()}
        out = brick_poses(results, self.history)
        self.timing.lap("output_s", t)
        return out

    def _guided(self, gray: np.ndarray, codes: list[CodeDetection],
                groups: dict[BrickKey, list[CodeDetection]], results: dict[BrickKey, Solved],
                gravity: np.ndarray | None
                ) -> tuple[list[CodeDetection], dict[BrickKey, Solved]]:
        """Stage 7: the guided codes, and the bricks that got one solved again (a brick
        keeps its pose from the read codes when the new solve leaves one of them out)."""
        more = guided_codes(gray, results, codes, self.camera, self.params, self._family_of,
                            self._solver.corners_m_by_layout())
        if not more:
            return codes, results
        for c in more:
            groups[(c.layout.name, c.instance, 0)].append(c)
        again = self._solver.solve_frame(groups, gravity, self._previous)
        for key, (res, used) in again.items():
            before = results.get(key)
            if before is None or {id(c) for c in before[1]} <= {id(c) for c in used}:
                results[key] = (res, used)
        return codes + more, results

    def _gray(self, image: np.ndarray) -> np.ndarray:
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if gray.shape[:2] != (self.camera.height, self.camera.width):
            raise ValueError(f"frame is {gray.shape[1]}×{gray.shape[0]} but the camera file "
                             f"is for {self.camera.width}×{self.camera.height}")
        return gray

    def _previous(self, key: BrickKey) -> tuple[np.ndarray, np.ndarray] | None:
        if self.history is None or key[2] > 0:  # a duplicate has no identity to follow
            return None
        return self.history.previous(key[:2])

    # ------------------------------------------------------------------ the codes
    def detect_codes(self, gray: np.ndarray, refine: bool = True) -> list[CodeDetection]:
        """Decode the layouts' codes in a grey image and (by default) refine their corners,
        with one BLAS thread (spinning BLAS threads made a frame's time follow the machine's
        load: :mod:`drovisio._threads`).

        Quads that OpenCV found but could not read (small codes whose corners it places a
        pixel or two inside) get a second reading (:mod:`.rescue`), and for small cells a
        second look (:mod:`.second_look`). Every code, rescued or not, is kept only if its
        refined fit reads its cells back clearly
        (:attr:`drovisio.detect.corners.RefinedCode.cell_margin`).

        Args:
            gray: (H, W) uint8 frame.
            refine: Fit the corners (stage 4); False: OpenCV's corners only.

        Returns:
            OpenCV's codes of every family, then the rescued ones.
        """
        with one_blas_thread():
            codes: list[CodeDetection] = []
            rescued: list[CodeDetection] = []
            for family in self.families:
                found, more = self._family_codes(gray, family)
                codes += found
                rescued += more
            codes += rescued
            t = time.perf_counter()
            if refine and codes:
                fit_corners(gray, codes, self.camera, self.params, self._family_of)
            self.timing.lap("refine_s", t)
            return codes

    def _family_codes(self, gray: np.ndarray, family: CodeFamily
                      ) -> tuple[list[CodeDetection], list[CodeDetection]]:
        """Stages 1–3 for one family: (OpenCV's codes, the rescued ones)."""
        p = self.params
        t = time.perf_counter()
        codes, rejected = opencv_codes(gray, family)
        found = [c.raw_corners for c in codes]
        t = self.timing.lap("opencv_s", t)
        if not p.rescue:
            return codes, []
        got, unread = rescue_codes(gray, rejected, found, family, p)
        t = self.timing.lap("rescue_s", t)
        if p.second_look_max and len(unread) and family.small_cells:
            got += second_look(gray, unread, found + [c.raw_corners for c in got], family, p,
                               self.camera)
            self.timing.lap("second_look_s", t)
        return codes, got

    # ------------------------------------------------------------------ inspection
    # The per-family views below keep the shape the tests inspect.
    @property
    def _detectors(self) -> list[tuple[cv2.aruco.ArucoDetector, np.ndarray,
                                       dict[int, CodeOwner], int]]:
        return [(f.detector, f.ids, f.owners, f.dvalue) for f in self.families]

    @property
    def _rescue_errors(self) -> dict[int, int]:
        return {f.dvalue: f.rescue_errors for f in self.families}

    def _rescue(self, gray: np.ndarray, rejected: Sequence[np.ndarray] | np.ndarray | None,
                found: Sequence[np.ndarray], ids: np.ndarray, owners: dict[int, CodeOwner],
                dvalue: int) -> tuple[list[CodeDetection], np.ndarray]:
        """The rescue stage for the family of ``dvalue`` (``ids`` and ``owners`` are the
        family's own)."""
        family = next(f for f in self.families if f.dvalue == dvalue)
        return rescue_codes(gray, rejected, found, family, self.params)


def detect_aruco(image: np.ndarray, camera: Camera, layouts: Iterable[MarkerLayout],
                 gravity: np.ndarray | None = None) -> list[BrickPose]:
    """One-shot convenience: :class:`ArucoBrickDetector` ``(camera, layouts).detect(...)``."""
    return ArucoBrickDetector(camera, layouts).detect(image, gravity)
