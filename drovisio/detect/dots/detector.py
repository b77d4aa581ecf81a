"""Colour-dot bricks: find bricks by the coloured dots painted on them, and their 6-DoF poses.

The thesis's pipeline, stage by stage, each in its own module (:meth:`DotDetector.detect`
runs them in this order and times each, :class:`StageTimes`):

1. BGR → HSV, CLAHE on V (:mod:`.color`);
2. per-colour thresholds from the layout's palette, red's hue wrap included
   (:class:`~.color.ColorClassifier`, equal to ``cv2.inRange`` per range);
3. morphological opening then closing (:func:`~.color.clean_mask`);
4. blobs with size, aspect, circularity, fill and convexity filters (:mod:`.blobs`); the
   palette's V range is judged on the CLAHE-equalised V of each blob (stages 1–4 on a frame:
   :mod:`.candidates`);
5. matching blobs to the layout's dots with pair-seeded, scored hypotheses — linear in the
   number of blobs, any planar layout of ≥ 4 dots, partial matches (:mod:`.match`);
6. sub-pixel dot centres from the colour coverage (:func:`~.blobs.refine_centers`) of the
   matched blobs, the bricks as one batch (:mod:`.batch`);
7. planar PnP: both solutions of the planar ambiguity (IPPE, :mod:`.poses`);
8. dots that the brick's own relief (a drick's pyramids) or something in front cuts are
   dropped, then wrong blobs, missing dots are looked for where the pose puts them
   (:mod:`.occlusion`);
9. the perspective shift of ellipse centres corrected in one Gauss–Newton step for all
   bricks (unbiased centres and poses), and the checks (:mod:`.refine`);
10. the planar ambiguity flagged (or resolved with gravity), a symmetric layout's yaw put in
    one canonical half-turn (:mod:`.ambiguity`; kept there over a stream with
    :class:`~.stream.DotsState`);
11. the covariance and the bricks (:mod:`.bricks`).

Entry point: :func:`detect_dots` (what ``drovisio detect --method dots`` calls), or a
:class:`DotDetector` kept across frames.

The per-frame geometry of stages 4–10 runs in compiled kernels (numba, beside each stage:
:mod:`.kernels` lists them) when numba is installed; the numpy functions of the stage modules
are the reference (tests compare the two) and the fallback (``DROVISIO_NUMBA=0``, 32-bit ARM).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from drovisio.camera import Camera
from drovisio.detect.base import unit_gravity
from drovisio.detect.dots.ambiguity import decide
from drovisio.detect.dots.batch import Context, dot_views, make_batch, set_centers
from drovisio.detect.dots.blobs import Blobs, refine_centers
from drovisio.detect.dots.bricks import brick_poses
from drovisio.detect.dots.candidates import BlobFinder
from drovisio.detect.dots.color import check_image
from drovisio.detect.dots.config import DotsConfig
from drovisio.detect.dots.kernels import notice_first_compile
from drovisio.detect.dots.match import (
    BlobGeometry,
    Candidate,
    assign_greedy,
    generate_hypotheses,
)
from drovisio.detect.dots.model import DotModel, LayoutNotSupported
from drovisio.detect.dots.occlusion import complete, drop_hidden, drop_wrong
from drovisio.detect.dots.poses import initial_poses
from drovisio.detect.dots.refine import accepted, perspective_step
from drovisio.detect.dots.stream import PreviousBrick, remembered
from drovisio.detect.result import BrickPose
from drovisio.layout import ColorSpec, MarkerLayout

__all__ = ["DotDetector", "DotsState", "StageTimes", "detect_dots"]

log = logging.getLogger("drovisio.detect.dots")

Stage = Literal["blobs", "match", "centers", "poses", "occlusion", "refine", "decide",
                "bricks"]


@dataclass
class StageTimes:
    """Seconds spent in each stage of :meth:`DotDetector.detect`, summed over the frames since
    the detector was built (a stage a frame did not reach adds nothing)."""

    blobs_s: float = 0.0
    """Stages 1–4: HSV, masks, blobs, CLAHE V."""
    match_s: float = 0.0
    """Blob geometry, hypotheses, assignment."""
    centers_s: float = 0.0
    """Sub-pixel centres of the matched blobs, the batch."""
    poses_s: float = 0.0
    """Both planar solutions of every brick."""
    occlusion_s: float = 0.0
    """Hidden dots, wrong blobs, completion."""
    refine_s: float = 0.0
    """Perspective step and checks."""
    decide_s: float = 0.0
    """Planar ambiguity and symmetric half-turn."""
    bricks_s: float = 0.0
    """Covariance and output."""
    frames: int = 0

    def lap(self, stage: Stage, since: float) -> float:
        """Add the time since ``since`` (``time.perf_counter()``) to ``stage``; returns now."""
        now = time.perf_counter()
        name = f"{stage}_s"
        setattr(self, name, getattr(self, name) + now - since)
        return now


@dataclass
class DotsState:
    """Memory of the previous frame, for a stream (pass the same object every frame).

    It keeps a symmetric brick's yaw in the same half-turn from frame to frame (instead of
    letting the canonical rule flip it where the rule's boundary is) and holds the detector
    built for the camera and layouts. Its size does not grow with the number of frames.
    """

    previous: list[PreviousBrick] = field(default_factory=list)
    """(layout name, tvec, rotation matrix, ambiguous) of the bricks of the previous frame."""
    note: str | None = None
    """Why the last frame gave nothing, when it was not a usable colour image."""
    detector: DotDetector | None = None
    frames: int = 0


class DotDetector:
    """The dot detector for one camera and a set of layouts (reuse it across frames; it keeps
    frame buffers, so use one detector per thread).

    Args:
        camera: The calibrated camera the frames come from.
        layouts: Layouts to look for; those without dots are ignored.
        config: Settings.
        stream: Frames come in order from one stream: keep a symmetric brick's yaw in the
            previous frame's half-turn (:meth:`reset` forgets it).

    Raises:
        LayoutNotSupported: a layout's dots cannot be used (fewer than 4, not coplanar), or
            more than 8 distinct colours.
    """

    name = "dots"

    def __init__(self, camera: Camera, layouts: Sequence[MarkerLayout],
                 config: DotsConfig | None = None, *, stream: bool = False):
        self.camera = camera
        self.state: DotsState | None = DotsState() if stream else None
        self.config = cfg = config or DotsConfig()
        self.layouts = [lay for lay in layouts if getattr(lay, "has_dots", False)]
        specs, mappings = _palette(self.layouts)
        notice_first_compile(log)
        if len(specs) > 8:
            raise LayoutNotSupported(f"the layouts use {len(specs)} distinct dot colours; the "
                                     "dot detector handles up to 8")
        self.specs = specs
        self.models = [DotModel.from_layout(lay, m, n_colors=len(specs))
                       for lay, m in zip(self.layouts, mappings)]
        self.f = float(math.sqrt(camera.fx * camera.fy))
        self._find = BlobFinder(specs, self.models, self.f, cfg)
        self.classifier = self._find.classifier
        self.blob_filter = self._find.blob_filter
        self._ctx = Context(config=cfg, camera=camera, f=self.f)
        self.timing = StageTimes()

    def blobs(self, image_bgr: np.ndarray) -> tuple[Blobs, np.ndarray]:
        """Stages 1–4: the candidate dot blobs of a frame (and its HSV image, which lives in a
        buffer of the detector: valid until the next frame)."""
        return self._find(image_bgr)

    def _blob_geometry(self, blobs: Blobs) -> tuple[np.ndarray, np.ndarray]:
        """Normalised centres (n, 2) and second-moment matrices (n, 2, 2) of blobs (local
        undistortion)."""
        q, J = self.camera.normalize_local(np.stack([blobs.x, blobs.y], axis=1))
        return q, J @ blobs.cov @ J.transpose(0, 2, 1)

    def reset(self) -> None:
        """Forget the stream's previous frame."""
        if self.state is not None:
            self.state = DotsState()

    def detect(self, image_bgr, gravity: Sequence[float] | np.ndarray | None = None,
               state: DotsState | None = None) -> list[BrickPose]:
        """Find the bricks in one frame.

        Args:
            image_bgr: (H, W, 3) uint8 BGR frame of this detector's camera.
            gravity: Direction of gravity in the camera frame (unit vector, pointing down),
                if known: resolves the planar ambiguity of bricks lying roughly flat.
            state: A :class:`DotsState` carried over a stream (optional; default: the
                detector's own, when built with ``stream=True``).

        Returns:
            One :class:`BrickPose` per brick found (``method="dots"``, ``instance=None``,
            ``markers`` = indices of the layout's dots used, ``image_points`` = their
            unbiased centres in pixels, in the order of ``markers``).

        Raises:
            DotsInputError: not an image (None, wrong dtype or shape).
        """
        img, note = check_image(image_bgr)
        if state is None:
            state = self.state
        if state is not None:
            state.note = note
            state.frames += 1
        if img is None:
            log.warning("detect_dots: %s", note)
            if state is not None:
                state.previous = []
            return []
        poses: list[BrickPose] = []
        if self.models:
            self.timing.frames += 1
            # degenerate hypotheses (coincident blobs...) give inf/NaN that the checks reject
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                poses = self._detect(img, gravity, state)
        if state is not None:
            state.previous = remembered(poses)
        return poses

    def _detect(self, img: np.ndarray, gravity, state: DotsState | None) -> list[BrickPose]:
        """The stages in order, each timed."""
        cfg, tm = self.config, self.timing
        t = time.perf_counter()
        blobs, _ = self.blobs(img)
        t = tm.lap("blobs", t)
        if len(blobs) < cfg.min_dots:
            return []
        q, cov = self._blob_geometry(blobs)
        usable = ~blobs.border
        geo = BlobGeometry.build(q, cov, blobs.color, usable)
        taken = ~usable
        hyps = [generate_hypotheses(m, geo, cfg.seeds_per_blob, cfg.ratio_tol, cfg.match_tol,
                                    cfg.min_dots) for m in self.models]
        cands = assign_greedy(hyps, len(blobs), cfg.min_dots, taken)
        t = tm.lap("match", t)
        if not cands:
            return []
        return self._solve(img, blobs, cands, taken, unit_gravity(gravity), state, cov, t)

    def _solve(self, img: np.ndarray, blobs: Blobs, cands: list[Candidate],
               taken: np.ndarray, gravity: np.ndarray | None, state: DotsState | None,
               cov_n: np.ndarray, t: float) -> list[BrickPose]:
        """The pose stages of the matched bricks (``taken``: blobs given to a dot or not to
        be used; ``cov_n``: the blobs' normalised second moments; ``t``: the clock)."""
        ctx, tm = self._ctx, self.timing
        bt = make_batch(cands)
        used = bt.blob[bt.used]     # each blob belongs to one dot of one brick at most
        centers = np.stack([blobs.x, blobs.y], axis=1)
        refined = np.zeros(len(blobs), bool)
        centers[used] = refine_centers(img, blobs, used)[0]
        refined[used] = True
        set_centers(self.camera, bt, centers)
        t = tm.lap("centers", t)
        bt.gravity = gravity
        initial_poses(ctx, bt, list(range(len(cands))))
        t = tm.lap("poses", t)
        views = dot_views(bt)
        alive = np.ones(len(cands), bool)
        drop_hidden(ctx, bt, cov_n, views, taken, alive)
        drop_wrong(ctx, bt, taken, alive)
        complete(ctx, bt, blobs, centers, refined, taken, img)
        t = tm.lap("occlusion", t)
        resid = perspective_step(bt)
        rows, rmse = accepted(ctx, bt, blobs, views, resid, alive)
        t = tm.lap("refine", t)
        if rows.size == 0:
            return []
        decision = decide(ctx, bt, rows, gravity,
                          state.previous if state is not None else None)
        t = tm.lap("decide", t)
        out = brick_poses(ctx, bt, rmse, decision)
        tm.lap("bricks", t)
        return out


