"""Bricks from their ArUco codes: detection, unbiased corners, joint pose, resolved flips.

Pipeline of :class:`ArucoBrickDetector` for one frame:

1. **Codes.** OpenCV's ``ArucoDetector`` with parameters tuned for small codes (≥ 14 px) on
   cluttered ground and for speed (:class:`ArucoParams`: one small adaptive-threshold window
   instead of three, a stricter threshold constant that keeps thin white paper rims apart
   from dark brick faces, 8 samples per cell when reading the bits, no candidate smaller
   than 11 px), and a dictionary made of *exactly* the ids the loaded layouts own (fewer
   false decodes). Quads OpenCV found but could not read, and for dictionaries with small
   cells (6×6, 36h11) the quads of thresholded contours it passed over (a code whose border
   merges with a pyramid's shaded side), are read again (:meth:`ArucoBrickDetector._rescue`)
   by a least-squares fit of their blurred cells
   (:class:`drovisio.detect.code_reading.CodeReader`), with as many misread bits as the
   codes' distances allow (36h11: 3, 4×4: 0). Quads still unread whose reading shows a
   code's frame and contrast, or comes closer to one of our codes than chance, get a second
   look at twice the size (:meth:`ArucoBrickDetector._second_look`). On 815 rendered tag36h11 bricks
   (``drovisio bench aruco --dictionary DICT_APRILTAG_36h11 --apriltag --bricks 4 --frames
   300 --seed 5000 --empty 0``): codes of 14–20 px 76.3 % (OpenCV's pass alone) → 96.2 %
   (AprilTag 3: 74.0 %), all ≥ 14 px 94.7 % → 99.3 % (93.6 %), no false brick, at 0.86× the
   time of plain ``detectMarkers``.
2. **Corners.** Every decoded code is refined by :func:`drovisio.detect.corners.refine_codes`
   (photometric fit of the code's interior, unbiased by the outer edge's surroundings), all
   codes of the frame in one batch, starting from OpenCV's corners moved outward by their
   measured bias. A code the model does not fit, or whose cells do not read back as its
   bits (a decoy, a partly hidden code), is dropped.
3. **Bricks.** Codes are grouped by their layout's id blocks into brick instances; one joint
   PnP over every visible code of a brick (:func:`drovisio.pose.solve_brick_pose`), with the
   corners' covariance from the fit; a code with a corner far beyond the noise the brick's
   own residuals show is left out of the final refinement (its corners share one wrong fit).
4. **Flips.** Candidates are chosen with gravity when known, then with the "up" of other,
   decided bricks in the same frame (bricks on one ground are parallel), then with the
   previous pose of the same brick when a :class:`drovisio.pose.PoseHistory` is given (a
   stream), then with the reprojection. Undecided poses are flagged ``ambiguous`` with the
   alternative.

Typical use::

    det = ArucoBrickDetector(camera, layouts)
    poses = det.detect(image_bgr, gravity=g)      # list[BrickPose]
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio._threads import one_blas_thread
from drovisio.camera import Camera
from drovisio.detect.base import decided_up, unit_gravity
from drovisio.detect.code_reading import CodeReader, ring_quads
from drovisio.detect.corners import RefinedCode, refine_codes
from drovisio.detect.result import BrickPose
from drovisio.layout import (
    aruco_code_bits,
    aruco_dictionary_id,
    aruco_dictionary_size,
    aruco_family,
)
from drovisio.pose import (
    AmbiguityRule,
    PoseEvidence,
    PoseHistory,
    solve_brick_pose,
)
from drovisio.pose.ambiguity import noise_scale

__all__ = [
    "ArucoBrickDetector",
    "ArucoParams",
    "CodeDetection",
    "detect_aruco",
    "plain_detector",
]


@dataclass
class ArucoParams:
    """Tuning of the code detector (defaults measured with ``drovisio bench aruco``)."""

    adaptive_window: int = 5
    """Adaptive threshold window (px, odd). One window: the default three cost 3× the time
    and found fewer small codes on the drick scenes."""
    threshold_constant: float = 12.0
    """Adaptive threshold constant (grey levels below the local mean that count as black).
    OpenCV's 7 merges the black border with the darker brick faces next to it (the white
    paper rim is < 1 px at 2 m), so the quad is lost."""
    pixels_per_cell: int = 8
    """Samples per cell when the bits are read (OpenCV's 4 misreads codes of ~3 px cells)."""
    min_code_px: float = 11.0
    """Smallest code side, pixels; OpenCV's perimeter rate is set from it for the camera's
    image size (0.07 at 640 px). The target is ≥ 15 px; fewer candidates than 8 px, same
    recall."""
    error_correction_rate: float = 0.6
    polygon_accuracy: float = 0.03
    """OpenCV's ``polygonalApproxAccuracyRate``: how far (× the perimeter) a candidate's
    contour may stray from its 4-gon. 0.05 read 1 code more in 1000 on the 60° lens, but
    through a fisheye it took curved, bumpy contours for codes and their poses were off by
    3 cm (``drovisio bench lens``)."""
    corner_noise_scale: float = 1.0
    """Multiplies the corner standard deviations predicted by the photometric fit (which
    takes the noise from its own residuals). The pose solve then inflates the covariance by
    its own χ²/dof when the corners disagree more than predicted (correlated JPEG noise), so
    a further factor counts that noise twice: with 2.0 the pose errors' Mahalanobis median
    against the reported covariance was 2.0 on rendered scenes (χ²(6): 5.35), with 1.0 it is
    3.8–4.7 (``tests/pose/test_covariance_honesty.py``)."""
    max_rmse_px: float = 2.0
    """Bricks whose joint fit is worse than this (px RMS) are dropped (a wrong grouping or a
    code on a bent surface) unless the fit is explained otherwise
    (:meth:`ArucoBrickDetector._fit_explained`: noisier corners, or a camera model that fits
    OpenCV's own corners no better)."""
    gravity_prior_deg: float | None = 5.0
    """With gravity, a soft prior that the brick lies flat (standard deviation, degrees;
    None: gravity only chooses between flip candidates). It covers the drone's attitude
    error and uneven ground; strong image evidence wins over it."""
    ambiguity: AmbiguityRule = field(default_factory=AmbiguityRule)
    """The planar ambiguity's rule, the same as the dot detector's
    (:mod:`drovisio.pose.ambiguity`; measured on the bench: at a χ² margin of 16, small single
    codes were flipped by corner errors, hence 25)."""
    initial_expand_px: float = 1.0
    """OpenCV's corners (contours of the thresholded image) lie inside the code: at the
    threshold settings above their mean signed radial error is -1.06 px (bench). The fit
    starts from them moved outward by this much along the diagonals."""
    refine_iterations: int = 2
    """Levenberg–Marquardt iterations of the corner fit (two suffice from the corrected
    start: RMS 0.17 px on the bench, against 0.23 px with three from the raw corners)."""
    refine_coarse_iterations: int = 0
    refine_lambda: float = 0.03
    max_samples: int = 200
    """Pixels per code in the corner fit (bigger codes: a random subset)."""
    band_px: float = 2.0
    """Only pixels within this distance of a modelled edge enter the corner fit."""
    rescue: bool = True
    """Read the quads OpenCV found but rejected, and the ring quads (see
    :meth:`ArucoBrickDetector._rescue`)."""
    rescue_max: int = 60
    """At most this many quads are read again per frame."""
    rescue_max_side_px: float = 40.0
    """Rejected quads bigger than this (mean side) are not read again."""
    rescue_max_bit_errors: int = 3
    """Most misread bits a rescued code may have (fewer when our codes are closer to each
    other: :meth:`ArucoBrickDetector._tolerable_bit_errors`); small 36h11 codes have cells
    of 1.4–2 px, blur makes one or two of 36 read wrong. The corner fit then checks every
    cell against the code's bits (a misread code is dropped there)."""
    rescue_chance_limit: float = 1e-4
    """Highest chance that a random reading (a quad on gravel) comes within the tolerated
    bit errors of one of our codes; it bounds the tolerance (36h11: 3 errors, 2e-5 for 40
    codes; 4×4: 0)."""
    rescue_shifts_px: tuple[float, ...] = (0.0, 0.8, 1.6)
    """Outward shifts of a rescued quad's corners tried when reading it (OpenCV's contours
    lie about a pixel inside the code, a ring's hull half a pixel)."""
    rescue_min_contrast: float = 15.0
    """Grey levels a rescued code's white cells must read above its black ones."""
    rescue_max_black_offset: float = 0.35
    """A rescued code's black cells must read as its border's black within this fraction
    of the contrast (a quad on gravel has no uniform black frame)."""
    ring_quads_max: int = 30
    """For dictionaries with small cells, at most this many quads from contours OpenCV
    passed over (a code whose border touches a dark edge: :func:`ring_quads`; 0: none)."""
    second_look_max: int = 6
    """Quads still unread after the rescue that get a second look at twice the size (the
    largest first; 0: none)."""
    small_cell_px: float = 2.5
    """Dictionaries whose cells are at most this wide on a 20-px code have "small cells":
    they get the ring quads and the second look. 4×4 codes (3.3 px) do not: on the bench the
    two found the last 3 of 520 bricks but made 7 false ones in 440 frames (16 bits read off
    random quads match one of our codes too often), at 2.3× the time."""
    second_look_max_side_px: float = 30.0
    second_look_chance: float = 0.05
    """The budget of the second look (0.25 ms a quad): only quads whose reading shows a
    code's frame (a uniform black border and cells with contrast, at some shift) or came
    closer to one of our codes than a random pattern would with this chance (36h11 with
    30–60 ids: at most 7 bits off) get it. Bits alone are no budget: a ring's hull that
    takes in a pyramid's edge reads 9–11 bits off and still holds a code."""
    """Unread quads larger than this (mean side) get no second look."""
    second_look_window: int = 9
    """Adaptive threshold window of the second look (px of the enlarged image)."""
    second_look_constant: float = 5.0
    """Adaptive threshold constant of the second look."""


@functools.lru_cache(maxsize=8)
def _reader(n: int) -> CodeReader:
    return CodeReader(n)


@dataclass
class CodeDetection:
    """One decoded code in one frame."""

    marker_id: int
    layout: object
    instance: int
    slot: int
    raw_corners: np.ndarray
    """(4, 2) OpenCV's corners, px."""
    refined: RefinedCode | None = None
    info: np.ndarray | None = None
    """(8, 8) inverse covariance of the refined corners (x0, y0, ... x3, y3), px⁻²."""


@dataclass
class _Timing:
    detect_s: float = 0.0
    refine_s: float = 0.0
    pose_s: float = 0.0
    frames: int = 0


def plain_detector(dictionary_name: str = "DICT_4X4_50") -> cv2.aruco.ArucoDetector:
    """OpenCV's ``ArucoDetector`` with default parameters (the benchmark's reference)."""
    d = cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary_name))
    return cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters())


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

    def __init__(self, camera: Camera, layouts, params: ArucoParams | None = None,
                 history: PoseHistory | None = None, *, stream: bool = False):
        self.camera = camera
        self.params = params or ArucoParams()
        self.history = history if history is not None else (PoseHistory() if stream else None)
        self.layouts = [lay for lay in layouts if lay.has_codes]
        self._corners_m: dict[int, dict] = {id(lay): lay.code_corners_m() for lay in self.layouts}
        self.timing = _Timing()
        self.last_codes: list[CodeDetection] = []
        """The codes of the last frame (with their refinement), for inspection."""
        self.last_results: dict = {}
        """(layout name, instance) -> :class:`drovisio.pose.PoseResult` of the last frame;
        codes whose id was read more than once: (layout name, instance, copy 1, 2, ...)."""
        self.last_duplicates: dict[int, int] = {}
        """Code id -> how many times it was read in the last frame, for ids read more than
        once (each copy is posed on its own and flagged ``duplicate``)."""
        # one cv2 detector per dictionary family, with a dictionary of exactly our ids
        fam: dict[str, dict] = {}
        for lay in self.layouts:
            for slot, dname in lay.code_dictionaries().items():
                f = aruco_family(dname)
                entry = fam.setdefault(f, {"dict": dname, "ids": {}})
                if aruco_dictionary_size(dname) > aruco_dictionary_size(entry["dict"]):
                    entry["dict"] = dname
                for k in range(lay.instances or 0):
                    entry["ids"][lay.marker_id(k, slot)] = (lay, k, slot)
        self._detectors: list[tuple[cv2.aruco.ArucoDetector, np.ndarray, dict, int]] = []
        self._dvalue: dict[int, int] = {}
        self._patterns: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._rescue_errors: dict[int, int] = {}
        self._look_errors: dict[int, int] = {}
        self._detectors_by_dvalue: dict[int, cv2.aruco.ArucoDetector] = {}
        self._second_detectors: dict[int, cv2.aruco.ArucoDetector] = {}
        self._small_cells: dict[int, bool] = {}
        self._readers: dict[int, CodeReader] = {}
        for entry in fam.values():
            dvalue = aruco_dictionary_id(entry["dict"])
            full = cv2.aruco.getPredefinedDictionary(dvalue)
            ids = np.array(sorted(i for i in entry["ids"] if i < full.bytesList.shape[0]),
                           np.int64)
            if ids.size == 0:
                continue
            sub = cv2.aruco.Dictionary(full.bytesList[ids].copy(), full.markerSize,
                                       full.maxCorrectionBits)
            det = cv2.aruco.ArucoDetector(sub, self._detector_params(),
                                          cv2.aruco.RefineParameters())
            self._detectors.append((det, ids, entry["ids"], dvalue))
            self._detectors_by_dvalue[dvalue] = det
            # the second look pays where a 20-px code's cells are small (6x6 and 36h11: 2.5
            # px; 4x4 codes: 3.3 px, read at the first pass)
            self._small_cells[dvalue] = (20.0 / (full.markerSize + 2)
                                         <= self.params.small_cell_px)
            self._readers[dvalue] = _reader(full.markerSize + 2)
            for mid in ids:
                self._dvalue[int(mid)] = dvalue
            # the inner bits of every id, in the four rotations a quad's corner order can
            # read them in: pats[k] is the code rotated by -k quarter turns (np.rot90)
            inner = [aruco_code_bits(dvalue, int(i))[1:-1, 1:-1] > 0 for i in ids]
            pats = np.array([[np.rot90(b, -k).ravel() for b in inner] for k in range(4)],
                            np.int8)
            self._patterns[dvalue] = (pats, ids)
            self._rescue_errors[dvalue] = self._tolerable_bit_errors(pats)
            self._look_errors[dvalue] = self._chance_bit_errors(
                pats, self.params.second_look_chance)

    @staticmethod
    def _chance_bit_errors(pats: np.ndarray, chance: float) -> int:
        """Most bit errors e such that a random reading lands within e bits of one of the
        patterns (every id in every quarter turn) with a chance of at most ``chance``."""
        import math

        n = pats.shape[2]
        count = pats.shape[0] * pats.shape[1]
        e, total = -1, 0
        while e < n and (total + math.comb(n, e + 1)) * count / 2.0 ** n <= chance:
            e += 1
            total += math.comb(n, e)
        return e

    def _tolerable_bit_errors(self, pats: np.ndarray) -> int:
        """Bit errors a rescued reading may have: at most a third of the smallest Hamming
        distance between two of our codes (any ids, any quarter turns, a code and its own
        turns included), so a reading that close to one code is twice as far from every
        other; and few enough that a random pattern (a quad on gravel) lands that close to
        one of them with a chance under ``rescue_chance_limit``. 4×4 codes get 0, 36h11 3."""
        import math

        P = pats.reshape(-1, pats.shape[2]).astype(np.int32)
        n = P.shape[1]
        d = (P[:, None, :] != P[None, :, :]).sum(axis=2)
        np.fill_diagonal(d, n)
        e = min(self.params.rescue_max_bit_errors, (int(d.min()) - 1) // 3)
        while e > 0 and (sum(math.comb(n, k) for k in range(e + 1)) * len(P) / 2.0 ** n
                         > self.params.rescue_chance_limit):
            e -= 1
        return max(e, 0)

    def _detector_params(self) -> cv2.aruco.DetectorParameters:
        p = cv2.aruco.DetectorParameters()
        w = int(self.params.adaptive_window) | 1
        p.adaptiveThreshWinSizeMin = w
        p.adaptiveThreshWinSizeMax = w
        p.adaptiveThreshWinSizeStep = 10
        p.adaptiveThreshConstant = float(self.params.threshold_constant)
        p.perspectiveRemovePixelPerCell = int(self.params.pixels_per_cell)
        side = max(self.camera.width, self.camera.height)
        p.minMarkerPerimeterRate = float(4.0 * self.params.min_code_px / side)
        p.errorCorrectionRate = float(self.params.error_correction_rate)
        p.polygonalApproxAccuracyRate = float(self.params.polygon_accuracy)
        p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
        return p

    # ------------------------------------------------------------------------ stages
    def detect_codes(self, gray: np.ndarray, refine: bool = True) -> list[CodeDetection]:
        """Decode the layouts' codes in a grey image and (by default) refine their corners,
        with one BLAS thread (spinning BLAS threads made a frame's time follow the machine's
        load: :mod:`drovisio._threads`). See :meth:`_detect_codes`."""
        with one_blas_thread():
            return self._detect_codes(gray, refine)

    def _detect_codes(self, gray: np.ndarray, refine: bool = True) -> list[CodeDetection]:
        """Decode the layouts' codes in a grey image and (by default) refine their corners.

        Quads that OpenCV found but could not read (small codes whose corners it places a
        pixel or two inside) get a second reading (:meth:`_rescue`). Every code, rescued or
        not, is kept only if its refined fit reads its cells back clearly
        (:attr:`drovisio.detect.corners.RefinedCode.cell_margin`).
        """
        t0 = time.perf_counter()
        codes: list[CodeDetection] = []
        rescued: list[CodeDetection] = []
        for det, ids, owners, dvalue in self._detectors:
            corners, idx, rejected = det.detectMarkers(gray)
            found = []
            if idx is not None:
                for c, i in zip(corners, np.ravel(idx)):
                    mid = int(ids[int(i)])
                    lay, k, slot = owners[mid]
                    q = np.asarray(c, np.float64).reshape(4, 2)
                    codes.append(CodeDetection(mid, lay, k, slot, q))
                    found.append(q)
            if self.params.rescue:
                got, unread = self._rescue(gray, rejected, found, ids, owners, dvalue)
                rescued += got
                if self.params.second_look_max and len(unread) and self._small_cells[dvalue]:
                    rescued += self._second_look(gray, unread, found + [c.raw_corners
                                                                         for c in got],
                                                 dvalue, ids, owners)
        codes += rescued
        t1 = time.perf_counter()
        self.timing.detect_s += t1 - t0
        if refine and codes:
            # OpenCV's corners sit inside the code by a known amount: start outside them
            q = np.array([c.raw_corners for c in codes])
            d = q - q.sum(axis=1, keepdims=True) * 0.25
            starts = q + self.params.initial_expand_px * d / np.sqrt(
                (d * d).sum(axis=2, keepdims=True))
            ref = refine_codes(gray, self.camera, starts,
                               [aruco_code_bits(self._dvalue[c.marker_id], c.marker_id).astype(np.float64)
                                for c in codes],
                               iterations=self.params.refine_iterations,
                               coarse_iterations=self.params.refine_coarse_iterations,
                               lm_lambda=self.params.refine_lambda,
                               max_samples=self.params.max_samples,
                               band_px=self.params.band_px,
                               tolerable_cells=np.array([self._rescue_errors[self._dvalue[
                                   c.marker_id]] for c in codes]))
            # the corners' information matrices (inverse covariances) for the pose: the
            # fit's covariance scaled to the measured noise, with a 0.03 px floor
            cov = np.array([r.cov_px for r in ref]) * self.params.corner_noise_scale ** 2
            cov += np.eye(8) * 0.03 ** 2
            try:
                info = np.linalg.inv(cov)
            except np.linalg.LinAlgError:
                info = np.array([np.linalg.pinv(c_) for c_ in cov])
            for c, r, w in zip(codes, ref, info):
                c.refined = r
                c.info = w
        self.timing.refine_s += time.perf_counter() - t1
        return codes

    # ------------------------------------------------------------------------ rescue
    def _rescue(self, gray, rejected, found, ids, owners, dvalue
                ) -> tuple[list[CodeDetection], np.ndarray]:
        """Read quads OpenCV rejected, and for dictionaries with small cells the quads of
        contours it passed over (:func:`drovisio.detect.code_reading.ring_quads`): each is
        read by :class:`drovisio.detect.code_reading.CodeReader` (blur included) at a few
        outward shifts of its corners and in the four corner orders; an unambiguous match to
        one of our ids is kept (a few bits may be misread: :meth:`_tolerable_bit_errors`).
        Returns the codes and the quads still unread that show a code's frame or read
        closer to one of our codes than chance (``second_look_chance``), for
        :meth:`_second_look`."""
        p = self.params
        none = np.zeros((0, 4, 2))
        quads = (np.asarray(rejected, np.float64).reshape(-1, 4, 2)
                 if rejected is not None and len(rejected) else none)
        if self._small_cells[dvalue] and p.ring_quads_max:
            rq = ring_quads(gray, p.adaptive_window, p.threshold_constant, 8.0,
                            p.rescue_max_side_px, p.ring_quads_max)
            quads = np.concatenate([quads, rq]) if len(rq) else quads
        if len(quads) == 0:
            return [], none
        dq = quads - quads[:, [3, 0, 1, 2]]
        side = np.sqrt((dq * dq).sum(axis=2))
        # small quads only: OpenCV reads bigger codes itself (rescued codes on the bench
        # measured 12-25 px a side); not too skewed
        mean_side = side.mean(axis=1)
        keep = ((side.min(axis=1) >= 8.0) & (mean_side <= p.rescue_max_side_px)
                & (side.max(axis=1) <= 3.0 * side.min(axis=1)))
        if not keep.any():
            return [], none
        if len(found):
            fc = np.asarray(found, np.float64).reshape(-1, 4, 2).sum(axis=1) * 0.25
            dd = quads.sum(axis=1)[:, None] * 0.25 - fc[None]
            dist = np.sqrt((dd * dd).sum(axis=2)).min(axis=1)
            keep &= dist > 0.5 * mean_side
        quads = quads[keep][: p.rescue_max]
        if len(quads) == 0:
            return [], none
        pats, pat_ids = self._patterns[dvalue]  # (4 rotations, ids, bits)
        ctr = quads.mean(axis=1, keepdims=True)
        radial = quads - ctr
        radial /= np.sqrt((radial * radial).sum(axis=2, keepdims=True))
        shifts = p.rescue_shifts_px  # outward along the diagonals
        T = np.stack([quads + sh * radial for sh in shifts], axis=1)  # (Q, shifts, 4, 2)
        Q, S = len(quads), len(shifts)
        reading = self._readers[dvalue].read(gray, T.reshape(-1, 4, 2))
        bits = reading.bits.reshape(Q, S, -1).astype(np.float32)
        P = pats.reshape(-1, pats.shape[2]).astype(np.float32)  # (4 * ids, bits)
        ham = bits @ (1.0 - P).T + (1.0 - bits) @ P.T  # Hamming distances (Q, S, 4 * ids)
        ok = ((reading.contrast >= p.rescue_min_contrast)
              & (reading.black_offset <= p.rescue_max_black_offset)).reshape(Q, S)
        ham = np.where(ok[..., None], ham, 99)
        out: list[CodeDetection] = []
        read = np.zeros(len(quads), bool)
        A = len(pat_ids)
        tol = self._rescue_errors[dvalue]
        best = ham.min(axis=(1, 2))
        for q in np.nonzero(best <= tol)[0]:
            hits = np.argwhere(ham[q] == best[q])  # (shift, rotation * A + id index)
            if len({(int(pat_ids[j % A]), int(j // A)) for _, j in hits}) != 1:
                continue  # two codes (or turns) read equally well: not trusted
            _shift, j = hits[0]
            rot, mid = int(j // A), int(pat_ids[j % A])
            if any(c.marker_id == mid and np.abs(c.raw_corners.mean(axis=0)
                                                 - quads[q].mean(axis=0)).max() < 3.0
                   for c in out):
                read[q] = True
                continue  # the same code from OpenCV's quad and from a ring's hull
            lay, k, slot = owners[mid]
            # the grid read with the corners rolled by `rot` is the code upright
            out.append(CodeDetection(mid, lay, k, slot, np.roll(quads[q], -rot, axis=0)))
            read[q] = True
        # the budget of the second look: unread quads whose reading shows a code's frame (a
        # uniform black border, cells with contrast: `ok` at some shift), or that read
        # closer to one of our codes than chance; a ring's hull that takes in a pyramid's
        # edge reads 9-11 bits off and still holds a code the second look finds
        promising = ok.any(axis=1) | (best <= self._look_errors[dvalue])
        return out, quads[~read & promising]

    def _second_look(self, gray, quads, found, dvalue, ids, owners) -> list[CodeDetection]:
        """Codes too small or too blurred for the first pass: around quads it found but could
        not read, the region is enlarged twice (bilinear) and searched again with a wider,
        softer threshold (at twice the size a code's cells are 3–4 px; the 1-px white rim
        between a code and a dark brick face survives). Codes read there go through the same
        corner fit and cell check as all others."""
        p = self.params
        det = self._second_detectors.get(dvalue)
        if det is None:
            dp = self._detector_params()
            dp.adaptiveThreshWinSizeMin = dp.adaptiveThreshWinSizeMax = p.second_look_window
            dp.adaptiveThreshConstant = float(p.second_look_constant)
            dp.minMarkerPerimeterRate = 0.05
            det = cv2.aruco.ArucoDetector(self._detectors_by_dvalue[dvalue].getDictionary(),
                                          dp, cv2.aruco.RefineParameters())
            self._second_detectors[dvalue] = det
        H, W = gray.shape[:2]
        centres = [np.asarray(f, np.float64).reshape(4, 2).mean(axis=0) for f in found]
        out: list[CodeDetection] = []
        done: set[int] = set()
        side = np.sqrt((np.diff(quads, axis=1, append=quads[:, :1]) ** 2).sum(axis=2)).mean(1)
        small = np.nonzero(side <= p.second_look_max_side_px)[0]
        for q in small[np.argsort(-side[small])][: p.second_look_max]:
            ctr = quads[q].mean(axis=0)
            if any(np.hypot(*(ctr - c)) < 0.5 * side[q] for c in centres):
                continue
            pad = 0.75 * side[q]
            x0, y0 = np.maximum(np.floor(quads[q].min(axis=0) - pad), 0).astype(int)
            x1, y1 = np.minimum(np.ceil(quads[q].max(axis=0) + pad), [W, H]).astype(int)
            if x1 - x0 < 8 or y1 - y0 < 8:
                continue
            up = cv2.resize(gray[y0:y1, x0:x1], None, fx=2.0, fy=2.0,
                            interpolation=cv2.INTER_LINEAR)
            corners, idx, _ = det.detectMarkers(up)
            if idx is None:
                continue
            for c, i in zip(corners, np.ravel(idx)):
                mid = int(ids[int(i)])
                if mid in done:
                    continue
                # pixel centres: x_up = 2 x + 0.5
                cq = (np.asarray(c, np.float64).reshape(4, 2) - 0.5) / 2.0 + [x0, y0]
                if any(np.hypot(*(cq.mean(axis=0) - cc)) < 0.5 * side[q] for cc in centres):
                    continue
                lay, k, slot = owners[mid]
                out.append(CodeDetection(mid, lay, k, slot, cq))
                centres.append(cq.mean(axis=0))
                done.add(mid)
        return out

    def reset(self) -> None:
        """Forget the stream's past poses."""
        if self.history is not None:
            self.history = PoseHistory()

    def detect(self, image: np.ndarray, gravity: np.ndarray | None = None) -> list[BrickPose]:
        """Bricks in one frame (BGR or grey uint8), their poses ``camera_from_brick``.

        Args:
            image: The frame.
            gravity: Unit gravity vector in the camera frame (pointing down), if known.

        Returns:
            One :class:`BrickPose` per brick found, sorted by layout name and instance.
        """
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if gray.shape[:2] != (self.camera.height, self.camera.width):
            raise ValueError(f"frame is {gray.shape[1]}×{gray.shape[0]} but the camera file "
                             f"is for {self.camera.width}×{self.camera.height}")
        if self.history is not None:
            self.history.next_frame()
        self.timing.frames += 1
        codes = self.detect_codes(gray)
        t0 = time.perf_counter()
        groups: dict[tuple[str, int, int], list[CodeDetection]] = {}
        for c in codes:
            if c.refined is None or not c.refined.ok:
                continue
            groups.setdefault((c.layout.name, c.instance, 0), []).append(c)
        groups = self._split_duplicates(groups)
        g = unit_gravity(gravity)
        results: dict[tuple[str, int, int], tuple] = {}
        for key, group in groups.items():
            res = self._solve(group, PoseEvidence(gravity=g,
                                                  previous=self._previous(key)))
            if res is not None:
                results[key] = res
        # second pass: undecided bricks, with the "up" of the decided ones in this frame
        if any(r[0].ambiguous for r in results.values()):
            chosen = [r[0] for r in results.values()]
            up = decided_up(np.array([cv2.Rodrigues(d.rvec.reshape(3, 1))[0] for d in chosen]),
                            [d.decided_by for d in chosen], np.array([d.ambiguous for d in chosen]))
            for key, (res, group) in list(results.items()):
                if up is not None and res.ambiguous:
                    res2 = self._solve(group, PoseEvidence(
                        gravity=g, reference_up=up, previous=self._previous(key)))
                    if res2 is not None:
                        results[key] = res2
        self.last_codes = codes
        self.last_results = {(key[:2] if key[2] == 0 else key): r[0]
                             for key, r in results.items()}
        out: list[BrickPose] = []
        for key in sorted(results):
            res, group = results[key]
            lay = group[0].layout
            duplicate = key[2] > 0
            if self.history is not None and not res.ambiguous and not duplicate:
                self.history.update(key[:2], res.rvec, res.tvec)
            img_pts = (group[0].refined.corners_px.copy() if len(group) == 1 else
                       np.concatenate([c.refined.corners_px for c in group]))
            out.append(BrickPose(
                layout=lay.name, instance=int(key[1]), method="aruco",
                rvec=np.asarray(res.rvec, np.float64), tvec=np.asarray(res.tvec, np.float64),
                reprojection_rmse_px=float(res.rmse_px),
                markers=sorted(c.marker_id for c in group), ambiguous=bool(res.ambiguous),
                alternatives=[(a.rvec, a.tvec) for a in res.alternatives],
                symmetric=False, covariance=res.covariance, image_points=img_pts,
                duplicate=duplicate))
        self.timing.pose_s += time.perf_counter() - t0
        return out

    def _previous(self, key):
        if self.history is None or key[2] > 0:  # a duplicate has no identity to follow
            return None
        return self.history.previous(key[:2])

    def _split_duplicates(self, groups: dict[tuple[str, int, int], list[CodeDetection]]
                          ) -> dict[tuple[str, int, int], list[CodeDetection]]:
        """Codes whose id was read more than once in the frame (one printed id on several
        objects) are taken out of their brick and each posed on its own, under keys
        ``(layout, instance, 1..)`` (flagged ``duplicate``): which copy belongs to the
        brick's other codes is unknown, and merging them would make one wrong brick. The
        brick's remaining codes keep key ``(layout, instance, 0)``. Counts per id go to
        :attr:`last_duplicates`."""
        self.last_duplicates = {}
        out: dict[tuple[str, int, int], list[CodeDetection]] = {}
        for (name, inst, _), group in groups.items():
            ids = [c.marker_id for c in group]
            dup = {i for i in ids if ids.count(i) > 1}
            if not dup:
                out[(name, inst, 0)] = group
                continue
            rest = [c for c in group if c.marker_id not in dup]
            if rest:
                out[(name, inst, 0)] = rest
            # copies in image order (top to bottom, left to right): stable keys for a frame
            copies = sorted((c for c in group if c.marker_id in dup),
                            key=lambda c: (c.marker_id, *c.refined.corners_px.mean(axis=0)[::-1]))
            for k, c in enumerate(copies, start=1):
                out[(name, inst, k)] = [c]
            for i in dup:
                self.last_duplicates[i] = ids.count(i)
        return out

    def _solve(self, group: list[CodeDetection], evidence: PoseEvidence):
        """Joint pose of one brick from its codes; (PoseResult, group) or None."""
        lay = group[0].layout
        corners_m = self._corners_m.get(id(lay))
        if corners_m is None:
            corners_m = self._corners_m[id(lay)] = lay.code_corners_m()
        if len(group) == 1:
            c0 = group[0]
            obj, img, xn = corners_m[c0.slot], c0.refined.corners_px, c0.refined.corners_norm
        else:
            obj = np.concatenate([corners_m[c.slot] for c in group])
            img = np.concatenate([c.refined.corners_px for c in group])
            xn = np.concatenate([c.refined.corners_norm for c in group])
        if len(group) == 1:
            info = group[0].info
        else:  # codes are fitted independently: block-diagonal
            info = np.zeros((8 * len(group), 8 * len(group)))
            for i, c in enumerate(group):
                info[8 * i:8 * i + 8, 8 * i:8 * i + 8] = c.info
        res = solve_brick_pose(obj, img, self.camera, image_pts_norm=xn, points_info=info,
                               evidence=evidence, rule=self.params.ambiguity,
                               gravity_prior_deg=self.params.gravity_prior_deg, planar=None,
                               point_groups=np.repeat(np.arange(len(group)), 4))
        if res is None or not np.isfinite(res.rmse_px) or (
                res.rmse_px > self.params.max_rmse_px
                and not self._fit_explained(res, group, obj, img, info)):
            if len(group) > 1:  # one code may be wrong: keep the best single-code pose
                singles = [self._solve([c], evidence) for c in group]
                singles = [s for s in singles if s is not None]
                if singles:
                    return min(singles, key=lambda s: s[0].rmse_px)
            return None
        return res, group


    def _fit_explained(self, res, group: list[CodeDetection], obj: np.ndarray, img: np.ndarray,
                       info: np.ndarray) -> bool:
        """Whether a joint fit worse than ``max_rmse_px`` is still right.

        Several codes: when their residuals are consistent with the corner noise measured
        robustly in them (χ² at that noise ≤ 3·dof + 4, the ambiguity rule's test,
        :func:`drovisio.pose.ambiguity.noise_scale`): noisy corners or a camera model that
        fits the whole board a little worse, not one code grouped wrongly (its residuals
        would stand out from the others'). One code (2 degrees of freedom cannot measure
        noise): when OpenCV's own corners of that code fit the camera no better (within
        1.5×, the spread of independent corner estimates): the residual is then the camera
        model's, not the corners' (both judged by the same unweighted planar PnP).
        """
        dof = 2 * len(img) - 6
        if len(group) > 1:
            px, _ = self.camera.project_points(obj.reshape(-1, 1, 3), res.rvec, res.tvec)
            r = (px.reshape(-1, 2) - img).ravel()
            try:
                e = np.linalg.cholesky(info).T @ r
            except np.linalg.LinAlgError:
                return False
            return float(e @ e) / noise_scale(e, dof) <= 3.0 * dof + 4.0
        ours = self._plain_rmse(obj, img)
        raw = self._plain_rmse(obj, group[0].raw_corners)
        return ours <= 1.5 * raw

    def _plain_rmse(self, obj: np.ndarray, pts: np.ndarray) -> float:
        """RMS residual (px) of the unweighted planar PnP (IPPE) of one code's corners: how
        well the camera model explains those four points as the square they are."""
        xn = self.camera.normalize(pts)
        if not np.all(np.isfinite(xn)):
            return float("inf")
        try:
            ok, rv, tv = cv2.solvePnP(obj.reshape(-1, 1, 3), xn.reshape(-1, 1, 2), np.eye(3),
                                      None, flags=cv2.SOLVEPNP_IPPE)
        except cv2.error:
            return float("inf")
        if not ok:
            return float("inf")
        px, _ = self.camera.project_points(obj.reshape(-1, 1, 3), rv, tv)
        return float(np.sqrt(((px.reshape(-1, 2) - pts) ** 2).sum(axis=1).mean()))


def detect_aruco(image: np.ndarray, camera: Camera, layouts, gravity: np.ndarray | None = None
                 ) -> list[BrickPose]:
    """One-shot convenience: :class:`ArucoBrickDetector` ``(camera, layouts).detect(...)``."""
    return ArucoBrickDetector(camera, layouts).detect(image, gravity)
