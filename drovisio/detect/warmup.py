"""Compile (or load) the detectors' numba kernels before the first frame needs them.

numba compiles a kernel on its first call (all of them: 160 s on a busy 2-core machine, once
per machine; later processes load the machine code from ``__pycache__`` in well under a second). Without a
warm-up the first frame of the first run waits for it: ``make install`` runs this module, and
``drovisio serve`` calls :func:`warm_up` in a background thread at start (and waits for it at
exit: a thread left compiling as the interpreter exits aborts the process). The frame used is
drawn, not rendered (a few milliseconds): the shipped colour-dot drick and an ArUco drick seen
from 0.8 m, so that every kernel runs with the argument types of real frames.

    python -m drovisio.detect.warmup
"""

from __future__ import annotations

import math
import sys
import time

import cv2
import numpy as np

from drovisio import _numba
from drovisio.camera import Camera
from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.detect.dots import DotsState, detect_dots
from drovisio.detect.dots import kernels as K
from drovisio.layout import load_layout, shipped_layouts_dir

__all__ = ["warm_up", "warm_up_frame"]


def _pose(tilt_deg: float, x: float) -> np.ndarray:
    """camera_from_brick: the camera 0.8 m above the brick, looking down, tilted."""
    a = math.radians(180.0 + tilt_deg)
    R = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)],
                  [0.0, math.sin(a), math.cos(a)]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [x, 0.0, 0.8]
    return T


def warm_up_frame(camera=None):
    """(BGR frame, gravity in the camera frame, camera, dots layout, code layouts): a grey
    ground with one dot drick and one ArUco drick drawn on it."""
    cam = camera or Camera.drone_webcam()
    d = shipped_layouts_dir()
    dots = load_layout(d / "drick-dots-2x3.json")
    codes = load_layout(d / "drick-aruco-centre.json")
    img = np.full((cam.height, cam.width, 3), 128, np.uint8)
    # the dots: each a filled projected circle in a colour inside its palette range
    T = _pose(10.0, -0.12)
    pal = dots.palette()
    ang = np.linspace(0, 2 * math.pi, 48, endpoint=False)
    for c, n, dia, name in zip(dots.dot_centers_m(), dots.dot_normals(),
                               dots.dot_diameters_m(), dots.dot_colors()):
        u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        rim = c + 0.5 * dia * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
        px = cam.project_from(rim, T)
        lo, hi = np.asarray(pal[name].hsv, float)
        h = (lo[0] + (hi[0] + 180 if lo[0] > hi[0] else hi[0])) / 2 % 180
        hsv = np.uint8([[[h, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2]]])
        bgr = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0].tolist()
        cv2.fillPoly(img, [np.round(px * 16).astype(np.int32)], bgr, cv2.LINE_AA, shift=4)
    # one code, warped from its image (with a white margin) onto its projected corners
    T2 = _pose(10.0, 0.14)
    slot, corners = next(iter(codes.code_corners_m().items()))
    dic = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, codes.code_dictionaries()[slot]))
    side = 120
    code = cv2.aruco.generateImageMarker(dic, codes.marker_id(0, slot), side)
    pad = side // 4
    tile = cv2.copyMakeBorder(code, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    src = np.float32([[pad, pad], [pad + side, pad], [pad + side, pad + side],
                      [pad, pad + side]]) - 0.5
    dst = cam.project_from(corners, T2).astype(np.float32)
    H = cv2.getPerspectiveTransform(src, dst)
    warped = cv2.warpPerspective(cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR), H,
                                 (cam.width, cam.height), flags=cv2.INTER_LINEAR,
                                 borderValue=(0, 0, 0))
    mask = cv2.warpPerspective(np.full(tile.shape, 255, np.uint8), H,
                               (cam.width, cam.height)) > 0
    img[mask] = warped[mask]
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    gravity = T[:3, :3] @ np.array([0.0, 0.0, -1.0])
    return img, gravity, cam, dots, [codes]


def warm_up() -> dict:
    """Run both detectors once on :func:`warm_up_frame` (with and without gravity).

    Returns:
        ``{"seconds": …, "dots": bricks found, "codes": bricks found, "compiled": bool}``.
    """
    t0 = time.perf_counter()
    if not _numba.enabled():
        return {"seconds": 0.0, "dots": 0, "codes": 0, "compiled": False}
    # kernels the frame may not reach (blob holes, a re-solve after a dropped dot), with the
    # argument types the detector passes
    K.polygon_areas(np.zeros((3, 2), np.int32), np.zeros(1, np.int64), np.array([3]))
    K.refine_poses(np.zeros((1, 4, 3)), np.zeros((1, 4, 2)), np.ones((1, 4)),
                   np.eye(3)[None].copy(), np.array([[0.0, 0.0, 1.0]]), 1, 1e-8)
    img, g, cam, dots, codes = warm_up_frame()
    found = detect_dots(img, cam, [dots], gravity=g)
    detect_dots(img, cam, [dots], state=DotsState())
    det = ArucoBrickDetector(cam, codes)
    coded = det.detect(img, gravity=g)
    det.detect(img)
    return {"seconds": time.perf_counter() - t0, "dots": len(found), "codes": len(coded),
            "compiled": True}


def main() -> int:
    if not _numba.enabled():
        print("drovisio: numba is not available here; the detectors use their numpy code",
              file=sys.stderr)
        return 0
    print("drovisio: preparing the detectors' compiled kernels (the first time on a machine: "
          "about 3 min on a small laptop; later runs load them in seconds)...",
          file=sys.stderr, flush=True)
    r = warm_up()
    print(f"drovisio: kernels ready in {r['seconds']:.1f} s (test frame: {r['dots']} dot "
          f"brick, {r['codes']} code brick found)", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