def _palette(layouts: list[MarkerLayout]) -> tuple[list[ColorSpec], list[dict[str, int]]]:
    """The distinct palette colours of the layouts' dots, and per layout its colour names'
    indices into them."""
    specs: list[ColorSpec] = []
    index: dict[tuple, int] = {}
    mappings: list[dict[str, int]] = []
    for lay in layouts:
        pal = lay.palette()
        mapping = {}
        for name in dict.fromkeys(lay.dot_colors()):
            spec = pal[name]
            key = (name, spec.hsv)
            if key not in index:
                index[key] = len(specs)
                specs.append(spec)
            mapping[name] = index[key]
        mappings.append(mapping)
    return specs, mappings


_LOCAL = threading.local()


def _detector_for(camera: Camera, layouts: Sequence[MarkerLayout], config: DotsConfig | None
                  ) -> DotDetector:
    """A cached detector per thread (a detector reuses frame buffers: one thread each; it
    takes ~5 ms to build, a frame's detection about as long). Layouts are compared by content
    (the same object first, at no cost), so equal layouts share a detector."""
    key = (camera.model, camera.K.tobytes(), camera.dist.tobytes(), camera.width, camera.height,
           config)
    cache = getattr(_LOCAL, "cache", None)
    if cache is None:
        cache = _LOCAL.cache = []
    lays = list(layouts)
    for k, refs, det in cache:
        if k == key and refs == lays:
            return det
    det = DotDetector(camera, layouts, config)
    cache.insert(0, (key, lays, det))
    del cache[4:]
    return det


