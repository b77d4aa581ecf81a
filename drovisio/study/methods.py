"""The methods compared, on the same frames: Drovisio (codes; dots), plain OpenCV
(``ArucoDetector`` with default parameters, then ``solvePnP``) and AprilTag 3
(``pupil-apriltags``, the ``peers`` extra).

Every method gets the frame and the camera and answers ``camera_from_brick`` of the bricks it
found (Drovisio also its ``ambiguous`` flag). Drovisio is run twice: given gravity as a
drone's autopilot gives it (the brick's down in the camera frame, 1° attitude error), and on
the image alone like the others. Plain OpenCV and AprilTag 3 pose a brick from
all its detected codes' corners at once with ``solvePnP``'s default (iterative) solver, the
lens's distortion given to it (OpenCV 5's ``SOLVEPNP_IPPE`` turned the two-code brick, whose
codes lie on a plane 2 cm above the brick's origin, upside down: 180° off, measured); AprilTag 3 does not model distortion, so its frames are undistorted first
(``cv2.undistort``, same K) and its corners, which count pixel centres from 0.5 (the top-left
pixel's corner is 0), are moved by −0.5 px into OpenCV's convention (pixel centres at
integers).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.detect.dots import DotDetector
from drovisio.layout import aruco_dictionary_id
from drovisio.study.apriltag import (
    APRILTAG_FAMILIES,
    APRILTAG_PIXEL_OFFSET,
    apriltag_detector,
    apriltag_reader,
)

__all__ = ["APRILTAG_FAMILIES", "APRILTAG_PIXEL_OFFSET", "METHODS", "Method",
           "apriltag_detector", "method_reason"]

Estimator = Callable[[np.ndarray, np.ndarray | None],
                     list[tuple[str, int | None, np.ndarray, bool]]]


@dataclass(frozen=True)
class Method:
    """A method of the study."""

    name: str
    label: str
    colour: str
    applies: Callable[[object], str | None]
    """``layout -> None`` when it can read the layout, else why not (one line)."""
    make: Callable[[object, list], Estimator]
    """``(camera, layouts) -> estimate(image_bgr, gravity)``."""
    gravity: bool = False
    """Given the drone's gravity (the others get None)."""
    accuracy_only: bool = False
    """Left out of the speed and memory runs (the same detector as another method)."""


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.ravel(t)
    return T


# ------------------------------------------------------------------------------ Drovisio
def _drovisio(detector: str) -> Callable[[object, list], Estimator]:
    """A factory of Drovisio estimators (``"aruco"`` or ``"dots"``)."""
    def make(camera, layouts) -> Estimator:
        det: Any
        if detector == "aruco":
            det = ArucoBrickDetector(camera, layouts)
        else:
            det = DotDetector(camera, layouts)

        def estimate(img: np.ndarray, g: np.ndarray | None = None) -> list:
            return [(p.layout, p.instance, p.camera_from_brick(), bool(p.ambiguous))
                    for p in det.detect(img, gravity=g)]
        return estimate
    return make


def _needs_codes(layout) -> str | None:
    return None if layout.has_codes else "the layout has no codes"


def _needs_dots(layout) -> str | None:
    return None if layout.has_dots else "the layout has no colour dots"


# ------------------------------------------------------------------------ plain OpenCV
def _pnp_bricks(camera_K, dist, layouts, found: dict[int, np.ndarray]):
    """Pose every brick from its found codes' corners (ids → (4, 2) px)."""
    out = []
    for lay in layouts:
        corners_m = lay.code_corners_m()
        for k in range(lay.instances or 0):
            obj, img = [], []
            for slot, c in corners_m.items():
                mid = lay.marker_id(k, slot)
                if mid in found:
                    obj.append(c)
                    img.append(found[mid])
            if not obj:
                continue
            o = np.concatenate(obj).astype(np.float64)
            i = np.concatenate(img).astype(np.float64)
            ok, rvec, tvec = cv2.solvePnP(o, i, camera_K, dist)   # OpenCV's default flags
            if ok:
                out.append((lay.name, k, _pose(cv2.Rodrigues(rvec)[0], tvec), False))
    return out


def _opencv(camera, layouts) -> Estimator:
    dets = []
    for d in sorted({dd for lay in layouts for dd in lay.dictionaries()}):
        dets.append(cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(d)),
            cv2.aruco.DetectorParameters()))
    K, dist = camera.K, camera.dist

    def estimate(img, g=None):
        found: dict[int, np.ndarray] = {}
        for det in dets:
            corners, ids, _ = det.detectMarkers(img)
            if ids is not None:
                for c, i in zip(corners, np.ravel(ids)):
                    found[int(i)] = np.asarray(c, np.float64).reshape(4, 2)
        return _pnp_bricks(K, dist, layouts, found)
    return estimate


# -------------------------------------------------------------------------- AprilTag 3
def _apriltag_applies(layout) -> str | None:
    if not layout.has_codes:
        return "the layout has no codes"
    try:
        import pupil_apriltags  # noqa: F401  (optional: the peers extra)
    except ImportError:
        return "AprilTag 3 is not installed: pip install drovisio[peers]"
    return None


def _apriltag(camera, layouts) -> Estimator:
    det = apriltag_reader(sorted({d for lay in layouts for d in lay.dictionaries()}))
    K = camera.K
    maps = None
    if camera.model == "fisheye":
        maps = cv2.fisheye.initUndistortRectifyMap(K, camera.dist, np.eye(3), K,
                                                   camera.size, cv2.CV_16SC2)
    else:
        maps = cv2.initUndistortRectifyMap(K, camera.dist, np.eye(3), K, camera.size,
                                           cv2.CV_16SC2)

    def estimate(img, g=None):
        gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
        und = cv2.remap(gray, maps[0], maps[1], cv2.INTER_LINEAR)
        found = {code.marker_id: code.corners for code in det.detect(und)}
        return _pnp_bricks(K, np.zeros(5), layouts, found)
    return estimate


METHODS: dict[str, Method] = {
    "drovisio-codes": Method("drovisio-codes", "Drovisio (codes)", "#0b4fa8", _needs_codes,
                             _drovisio("aruco"), gravity=True),
    "drovisio-codes-image": Method("drovisio-codes-image", "Drovisio (codes), image only",
                                   "#6fa8dc", _needs_codes, _drovisio("aruco"),
                                   accuracy_only=True),
    "drovisio-dots": Method("drovisio-dots", "Drovisio (dots)", "#c0392b", _needs_dots,
                            _drovisio("dots"), gravity=True),
    "drovisio-dots-image": Method("drovisio-dots-image", "Drovisio (dots), image only",
                                  "#e6a19a", _needs_dots, _drovisio("dots"), accuracy_only=True),
    "opencv": Method("opencv", "plain OpenCV", "#7f8c8d", _needs_codes, _opencv),
    "apriltag3": Method("apriltag3", "AprilTag 3", "#e67e22", _apriltag_applies, _apriltag),
}


def method_reason(name: str, layout) -> str | None:
    """None when ``name`` can read ``layout``, else why not."""
    return METHODS[name].applies(layout)
