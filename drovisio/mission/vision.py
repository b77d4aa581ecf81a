"""Vision for the mission simulator: a detector *model*, or renders through real detectors.

Both give, for a camera pose in the site frame and the bricks where they truly are, a list of
:class:`Seen` (layout, instance, ``camera_from_brick``), the DESIGN.md pose convention
(``X_cam = R · X_brick + t``, OpenCV camera frame). The simulator turns them into the
machine's body-frame sightings with the camera mount.

* :class:`DetectorModel` — fast: projects every marker with the real camera model and keeps a
  brick if its markers are in the image (field of view, margin), in front of the camera
  between ``min_distance_m`` and ``max_distance_m``, facing it, and not covered by a brick
  lying on them (codes: at least one code; dots: all six, as the thesis's grouping needs);
  then misses it with probability ``miss_prob`` and adds pose noise that grows with distance.
* :class:`RenderVision` — slow and end to end: renders the scene with :mod:`drovisio.synth`
  and runs the real detectors on the image (:func:`find_detector`).

The held brick is not drawn or modelled: the camera is assumed mounted clear of the payload.
"""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.detect.result import BrickPose
from drovisio.layout import MarkerLayout
from drovisio.synth import BrickInstance, Effects, Ground, Scene, render

__all__ = ["Seen", "WorldBrick", "DetectorModelParams", "DetectorModel", "RenderVision",
           "find_detector", "opencv_aruco_baseline"]


@dataclass(frozen=True)
class Seen:
    """A brick the vision reports: its pose ``camera_from_brick`` (4, 4), OpenCV camera frame,
    metres."""

    layout: str
    instance: int | None
    camera_from_brick: np.ndarray
    method: str = "model"


@dataclass
class WorldBrick:
    """A brick where it truly is (site frame)."""

    id: str
    layout: MarkerLayout
    instance: int | None
    world_from_brick: np.ndarray


@dataclass
class DetectorModelParams:
    """What :class:`DetectorModel` sees and how well: frame rate (Hz), distances (m), the
    largest angle between a marker's normal and the line of sight, the image margin (px), the
    chance to miss a brick in view, and the pose noise."""

    rate_hz: float = 10.0
    min_distance_m: float = 0.15
    max_distance_m: float = 3.0
    max_view_angle_deg: float = 65.0
    margin_px: float = 4.0
    miss_prob: float = 0.03
    lateral_sigma_rel: float = 0.002
    """Lateral position noise, standard deviation as a fraction of the distance."""
    depth_sigma_rel: float = 0.01
    yaw_sigma_deg: float = 0.3
    tilt_sigma_deg: float = 1.0


def _footprint_covers(other: WorldBrick, pts_world: np.ndarray) -> np.ndarray:
    """Which points lie under ``other`` (inside its footprint and below its top)."""
    dims = np.asarray(other.layout.dimensions_m, float)
    inv = np.linalg.inv(other.world_from_brick)
    q = pts_world @ inv[:3, :3].T + inv[:3, 3]
    return (np.abs(q[:, 0]) <= dims[0] / 2) & (np.abs(q[:, 1]) <= dims[1] / 2) & (q[:, 2] < -0.005)


Markers = tuple[list[np.ndarray], list[np.ndarray], bool]
"""A layout's point groups (brick frame, m), their normals, and whether every group is
needed."""
_MARKERS: dict[tuple[str, int], Markers] = {}


def _markers(layout: MarkerLayout) -> Markers:
    key = (layout.name, id(layout))
    if key not in _MARKERS:
        _MARKERS[key] = _markers_of(layout)
    return _MARKERS[key]