def detect_dots(image_bgr, camera: Camera, layouts: Sequence[MarkerLayout],
                gravity: Sequence[float] | np.ndarray | None = None, state: DotsState | None = None, *,
                config: DotsConfig | None = None) -> list[BrickPose]:
    """Find colour-dot bricks in one frame and estimate their poses.

    Args:
        image_bgr: (H, W, 3) uint8 BGR frame (BGRA, greyscale and uint16 are accepted; a
            greyscale frame gives no bricks and a warning).
        camera: The calibrated camera of the frame.
        layouts: Layouts to look for (those without dots are ignored).
        gravity: Unit vector of gravity in the camera frame (pointing down), if known.
        state: A :class:`DotsState` passed with every frame of a stream (keeps symmetric
            yaws from flipping between frames; also caches the detector).
        config: Detector settings (defaults if None).

    Returns:
        A :class:`~drovisio.detect.result.BrickPose` per brick found.

    Raises:
        DotsInputError: the image is not an image (None, float or other dtype, bad shape).
        LayoutNotSupported: a layout's dots cannot be used.
    """
    if state is not None:
        det = state.detector
        if (det is None or det.camera is not camera and not det.camera.almost_equal(camera)
                or [x.name for x in det.layouts] != [x.name for x in layouts
                                                      if getattr(x, "has_dots", False)]
                or (config is not None and det.config != config)):
            det = state.detector = DotDetector(camera, layouts, config)
    else:
        det = _detector_for(camera, layouts, config)
    return det.detect(image_bgr, gravity=gravity, state=state)
