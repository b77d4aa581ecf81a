"""Colour-dot bricks: find bricks by the coloured dots painted on them, and their 6-DoF poses.

The thesis's pipeline, stage by stage (each a small function of its own module):

1. BGR → HSV, CLAHE on V (:mod:`.dots_color`);
2. per-colour thresholds from the layout's palette, red's hue wrap included
   (:class:`~.dots_color.ColorClassifier`, equal to ``cv2.inRange`` per range);
3. morphological opening then closing (:func:`~.dots_color.clean_mask`);
4. blobs with size, aspect, circularity, fill and convexity filters (:mod:`.dots_blobs`);
   the palette's V range is judged on the CLAHE-equalised V of each blob;
5. sub-pixel dot centres from the colour coverage (:func:`~.dots_blobs.refine_centers`);
6. matching blobs to the layout's dots with pair-seeded, scored hypotheses — linear in the
   number of blobs, any planar layout of ≥ 4 dots, partial matches (:mod:`.dots_match`);
7. planar PnP: both solutions of the planar ambiguity (IPPE), dots that the brick's own
   relief (a drick's pyramids) or something in front cuts are dropped, then wrong blobs,
   missing dots are looked for where the pose puts them, and the perspective shift of
   ellipse centres is corrected in one Gauss–Newton step for all bricks (unbiased centres
   and poses; :mod:`drovisio.pose.batch`);
8. the planar ambiguity flagged (or resolved with gravity), a symmetric layout's yaw put in
   one canonical half-turn (and kept there over a stream with :class:`DotsState`).

Entry point: :func:`detect_dots` (what ``drovisio detect --method dots`` calls), or a
:class:`DotDetector` kept across frames.

The per-frame geometry of stages 4–8 runs in compiled kernels (:mod:`.dots_kernels`, numba)
when numba is installed; the numpy functions of the stage modules are the reference (tests
compare the two) and the fallback (``DROVISIO_NUMBA=0``, 32-bit ARM).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio import _numba
from drovisio.camera import Camera
from drovisio.detect.base import decided_up, unit_gravity
from drovisio.detect.dots import color_kernels
from drovisio.detect.dots.blobs import (
    BlobFilter,
    Blobs,
    find_blobs_multi,
    refine_centers,
)
from drovisio.detect.dots.color import (
    ClaheMap,
    ColorClassifier,
    DotsInputError,
    check_image,
    clean_mask,
)
from drovisio.detect.dots.kernels import notice_first_compile
from drovisio.detect.dots.match import (
    BlobGeometry,
    Candidate,
    DotModel,
    LayoutNotSupported,
    assign_greedy,
    generate_hypotheses,
    occluded_dots,
)
from drovisio.detect.result import BrickPose
from drovisio.layout import MarkerLayout
from drovisio.pose import (
    HALF_TURN,
    AmbiguityRule,
    alternative_plausible,
    canonical_half_turn,
    decide_flips,
)
from drovisio.pose.batch import (
    conic_center_offsets,
    gn_step,
    ippe_batch,
    mirror_pose,
    pose_covariance_from_normal,
    project_normalized,
    refine_poses,
    rotation_vectors,
)

__all__ = [
    "DotDetector",
    "DotsConfig",
    "DotsInputError",
    "DotsState",
    "LayoutNotSupported",
    "detect_dots",
]

log = logging.getLogger("drovisio.detect.dots")


@dataclass(frozen=True)
class DotsConfig:
    """Settings of the dot detector (defaults are what the benchmark measured)."""

    clahe: bool = True
    """Judge the palette's V range on CLAHE-equalised V (per blob); False: on raw V, per
    pixel, exactly as ``cv2.inRange`` with the palette ranges."""
    clahe_clip: float = 2.0
    clahe_tiles: tuple[int, int] = (8, 8)
    clahe_stride: int = 4
    """Histogram subsampling of the CLAHE tables (1 = exactly OpenCV's)."""
    v_floor: int = 25
    """With ``clahe``: pixels darker than this (raw V) are never dots."""
    morph_kernel_px: int = 3
    """Opening/closing element diameter."""
    min_dot_px: float = 3.5
    """Smallest dot diameter looked for, pixels."""
    min_distance_m: float = 0.12
    """Nearest a dot may be to the camera (bounds the largest blob)."""
    min_aspect: float = 0.25
    min_circularity: float = 0.55
    min_fill: float = 0.88
    min_convexity: float = 0.85
    max_ellipse_err: float = 0.05
    """Outline deviation from the blob's moment ellipse (plus 0.35 px / minor semi-axis)."""
    max_holes: float = 0.15
    seeds_per_blob: int = 2
    """Nearest neighbours of each blob tried as its pair (hypothesis seeds)."""
    ratio_tol: float = 1.5
    match_tol: float = 0.3
    min_dots: int = 4
    """Fewest dots of a brick (partial matches use any 4 or more)."""
    max_dot_residual_px: float = 0.9
    """A dot farther than this from where the pose puts it is dropped (or the brick is)."""
    max_rmse_px: float = 0.6
    """Largest RMS reprojection error of an accepted brick."""
    size_ratio: tuple[float, float] = (0.5, 1.7)
    """Accepted measured / predicted dot size."""
    max_view_angle_deg: float = 82.0
    """Dots seen more obliquely than this (from their normal) are not trusted."""
    ambiguity: AmbiguityRule = field(default_factory=AmbiguityRule)
    """The planar ambiguity's rule, the same as the ArUco detector's
    (:mod:`drovisio.pose.ambiguity`); χ² at ``centroid_sigma_px``."""
    centroid_sigma_px: float = 0.15
    """Prior standard deviation of a dot centre (the ambiguity rule's χ²)."""
    covariance_floor_px: float = 0.001
    """Least standard deviation of a dot centre for the pose covariance, which takes it from
    the brick's own reprojection residuals (the floor only keeps the matrix invertible).
    A prior of ``centroid_sigma_px`` (0.15 px) here made the covariance ~25× too large (in
    variance) on rendered scenes: Mahalanobis median 0.21 for χ²(6)'s 5.35; from the
    residuals it is 4.8 (``tests/pose/test_covariance_honesty.py``)."""
    covariance: bool = True


@dataclass
class DotsState:
    """Memory of the previous frame, for a stream (pass the same object every frame).

    It keeps a symmetric brick's yaw in the same half-turn from frame to frame (instead of
    letting the canonical rule flip it where the rule's boundary is) and holds the detector
    built for the camera and layouts. Its size does not grow with the number of frames.
    """

    previous: list[tuple[str, np.ndarray, np.ndarray, bool]] = field(default_factory=list)
    """(layout name, tvec, rotation matrix, ambiguous) of the bricks of the previous frame."""
    note: str | None = None
    """Why the last frame gave nothing, when it was not a usable colour image."""
    detector: DotDetector | None = None
    frames: int = 0


@dataclass
class _Batch:
    """Working arrays of the bricks of one frame (B bricks, up to N dots each)."""

    models: list[DotModel]
    blob: np.ndarray        # (B, N) blob index per dot, -1 absent
    X: np.ndarray           # (B, N, 3) dot centres, brick frame
    U: np.ndarray           # (B, N, 3) in-plane axes of each dot
    V: np.ndarray
    normals: np.ndarray     # (B, N, 3)
    radii: np.ndarray       # (B, N)
    px: np.ndarray = None   # (B, N, 2) measured (ellipse) centres, pixels
    q: np.ndarray = None    # (B, N, 2) the same, normalised
    R: np.ndarray = None    # (B, 2, 3, 3) the two planar solutions, best first
    t: np.ndarray = None    # (B, 2, 3)
    cost: np.ndarray = None  # (B, 2) sums of squared residuals (normalised units²)
    offset: np.ndarray = None  # (B, 2, N, 2) ellipse-centre offsets (normalised)
    hidden: np.ndarray = None  # (B, N) dots hidden by the brick's own relief
    gravity: np.ndarray = None  # (3,) gravity in the camera frame, if known
    normal_eq: np.ndarray = None  # (B, 6, 6) JᵀJ of the chosen solution (covariance)
    single: DotModel | None = None  # the model of every brick, when they share one
    colors: np.ndarray = None  # (B, N) colour index of each dot, -1 for padding

    @property
    def used(self) -> np.ndarray:
        return self.blob >= 0

    @property
    def w(self) -> np.ndarray:
        return (self.blob >= 0).astype(np.float64)


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
        specs, index = [], {}
        mappings: list[dict[str, int]] = []
        for lay in self.layouts:
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
        notice_first_compile(log)
        if len(specs) > 8:
            raise LayoutNotSupported(f"the layouts use {len(specs)} distinct dot colours; the "
                                     "dot detector handles up to 8")
        self.specs = specs
        self.models = [DotModel.from_layout(lay, m, n_colors=len(specs))
                       for lay, m in zip(self.layouts, mappings)]
        self.classifier = ColorClassifier(specs, v_floor=cfg.v_floor if cfg.clahe else None) \
            if specs else None
        self.f = float(math.sqrt(camera.fx * camera.fy))
        self.blob_filter = BlobFilter()
        if self.models:
            d_max = max(float(m.radii.max()) for m in self.models) * 2
            max_px = self.f * d_max / cfg.min_distance_m
            self.blob_filter = BlobFilter(
                min_area=max(5.0, 0.55 * math.pi / 4 * cfg.min_dot_px ** 2),
                max_area=1.3 * math.pi / 4 * max_px ** 2,
                min_aspect=cfg.min_aspect, min_circularity=cfg.min_circularity,
                min_fill=cfg.min_fill, min_convexity=cfg.min_convexity,
                max_ellipse_err=cfg.max_ellipse_err, max_holes=cfg.max_holes)
        self._v_ranges = np.array([[s.hsv[0][2], s.hsv[1][2]] for s in specs], float) \
            if specs else np.zeros((0, 2))
        self._hsv: np.ndarray | None = None    # frame buffers, reused (no allocation per frame)

    # ------------------------------------------------------------------------------ stages
    def blobs(self, image_bgr: np.ndarray) -> tuple[Blobs, np.ndarray]:
        """Stages 1–4: the candidate dot blobs of a frame (and its HSV image, which lives in a
        buffer of the detector: valid until the next frame)."""
        H, W = image_bgr.shape[:2]
        if self._hsv is None or self._hsv.shape[:2] != (H, W):
            self._hsv = np.empty((H, W, 3), np.uint8)
        hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV, self._hsv)
        cfg = self.config
        masks = []
        pad = 2 * cfg.morph_kernel_px + 2
        for m in self.classifier.masks(hsv, reuse=True):
            # only the regions with colour pixels: bands of rows separated by empty rows, each
            # cut to its columns (padded: the morphology reaches no further, so separate bands
            # give the blobs of the whole mask)
            # (REDUCE_SUM to int32: OpenCV 5's REDUCE_MAX on uint8 is ~100× slower)
            rows = np.flatnonzero(cv2.reduce(m, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel())
            if rows.size == 0:
                masks.append(None)
                continue
            cut = np.flatnonzero(np.diff(rows) > 2 * pad + 1)
            parts = []
            for r0, r1 in zip([rows[0], *rows[cut + 1].tolist()],
                              [*rows[cut].tolist(), rows[-1]]):
                y0, y1 = max(int(r0) - pad, 0), min(int(r1) + 1 + pad, H)
                x, _, w, _ = cv2.boundingRect(m[y0:y1])
                x0, x1 = max(x - pad, 0), min(x + w + pad, W)
                parts.append((clean_mask(m[y0:y1, x0:x1], cfg.morph_kernel_px), (x0, y0)))
            masks.append(parts)
        blobs, _ = find_blobs_multi(masks, self.blob_filter,
                                    extra=(lambda b: self._clahe_ok(b, hsv)) if cfg.clahe
                                    else None, shape=(H, W))
        return blobs, hsv

    def _clahe_ok(self, blobs: Blobs, hsv: np.ndarray) -> np.ndarray:
        """Blobs whose CLAHE-equalised V lies in their colour's V range."""
        cfg = self.config
        v = hsv[:, :, 2]
        H, W = v.shape
        tx, ty = cfg.clahe_tiles
        rng = self._v_ranges[blobs.color]
        if _numba.enabled() and W % tx == 0 and H % ty == 0 and hsv.flags.c_contiguous:
            eq = color_kernels.clahe_at(hsv, np.ascontiguousarray(blobs.x, np.float64),
                             np.ascontiguousarray(blobs.y, np.float64), int(tx), int(ty),
                             int(cfg.clahe_stride), float(cfg.clahe_clip))
            return (eq >= rng[:, 0] - 0.5) & (eq <= rng[:, 1] + 0.5)
        xi = np.clip(np.rint(blobs.x).astype(np.int64), 1, W - 2)
        yi = np.clip(np.rint(blobs.y).astype(np.int64), 1, H - 2)
        raw = (v[yi, xi].astype(np.float64) + v[yi - 1, xi] + v[yi + 1, xi] + v[yi, xi - 1]
               + v[yi, xi + 1]) / 5.0
        eq = ClaheMap(v, cfg.clahe_clip, cfg.clahe_tiles, cfg.clahe_stride)(blobs.x, blobs.y,
                                                                            raw)
        rng = self._v_ranges[blobs.color]
        return (eq >= rng[:, 0] - 0.5) & (eq <= rng[:, 1] + 0.5)

    def _normalize(self, px: np.ndarray) -> np.ndarray:
        return self.camera.normalize_fast(px)

    def _project(self, Y: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) → distorted pixels (..., 2)."""
        return self.camera.project_fast(Y)

    def _blob_geometry(self, blobs: Blobs) -> tuple[np.ndarray, np.ndarray]:
        """Normalised centres and second-moment matrices of blobs (local undistortion)."""
        q, J = self.camera.normalize_local(np.stack([blobs.x, blobs.y], axis=1))
        return q, J @ blobs.cov @ J.transpose(0, 2, 1)

    # ------------------------------------------------------------------------------ detect
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
            # degenerate hypotheses (coincident blobs...) give inf/NaN that the checks reject
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                poses = self._detect(img, gravity, state)
        if state is not None:
            state.previous = [(p.layout, np.asarray(p.tvec, float).copy(),
                               cv2.Rodrigues(np.asarray(p.rvec, float))[0], p.ambiguous)
                              for p in poses]
        return poses

    def _detect(self, img: np.ndarray, gravity, state: DotsState | None) -> list[BrickPose]:
        cfg = self.config
        blobs, _ = self.blobs(img)
        if len(blobs) < cfg.min_dots:
            return []
        q, cov = self._blob_geometry(blobs)
        usable = ~blobs.border
        geo = BlobGeometry.build(q, cov, blobs.color, usable)
        taken = ~usable
        hyps = [generate_hypotheses(m, geo, cfg.seeds_per_blob, cfg.ratio_tol, cfg.match_tol,
                                    cfg.min_dots) for m in self.models]
        cands = assign_greedy(hyps, len(blobs), cfg.min_dots, taken)
        if not cands:
            return []
        g = unit_gravity(gravity)
        return self._solve(img, blobs, cands, taken, g, state, cov)

    # ------------------------------------------------------------------------------ poses
    def _make_batch(self, cands: list[Candidate]) -> _Batch:
        B = len(cands)
        N = max(c.model.n for c in cands)
        if all(c.model is cands[0].model for c in cands):
            m = cands[0].model

            X, U, V, nrm, rad = m.batch_arrays(B)
            return _Batch(models=[m] * B, blob=np.stack([c.assign for c in cands]),
                          X=X.copy(), U=U, V=V, normals=nrm, radii=rad, single=m,
                          colors=np.broadcast_to(m.colors, (B, N)))
        blob = np.full((B, N), -1, np.int64)
        X = np.zeros((B, N, 3))
        U = np.tile(np.array([1.0, 0, 0]), (B, N, 1))
        V = np.tile(np.array([0, 1.0, 0]), (B, N, 1))
        normals = np.tile(np.array([0, 0, 1.0]), (B, N, 1))
        radii = np.full((B, N), 0.01)
        colors = np.full((B, N), -1, np.int64)
        for k, c in enumerate(cands):
            m = c.model
            n = m.n
            blob[k, :n] = c.assign
            colors[k, :n] = m.colors
            X[k, :n], U[k, :n], V[k, :n] = m.X, m.axes_u, m.axes_v
            normals[k, :n] = m.normals
            radii[k, :n] = m.radii
        return _Batch(models=[c.model for c in cands], blob=blob, X=X, U=U, V=V,
                      normals=normals, radii=radii, colors=colors)

    def _set_centers(self, bt: _Batch, centers: np.ndarray, rows=None) -> None:
        m = bt.used
        if rows is None:
            bt.px = np.where(m[..., None], centers[np.maximum(bt.blob, 0)], 0.0)
            bt.q = np.zeros_like(bt.px)
            bt.q[m] = self._normalize(bt.px[m])
        else:
            mr = m[rows]
            px = np.where(mr[..., None], centers[np.maximum(bt.blob[rows], 0)], 0.0)
            q = np.zeros_like(px)
            q[mr] = self._normalize(px[mr])
            bt.px[rows] = px
            bt.q[rows] = q

    def _initial_poses(self, bt: _Batch, rows) -> None:
        """Both planar solutions of the given bricks (IPPE on the normalised points: compiled,
        or OpenCV's; SQPnP and its mirrored pose, refined, where three of four dots are in a
        line). Solution 0 reprojects best."""
        if bt.R is None:
            Bt = bt.blob.shape[0]
            bt.R = np.tile(np.eye(3), (Bt, 2, 1, 1))
            bt.t = np.zeros((Bt, 2, 3))
            bt.cost = np.full((Bt, 2), np.inf)
        bits = (bt.used * _BITS[:bt.blob.shape[1]]).sum(axis=1).tolist()
        special, warm, fit = [], [], []
        for r in rows:
            if bt.models[r].degeneracy(bits[r]) <= 0.02:   # no homography from these dots
                (warm if np.isfinite(bt.cost[r, 0]) else special).append(r)
            else:
                fit.append(r)
        if fit:
            special += self._ippe(bt, fit)
        if special:
            self._special_poses(bt, np.array(special))
        if warm:
            self._refine_both(bt, np.array(warm))
        self._prefer_level(bt, rows, bt.gravity)

    @staticmethod
    def _ippe(bt: _Batch, rows: list[int]) -> list[int]:
        """Both planar solutions of the given bricks, all bricks of a layout at once; returns
        the bricks it failed on."""
        groups: dict[int, list[int]] = {}
        for r in rows:
            groups.setdefault(id(bt.models[r]), []).append(r)
        failed: list[int] = []
        for g in groups.values():
            m = bt.models[g[0]]
            ga = np.asarray(g, np.int64)
            Pm = np.zeros((ga.size, bt.blob.shape[1], 2))
            Pm[:, :m.n] = m.P
            R, t, cost, ok = ippe_batch(Pm, bt.q[ga], bt.w[ga], m.plane_from_brick)
            bt.R[ga[ok]] = R[ok]
            bt.t[ga[ok]] = t[ok]
            bt.cost[ga[ok]] = cost[ok]
            failed.extend(ga[~ok].tolist())
        return failed

    def _resolve(self, bt: _Batch, rows) -> None:
        """Solve again bricks whose dots changed: both solutions refined from where they are
        (one batch for all bricks), then the gravity preference."""
        rows = np.asarray(rows, np.int64)
        if rows.size:
            self._refine_both(bt, rows, iterations=3)
            self._prefer_level(bt, rows, bt.gravity)

    def _refine_both(self, bt: _Batch, rows: np.ndarray, iterations: int = 4) -> None:
        """Refine both solutions of bricks that already have poses (their dots changed)."""
        self._refine_pair(bt, rows, bt.R[rows, 0], bt.R[rows, 1], bt.t[rows, 0],
                          bt.t[rows, 1], iterations)

    @staticmethod
    def _refine_pair(bt: _Batch, rows: np.ndarray, R0, R1, t0, t1, iterations: int) -> None:
        """Refine two starting poses of each brick (one batch), store them best first."""
        B = rows.size
        X, w, q = bt.X[rows], bt.w[rows], bt.q[rows]
        Rr, tr, cost = refine_poses(np.concatenate([X, X]), np.concatenate([q, q]),
                                    np.concatenate([w, w]), np.concatenate([R0, R1]),
                                    np.concatenate([t0, t1]), iterations=iterations)
        bt.R[rows, 0], bt.R[rows, 1] = Rr[:B], Rr[B:]
        bt.t[rows, 0], bt.t[rows, 1] = tr[:B], tr[B:]
        bt.cost[rows, 0], bt.cost[rows, 1] = cost[:B], cost[B:]
        swap = rows[bt.cost[rows, 1] < bt.cost[rows, 0]]
        if swap.size:
            bt.R[swap] = bt.R[swap][:, ::-1]
            bt.t[swap] = bt.t[swap][:, ::-1]
            bt.cost[swap] = bt.cost[swap][:, ::-1]

    def _special_poses(self, bt: _Batch, rows: np.ndarray) -> None:
        """Poses where no homography can be fitted (three of four dots in a line): SQPnP, the
        mirrored pose, both refined by Levenberg–Marquardt."""
        B = rows.size
        R0 = np.tile(np.eye(3), (B, 1, 1))
        t0 = np.tile(np.array([0.0, 0.0, 1.0]), (B, 1))
        Rpb = np.zeros((B, 3, 3))
        tpb = np.zeros((B, 3))
        for k, r in enumerate(rows.tolist()):
            T = bt.models[r].plane_from_brick
            Rpb[k], tpb[k] = T[:3, :3], T[:3, 3]
            m = bt.blob[r] >= 0
            try:
                ok, rv, tv = cv2.solvePnP(bt.X[r][m].reshape(-1, 1, 3),
                                          bt.q[r][m].reshape(-1, 1, 2), _EYE3, None,
                                          flags=cv2.SOLVEPNP_SQPNP)
            except cv2.error:
                ok = False
            if ok:
                R0[k] = cv2.Rodrigues(rv)[0]
                t0[k] = tv.ravel()
        X, w = bt.X[rows], bt.w[rows]
        Pl = X @ Rpb.transpose(0, 2, 1) + tpb[:, None, :]
        Rcp = R0 @ Rpb.transpose(0, 2, 1)
        tcp = t0 - (Rcp @ tpb[:, :, None])[:, :, 0]
        cen = (Pl * w[..., None]).sum(axis=1) / np.maximum(w.sum(axis=1), 1)[:, None]
        cen[:, 2] = 0.0
        Rm, tm = mirror_pose(Rcp, tcp, cen)
        R1 = Rm @ Rpb
        t1 = (Rm @ tpb[:, :, None])[:, :, 0] + tm
        self._refine_pair(bt, rows, R0, R1, t0, t1, iterations=8)

    def _residuals_px(self, bt: _Batch, q: np.ndarray | None = None) -> np.ndarray:
        """(B, N) distance of each dot from where the best solution puts it (≈ pixels)."""
        _, proj = project_normalized(bt.X, bt.R[:, 0], bt.t[:, 0])
        d = (q if q is not None else bt.q) - proj
        return np.where(bt.used, np.sqrt((d * d).sum(axis=2)) * self.f, 0.0)

    def _geometry(self, bt: _Batch) -> dict:
        """The dots under the best solution: camera-frame centres, view cosines, and the
        second-moment matrices of their ellipses (normalised), (r²/4)·A·Aᵀ with A the local
        projection of the dot's plane."""
        R, t = bt.R[:, 0], bt.t[:, 0]
        Rt = R.transpose(0, 2, 1)
        Y = bt.X @ Rt + t[:, None, :]
        uc, vc, nc = bt.U @ Rt, bt.V @ Rt, bt.normals @ Rt
        z = np.maximum(Y[..., 2], 1e-9)
        iz = 1.0 / z
        x, y = Y[..., 0] * iz, Y[..., 1] * iz
        a00 = (uc[..., 0] - x * uc[..., 2]) * iz
        a10 = (uc[..., 1] - y * uc[..., 2]) * iz
        a01 = (vc[..., 0] - x * vc[..., 2]) * iz
        a11 = (vc[..., 1] - y * vc[..., 2]) * iz
        k = bt.radii * bt.radii / 4
        c00 = k * (a00 * a00 + a01 * a01)
        c01 = k * (a00 * a10 + a01 * a11)
        c11 = k * (a10 * a10 + a11 * a11)
        dist = np.sqrt((Y * Y).sum(axis=2))
        return {"Y": Y, "cos_view": -(nc * Y).sum(axis=2) / np.maximum(dist, 1e-12),
                "c00": c00, "c01": c01, "c11": c11}

    def _solve(self, img: np.ndarray, blobs: Blobs, cands: list[Candidate],
               taken: np.ndarray, gravity: np.ndarray | None,
               state: DotsState | None, cov_n: np.ndarray) -> list[BrickPose]:
        cfg = self.config
        bt = self._make_batch(cands)
        B = len(cands)
        allrows = list(range(B))
        used = bt.blob[bt.used]     # each blob belongs to one dot of one brick at most
        centers = np.stack([blobs.x, blobs.y], axis=1)
        refined = np.zeros(len(blobs), bool)
        centers[used] = refine_centers(img, blobs, used)[0]
        refined[used] = True
        self._set_centers(bt, centers)
        alive = np.ones(B, bool)
        bt.gravity = gravity
        self._initial_poses(bt, allrows)
        # ---- dots hidden in part (by the brick's own relief, or by something in front: a
        # blob smaller than the pose predicts): their centres are off
        geo = self._geometry(bt)
        clear = self._self_occluded(bt)
        bt.hidden = clear < 1.0
        short = self._shape_outliers(bt, cov_n, geo)
        u = bt.used
        bad = (bt.hidden | short) & u
        if bad.any():
            keep_ok = (u.sum(axis=1) - bad.sum(axis=1)) >= cfg.min_dots
            cut = ((bt.hidden & u & (clear < 0.95)) | (short & u)).any(axis=1) & ~keep_ok
            if cut.any():
                # too few dots to drop the cut one: its pose would be off; unless the other
                # planar solution is plausible and sees no dot cut (the cut came from a
                # mirrored pose)
                rows = np.flatnonzero(cut)
                alt = self._self_occluded(bt, sol=1, rows=rows)
                plaus = self._alt_plausible(bt, rows)
                cut[rows] &= ~(plaus & ~(u[rows] & (alt < 0.95)).any(axis=1))
            alive &= ~cut
            drop = bad & keep_ok[:, None]
            if drop.any():
                taken[bt.blob[drop]] = False
                bt.blob[drop] = -1
                rows = np.flatnonzero(drop.any(axis=1)).tolist()
                self._resolve(bt, rows)
        # ---- a dot far from where the pose puts it (a wrong blob): drop the worst
        for _ in range(2):
            res = self._residuals_px(bt)
            worst = res.argmax(axis=1)
            wv = res[np.arange(B), worst]
            drop = alive & (wv > cfg.max_dot_residual_px) & (bt.used.sum(axis=1) > cfg.min_dots)
            if not drop.any():
                break
            rows = np.flatnonzero(drop)
            taken[bt.blob[rows, worst[rows]]] = False
            bt.blob[rows, worst[rows]] = -1
            self._resolve(bt, rows.tolist())
        # ---- look for missing dots where the pose puts them
        self._complete(bt, blobs, centers, refined, taken, img)
        # ---- perspective: the measured centres are ellipse centres, not circle centres
        # both solutions of all bricks as one batch of 2B problems: [sol 0 | sol 1]
        X2 = np.concatenate([bt.X, bt.X])
        R2 = bt.R.transpose(1, 0, 2, 3).reshape(2 * B, 3, 3)
        t2 = bt.t.transpose(1, 0, 2).reshape(2 * B, 3)
        nrm2 = np.concatenate([bt.normals, bt.normals])
        off = conic_center_offsets(X2, nrm2, np.concatenate([bt.radii, bt.radii]), R2, t2)
        w = bt.w
        q2 = np.concatenate([bt.q, bt.q]) - off
        Rr, tr, cost, A, resid = gn_step(X2, q2, np.concatenate([w, w]), R2, t2,
                                         return_normal=True)
        bt.R = Rr.reshape(2, B, 3, 3).transpose(1, 0, 2, 3).copy()
        bt.t = tr.reshape(2, B, 3).transpose(1, 0, 2).copy()
        bt.cost = cost.reshape(2, B).T.copy()
        bt.offset = off.reshape((2, B) + off.shape[1:]).transpose(1, 0, 2, 3).copy()
        bt.normal_eq = A.reshape(2, B, 6, 6).transpose(1, 0, 2, 3).copy()
        resid = resid.reshape((2, B) + resid.shape[1:]).transpose(1, 0, 2).copy()
        swap = bt.cost[:, 1] < bt.cost[:, 0]
        if swap.any():
            for name in ("R", "t", "cost", "offset", "normal_eq"):
                arr = getattr(bt, name)
                arr[swap] = arr[swap][:, ::-1]
            resid[swap] = resid[swap][:, ::-1]
        # ---- checks
        count = bt.used.sum(axis=1)
        rmse = np.sqrt(bt.cost / np.maximum(count, 1)[:, None] / 2) * self.f  # (B, 2)
        res = resid[:, 0] * self.f
        alive &= (count >= cfg.min_dots) & (rmse[:, 0] <= cfg.max_rmse_px)
        alive &= res.max(axis=1) <= cfg.max_dot_residual_px
        alive &= self._plausible(bt, blobs, geo)
        rows = np.flatnonzero(alive)
        if rows.size == 0:
            return []
        return self._finish(bt, rows, rmse, gravity, state)

    def _complete(self, bt: _Batch, blobs: Blobs, centers: np.ndarray, refined: np.ndarray,
                  taken: np.ndarray, img: np.ndarray) -> None:
        """Add dots a partial match missed: a free blob of the right colour where the pose
        puts a missing dot."""
        cfg = self.config
        missing = ~bt.used & ~bt.hidden & (bt.colors >= 0)
        if not missing.any():
            return
        free = np.flatnonzero(~taken)
        if free.size == 0:
            return
        bi, di = np.nonzero(missing)
        Y = (bt.R[bi, 0] @ bt.X[bi, di][:, :, None])[:, :, 0] + bt.t[bi, 0]
        front = Y[:, 2] > 1e-6
        bi, di, Y = bi[front], di[front], Y[front]
        if bi.size == 0:
            return
        pred = self._project(Y)
        size_px = self.f * bt.radii[bi, di] * 2 / Y[:, 2]
        tol2 = np.maximum(1.5, 0.25 * size_px) ** 2
        dd = pred[:, None, :] - centers[free][None, :, :]
        d2 = (dd * dd).sum(axis=2)
        want = bt.colors[bi, di]
        d2[blobs.color[free][None, :] != want[:, None]] = np.inf
        best = d2.argmin(axis=1)
        ok = d2[np.arange(bi.size), best] <= tol2
        if not ok.any():
            return
        changed, new = set(), []
        for k in np.flatnonzero(ok).tolist():
            blob = int(free[best[k]])
            if taken[blob]:
                continue
            taken[blob] = True
            bt.blob[bi[k], di[k]] = blob
            changed.add(int(bi[k]))
            new.append(blob)
        if not changed:
            return
        new_a = np.array(new)
        need = new_a[~refined[new_a]]
        if need.size:
            centers[need] = refine_centers(img, blobs, need)[0]
            refined[need] = True
        rows = np.array(sorted(changed))
        self._set_centers(bt, centers, rows)
        self._resolve(bt, rows.tolist())
        # a completed dot that does not fit is removed again
        res = self._residuals_px(bt)
        bad = (res > cfg.max_dot_residual_px) & np.isin(bt.blob, new_a)
        if bad.any():
            taken[bt.blob[bad]] = False
            bt.blob[bad] = -1
            self._resolve(bt, np.flatnonzero(bad.any(axis=1)))

    def _shape_outliers(self, bt: _Batch, cov_n: np.ndarray, geo: dict) -> np.ndarray:
        """(B, N) dots whose blob is clearly smaller (or larger) than the brick's other dots,
        relative to the size the pose predicts (a dot cut by an edge in front of it)."""
        u = bt.used
        Cm = cov_n[np.maximum(bt.blob, 0)]
        c00, c01, c11 = geo["c00"], geo["c01"], geo["c11"]
        det_p = np.maximum(c00 * c11 - c01 * c01, 1e-30)
        det_m = np.maximum(Cm[..., 0, 0] * Cm[..., 1, 1] - Cm[..., 0, 1] ** 2, 0)
        rho = np.sqrt(np.sqrt(det_m / det_p))                 # linear size ratio
        srt = np.sort(np.where(u, rho, np.inf), axis=1)
        n = u.sum(axis=1)
        med = srt[np.arange(rho.shape[0]), np.maximum(n - 1, 0) // 2]
        # predicted minor semi-axis in pixels: small dots are measured ±1 px
        tr = c00 + c11
        lmin = tr / 2 - np.sqrt(np.maximum(tr * tr / 4 - det_p, 0))
        b_px = 2 * np.sqrt(np.maximum(lmin, 0)) * self.f
        tol = np.maximum(0.2, 1.2 / np.maximum(b_px, 0.5))
        rel = rho / med[:, None]
        return u & ((rel < 1 - tol) | (rel > 1 / (1 - tol)))

    def _self_occluded(self, bt: _Batch, sol: int = 0, rows=None) -> np.ndarray:
        """(B, N) (or (len(rows), N)) clearance of the dots from the shadows of the brick's
        own mesh under solution ``sol``, in dot radii (< 1: partly hidden)."""
        if bt.single is not None:
            m = bt.single
            if not m.occluders.shape[0]:
                n = bt.blob.shape[0] if rows is None else len(rows)
                return np.full((n, bt.blob.shape[1]), np.inf)
            if rows is None:
                return occluded_dots(m, bt.R[:, sol], bt.t[:, sol], clearance=True)
            rr = np.asarray(rows, np.int64)
            return occluded_dots(m, bt.R[rr, sol], bt.t[rr, sol], clearance=True)
        rows = list(range(bt.blob.shape[0])) if rows is None else list(rows)
        out = np.full((len(rows), bt.blob.shape[1]), np.inf)
        groups: dict[int, list[int]] = {}
        for k, r in enumerate(rows):
            m = bt.models[r]
            if m.occluders.shape[0]:
                groups.setdefault(id(m), []).append(k)
        for ks in groups.values():
            m = bt.models[rows[ks[0]]]
            kk = np.array(ks)
            rr = np.array(rows)[kk]
            out[kk, :m.n] = occluded_dots(m, bt.R[rr, sol], bt.t[rr, sol], clearance=True)
        return out

    def _chi2(self, bt: _Batch, rows) -> tuple[np.ndarray, np.ndarray]:
        """χ² (n, 2) of both solutions of the given bricks at ``centroid_sigma_px``, and the
        degrees of freedom (n,) of their fits."""
        rows = np.asarray(rows)
        n = bt.used[rows].sum(axis=1)
        chi2 = bt.cost[rows] * (self.f / self.config.centroid_sigma_px) ** 2
        return chi2, np.maximum(2 * n - 6, 1)

    def _alt_plausible(self, bt: _Batch, rows) -> np.ndarray:
        """Whether the second planar solution of the given bricks is plausible (the rule's
        test, on the current costs)."""
        chi2, dof = self._chi2(bt, rows)
        return alternative_plausible(chi2, dof, self.config.ambiguity)

    def _prefer_level(self, bt: _Batch, rows, gravity: np.ndarray | None) -> None:
        """With gravity: where the second solution is plausible and gravity speaks for it
        (bricks lie roughly flat), make it the working solution."""
        if gravity is None or not len(rows):
            return
        rows = np.asarray(rows)
        chi2, dof = self._chi2(bt, rows)
        plaus = alternative_plausible(chi2, dof, self.config.ambiguity)
        if not plaus.any():
            return
        rows, chi2, dof = rows[plaus], chi2[plaus], dof[plaus]
        pick, _ = decide_flips(bt.R[rows], chi2, dof, gravity=gravity,
                               rule=self.config.ambiguity, use_fit=False)
        swap = rows[pick == 1]
        if swap.size:
            bt.R[swap] = bt.R[swap][:, ::-1]
            bt.t[swap] = bt.t[swap][:, ::-1]
            bt.cost[swap] = bt.cost[swap][:, ::-1]

    def _plausible(self, bt: _Batch, blobs: Blobs, geo: dict) -> np.ndarray:
        """Dots in front, facing the camera, of the size the pose predicts."""
        cfg = self.config
        u = bt.used
        Y = geo["Y"]
        ok_front = np.all(~u | ((Y[..., 2] > 0.02) & (geo["cos_view"] >= _COS_MAX_VIEW[
            cfg.max_view_angle_deg])), axis=1)
        a_pred = self.f * bt.radii / np.maximum(Y[..., 2], 1e-6)   # major semi-axis, approx.
        ratio = np.where(u, blobs.a[np.maximum(bt.blob, 0)] / np.maximum(a_pred, 1e-9), 1.0)
        lo, hi = cfg.size_ratio
        slack = 1.0 / np.maximum(a_pred, 0.5)                   # small blobs: ±1 px
        return ok_front & np.all((ratio >= lo - slack) & (ratio <= hi + slack), axis=1)

    def _finish(self, bt: _Batch, rows: np.ndarray, rmse: np.ndarray,
                gravity: np.ndarray | None, state: DotsState | None) -> list[BrickPose]:
        cfg = self.config
        B = rows.size
        ar = np.arange(B)
        R2, t2 = bt.R[rows], bt.t[rows]
        # ---- the planar ambiguity: the one rule (gravity, the previous frame, the image,
        # "close"); then the bricks still undecided with the up of the decided ones
        chi2, dof = self._chi2(bt, rows)
        prev = self._previous_rotations(bt, rows, R2, t2, state)
        choose, why = decide_flips(R2, chi2, dof, gravity=gravity, previous=prev,
                                   rule=cfg.ambiguity)
        undecided = choose < 0
        up = decided_up(R2[ar, np.maximum(choose, 0)], why, undecided)
        if up is not None:
            u = np.flatnonzero(undecided)
            choose[u], _ = decide_flips(R2[u], chi2[u], dof[u], gravity=gravity,
                                        reference_up=up, rule=cfg.ambiguity,
                                        previous=None if prev is None else [prev[k] for k in u])
        ambiguous = choose < 0
        choose = np.where(ambiguous, 0, choose)      # undecided: the better fit, flagged
        Rc, tc = R2[ar, choose], t2[ar, choose]
        rm = rmse[rows][ar, choose]
        qsel = bt.q[rows] - bt.offset[rows][ar, choose]
        # ---- symmetric layouts: one canonical half-turn (the previous frame's, in a stream)
        if bt.single is not None:
            sym = np.full(B, bt.single.sym_perm is not None)
        else:
            sym = np.array([bt.models[r].sym_perm is not None for r in rows.tolist()])
        flip = np.zeros(B, bool)
        if sym.any():
            flip = sym & canonical_half_turn(Rc)
            prev = state.previous if state is not None else []
            if prev:
                for k in np.flatnonzero(sym).tolist():
                    f = self._previous_flip(bt.models[rows[k]], Rc[k], tc[k], prev)
                    if f is not None:
                        flip[k] = f
            Rc = np.where(flip[:, None, None], Rc * HALF_TURN, Rc)
        # ---- unbiased centres in pixels, covariance
        img_pts = self._project(np.concatenate([qsel, np.ones(qsel.shape[:2] + (1,))], axis=2))
        cov = None
        if cfg.covariance:
            n = bt.used[rows].sum(axis=1)
            sig = np.maximum(cfg.covariance_floor_px, rm * np.sqrt(2 * n / np.maximum(
                2 * n - 6, 1))) / self.f
            A = bt.normal_eq[rows][ar, choose]
            rvecs = rotation_vectors(Rc)
            cov = pose_covariance_from_normal(A, Rc, tc, rvecs, sig)
        else:
            rvecs = rotation_vectors(Rc)
        # dot labels in the reported (possibly half-turned) frame, sorted
        N = bt.blob.shape[1]
        used = bt.used[rows]
        lab = np.broadcast_to(np.arange(N), (B, N))
        if flip.any() and bt.single is not None:
            lab = np.where(flip[:, None], bt.single.sym_perm, lab)
        elif flip.any():
            perm = np.stack([bt.models[r].sym_perm if bt.models[r].sym_perm is not None
                             else np.arange(bt.models[r].n) for r in rows.tolist()]) \
                if N == max(bt.models[r].n for r in rows.tolist()) else None
            if perm is not None:
                lab = np.where(flip[:, None], perm, lab)
        key = np.where(used, lab, N + 1)
        order = np.argsort(key, axis=1)                          # (B, N) dots by label
        counts = used.sum(axis=1).tolist()
        lab_sorted = np.take_along_axis(key, order, axis=1).tolist()
        pts_sorted = img_pts[ar[:, None], order]
        names = [bt.single.name] * B if bt.single is not None else \
            [bt.models[r].name for r in rows.tolist()]
        out = []
        amb, syml, rml, chl = ambiguous.tolist(), sym.tolist(), rm.tolist(), choose.tolist()
        for k in range(B):
            nk = counts[k]
            alt = []
            if amb[k]:
                Ra = R2[k, 1 - chl[k]]
                if syml[k] and canonical_half_turn(Ra):
                    Ra = Ra * HALF_TURN
                alt = [(cv2.Rodrigues(Ra)[0].ravel(), t2[k, 1 - chl[k]].copy())]
            out.append(BrickPose(
                layout=names[k], instance=None, method="dots", rvec=rvecs[k], tvec=tc[k],
                reprojection_rmse_px=rml[k], markers=lab_sorted[k][:nk],
                ambiguous=amb[k], alternatives=alt, symmetric=syml[k],
                covariance=None if cov is None else cov[k], image_points=pts_sorted[k, :nk]))
        return out

    @staticmethod
    def _previous_match(model: DotModel, t: np.ndarray,
                        previous: list[tuple[str, np.ndarray, np.ndarray, bool]]
                        ) -> tuple[np.ndarray, bool] | None:
        """The brick of the same layout in the previous frame nearest to ``t`` (within half
        the layout's extent): (its rotation, whether it was ambiguous), or None."""
        best, bd = None, 0.5 * model.max_extent
        for name, tp, Rp, amb in previous:
            if name == model.name:
                d = float(np.linalg.norm(tp - t))
                if d < bd:
                    best, bd = (Rp, amb), d
        return best

    def _previous_flip(self, model: DotModel, R: np.ndarray, t: np.ndarray,
                       previous: list[tuple[str, np.ndarray, np.ndarray, bool]]
                       ) -> bool | None:
        """With a brick of the same layout in the previous frame: whether to half-turn the
        pose to stay in that brick's half-turn."""
        m = self._previous_match(model, t, previous)
        return None if m is None else float(R[:, 0] @ m[0][:, 0]) < 0

    def _previous_rotations(self, bt: _Batch, rows: np.ndarray, R2: np.ndarray,
                            t2: np.ndarray, state: DotsState | None
                            ) -> list[np.ndarray | None] | None:
        """Per brick, the rotation of the same brick in the previous frame when that pose was
        decided (evidence for the planar ambiguity), else None. A symmetric layout's pose
        was reported in one of its half-turns: the one nearer to either candidate."""
        if state is None or not any(not p[3] for p in state.previous):
            return None
        out: list[np.ndarray | None] = []
        for k, r in enumerate(rows.tolist()):
            m = bt.models[r]
            hit = self._previous_match(m, t2[k, 0], state.previous)
            if hit is None or hit[1]:
                out.append(None)
                continue
            Rp = hit[0]
            if m.sym_perm is not None:
                Rh = Rp * HALF_TURN
                near = max(float(np.trace(Rp.T @ R2[k, j])) for j in (0, 1))
                near_h = max(float(np.trace(Rh.T @ R2[k, j])) for j in (0, 1))
                Rp = Rh if near_h > near else Rp
            out.append(Rp)
        return out


_BITS = 1 << np.arange(16)
_EYE3 = np.eye(3)


class _CosTable(dict):
    def __missing__(self, deg: float) -> float:
        val = self[deg] = math.cos(math.radians(deg))
        return val


_COS_MAX_VIEW = _CosTable()


_LOCAL = threading.local()


def _detector_for(camera: Camera, layouts: Sequence[MarkerLayout], config: DotsConfig | None
                  ) -> DotDetector:
    """A cached detector per thread (a detector reuses frame buffers: one thread each)."""
    key = (camera.K.tobytes(), camera.dist.tobytes(), camera.width, camera.height,
           tuple(id(x) for x in layouts), config)
    cache = getattr(_LOCAL, "cache", None)
    if cache is None:
        cache = _LOCAL.cache = []
    for k, _refs, det in cache:
        if k == key:
            return det
    det = DotDetector(camera, layouts, config)
    cache.insert(0, (key, list(layouts), det))   # holds the layouts: their ids stay valid
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