def _markers_of(layout: MarkerLayout) -> Markers:
    """Point groups of a layout (one group per code, or one group of all dots), their
    normals, and whether every group is needed (dots) or one suffices (codes)."""
    groups, normals = [], []
    if layout.has_codes:
        for slot, corners in layout.code_corners_m().items():
            groups.append(np.asarray(corners, float))
            normals.append(np.asarray(layout.code_normals()[slot], float))
        return groups, normals, False
    dots = np.asarray(layout.dot_centers_m(), float)
    for k in range(len(dots)):
        groups.append(dots[k:k + 1])
        normals.append(np.asarray(layout.dot_normals()[k], float))
    return groups, normals, True


class DetectorModel:
    """What a detector would report, without an image (see the module docstring)."""

    def __init__(self, camera: Camera, params: DetectorModelParams | None = None):
        self.camera = camera
        self.params = params or DetectorModelParams()

    def _in_view(self, pts: np.ndarray, n: np.ndarray, cfb: np.ndarray) -> bool:
        """Whether a marker group (points ``pts`` (k, 3), normal ``n``, brick frame) is in
        the picture: in range, facing the camera, inside the image's margin."""
        p = self.params
        cam = self.camera
        cos_max = math.cos(math.radians(p.max_view_angle_deg))
        pc = pts @ cfb[:3, :3].T + cfb[:3, 3]
        centre = pc.mean(axis=0)
        d = float(np.linalg.norm(centre))
        if np.any(pc[:, 2] < p.min_distance_m) or d > p.max_distance_m:
            return False
        n_c = cfb[:3, :3] @ n
        if float(-n_c @ centre) / d < cos_max:
            return False
        px = cam.project(pc)
        m = p.margin_px
        return bool(np.all(px[:, 0] >= m) and np.all(px[:, 0] <= cam.width - 1 - m)
                    and np.all(px[:, 1] >= m) and np.all(px[:, 1] <= cam.height - 1 - m))

    def observe(self, world_from_camera: np.ndarray, bricks: Sequence[WorldBrick],
                rng: np.random.Generator) -> list[Seen]:
        """The bricks a detector would report from the camera at ``world_from_camera``."""
        p = self.params
        cfw = np.linalg.inv(world_from_camera)
        out: list[Seen] = []
        for b in bricks:
            cfb = cfw @ b.world_from_brick
            if cfb[2, 3] <= 0:
                continue
            groups, normals, need_all = _markers(b.layout)
            visible = 0
            for pts, n in zip(groups, normals):
                if not self._in_view(pts, n, cfb):
                    continue
                pw = pts @ b.world_from_brick[:3, :3].T + b.world_from_brick[:3, 3]
                if any(np.any(_footprint_covers(o, pw)) for o in bricks if o is not b):
                    continue
                visible += 1
            if visible == 0 or (need_all and visible < len(groups)):
                continue
            if rng.random() < p.miss_prob:
                continue
            out.append(Seen(b.layout.name, b.instance if b.layout.has_codes else None,
                            self._noisy(cfb, visible if not need_all else 2, rng)))
        return out

    def _noisy(self, cfb: np.ndarray, n_groups: int, rng: np.random.Generator) -> np.ndarray:
        p = self.params
        d = float(np.linalg.norm(cfb[:3, 3]))
        k = 1.0 / math.sqrt(max(1, n_groups))
        T = cfb.copy()
        T[:3, 3] += rng.normal(0.0, 1.0, 3) * np.array(
            [p.lateral_sigma_rel * d, p.lateral_sigma_rel * d, p.depth_sigma_rel * d]) * k
        w = np.radians([p.tilt_sigma_deg, p.tilt_sigma_deg, p.yaw_sigma_deg]) * k
        dR = cv2.Rodrigues(rng.normal(0.0, 1.0, 3) * w)[0]
        T[:3, :3] = dR @ T[:3, :3]
        return T


# ======================================================================= real detectors
Detector = Callable[[np.ndarray, Camera, list[Any], "np.ndarray | None"], list[Any]]
"""``(image, camera, layouts, gravity) -> list[BrickPose]``."""

_Found = dict[tuple[str, int], list[tuple[int, np.ndarray]]]
"""(layout name, instance) → the codes seen of it: (slot, (4, 2) corners, px)."""


def _codes_by_dictionary(layouts: list[Any]) -> dict[str, list[Any]]:
    by_dict: dict[str, list[Any]] = {}
    for lay in layouts:
        for d in lay.dictionaries():
            by_dict.setdefault(d, []).append(lay)
    return by_dict


def _find_codes(gray: np.ndarray, dname: str, lays: list[Any]) -> _Found:
    """The codes of dictionary ``dname`` in the image, refined, grouped by brick."""
    det = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dname)),
        cv2.aruco.DetectorParameters())
    corners, ids, _ = det.detectMarkers(gray)
    found: _Found = {}
    if ids is None:
        return found
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.01)
    for c, i in zip(corners, ids.ravel()):
        c = cv2.cornerSubPix(gray, c.reshape(-1, 1, 2).astype(np.float32), (4, 4), (-1, -1),
                             crit).reshape(4, 2)
        for lay in lays:
            ks = lay.instance_slot(int(i))
            if ks is not None:
                found.setdefault((lay.name, ks[0]), []).append((ks[1], c))
    return found


def _solve_brick(camera: Camera, lay: Any, k: int, items: list[tuple[int, np.ndarray]],
                 gravity: np.ndarray | None) -> BrickPose | None:
    """IPPE on the brick's codes (the solution whose z axis points up), then refined."""
    obj = np.concatenate([lay.code_corners_m()[s] for s, _ in items]).astype(np.float64)
    img = np.concatenate([c for _, c in items]).astype(np.float64)
    # PnP in undistorted normalised coordinates: right for every lens model
    xn = camera.normalize(img)
    if not np.all(np.isfinite(xn)):
        return None
    n, rv, tv, _ = cv2.solvePnPGeneric(obj, xn, _EYE3, None, flags=cv2.SOLVEPNP_IPPE)
    best = None
    for r, t in zip(rv, tv):
        R = cv2.Rodrigues(r)[0]
        up = -np.asarray(gravity, float) if gravity is not None else np.array([0, 0, -1.0])
        score = float(R[:, 2] @ up)
        if best is None or score > best[0]:
            best = (score, r, t)
    if best is None:
        return None
    _, r, t = best
    r, t = cv2.solvePnPRefineLM(obj, xn, _EYE3, None, r.copy(), t.copy())
    proj, _ = camera.project_points(obj, r, t)
    rmse = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
    return BrickPose(lay.name, k, "aruco", r.ravel(), t.ravel(), rmse,
                     markers=[lay.marker_id(k, s) for s, _ in items])


def opencv_aruco_baseline(image: np.ndarray, camera: Camera, layouts: list[Any],
                          gravity: np.ndarray | None = None) -> list[BrickPose]:
    """A plain OpenCV detector (``cv2.aruco.ArucoDetector`` + IPPE/iterative PnP per brick),
    used only when :mod:`drovisio.detect.aruco` is not available. Returns ``BrickPose``.

    ``gravity`` (unit vector, down, camera frame) picks among IPPE's two poses the one whose
    brick z axis points up.
    """
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    out = []
    for dname, lays in _codes_by_dictionary(layouts).items():
        for (name, k), items in _find_codes(gray, dname, lays).items():
            lay = next(x for x in lays if x.name == name)
            pose = _solve_brick(camera, lay, k, items, gravity)
            if pose is not None:
                out.append(pose)
    return out


_CANDIDATES = {
    "aruco": ("drovisio.detect.aruco", ("detect_aruco", "detect_codes", "detect_bricks",
                                        "detect")),
    "dots": ("drovisio.detect.dots", ("detect_dots", "detect")),
}


def find_detector(kind: str) -> tuple[Detector, str]:
    """The project's detector for ``kind`` (``aruco`` or ``dots``) and its name.

    Looks up ``drovisio.detect.aruco`` / ``drovisio.detect.dots`` (being written alongside) for
    a function ``(image, camera, layouts, gravity=None) -> list[BrickPose]``; when the codes'
    module is missing, falls back to :func:`opencv_aruco_baseline` (and says so in the name).
    """
    module_name, names = _CANDIDATES[kind]
    try:
        mod = importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if e.name != module_name:
            raise
        mod = None
    if mod is not None:
        for n in names:
            f = getattr(mod, n, None)
            if callable(f):
                return _adapt(f), f"{module_name}.{n}"
    if kind == "aruco":
        return opencv_aruco_baseline, "opencv-aruco-baseline (drovisio.detect.aruco not found)"
    raise RuntimeError(f"no detector for {kind}: {module_name} has none of {names}")


def _adapt(f: Callable[..., Any]) -> Detector:
    def run(image: np.ndarray, camera: Camera, layouts: list[Any],
            gravity: np.ndarray | None = None) -> list[Any]:
        try:
            res = f(image, camera, layouts, gravity=gravity)
        except TypeError:
            res = f(image, camera, layouts)
        if hasattr(res, "bricks"):
            res = res.bricks
        return list(res)
    return run


class RenderVision:
    """Render the scene and run the real detectors (slow: ~0.2–0.5 s per frame)."""

    def __init__(self, camera: Camera, layouts: Sequence, ss: int = 2, ground: str = "concrete",
                 noise_sigma: float = 1.5, seed: int = 0):
        self.camera = camera
        self.layouts = list(layouts)
        self.ss = ss
        self.ground = ground
        self.noise_sigma = noise_sigma
        self.seed = seed
        self.frames = 0
        self.seconds = 0.0
        kinds = set()
        for lay in self.layouts:
            kinds.add("aruco" if lay.has_codes else "dots")
        self.detectors: list[tuple[str, Detector, str]] = []
        for k in sorted(kinds):
            det = self._stateful(k)
            self.detectors.append((k, *(det or find_detector(k))))

    def _stateful(self, kind: str) -> tuple[Detector, str] | None:
        """The codes' detector object built once (its set-up is not redone every frame)."""
        if kind != "aruco":
            return None
        try:  # deferred: the compiled detector is only needed when rendering
            from drovisio.detect.aruco import ArucoBrickDetector
        except ImportError:
            return None
        obj = ArucoBrickDetector(self.camera, [x for x in self.layouts if x.has_codes])

        def run(image: np.ndarray, camera: Camera, layouts: list[Any],
                gravity: np.ndarray | None = None) -> list[Any]:
            return list(obj.detect(image, gravity))
        return run, "drovisio.detect.aruco.ArucoBrickDetector"

    @property
    def detector_names(self) -> list[str]:
        return [name for _, _, name in self.detectors]

    def observe(self, world_from_camera: np.ndarray, bricks: Sequence[WorldBrick],
                rng: np.random.Generator) -> list[Seen]:
        """Render the view from ``world_from_camera`` and run the detectors on it."""
        t0 = time.perf_counter()
        cfw = np.linalg.inv(world_from_camera)
        scene = Scene(self.camera, cfw, ground=Ground(self.ground, self.seed),
                      bricks=[BrickInstance(b.layout, b.world_from_brick, b.instance)
                              for b in bricks])
        res = render(scene, Effects(blur_sigma_px=0.4, noise_sigma=self.noise_sigma,
                                    seed=int(rng.integers(1 << 30))), ss=self.ss)
        gravity = cfw[:3, :3] @ np.array([0.0, 0.0, -1.0])
        out: list[Seen] = []
        for kind, det, _ in self.detectors:
            lays = [x for x in self.layouts if (x.has_codes == (kind == "aruco"))]
            for bp in det(res.image, self.camera, lays, gravity):
                out.append(Seen(bp.layout, bp.instance, bp.camera_from_brick(), bp.method))
        self.frames += 1
        self.seconds += time.perf_counter() - t0
        return out


_EYE3 = np.eye(3)
