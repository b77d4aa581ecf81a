"""The live view's drawing: this frame's detections over the camera image."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from drovisio.camera import Camera

__all__ = ["annotate"]

_TARGET = (0, 210, 255)   # BGR yellow
_CODE = (255, 160, 40)
_DOT = (60, 60, 255)
_WHITE = (255, 255, 255)
#: a brick's axes drawn 10 cm long: origin, x, y, z (brick frame, metres)
_AXES = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], np.float64)


def _short(layout: str) -> str:
    return layout.replace("drick-", "")


def _draw_evidence(img: np.ndarray, m: Any, is_target: bool) -> None:
    """The measurement's image points (pixels): code outlines (groups of four corners), then
    dots as circles."""
    pts = np.asarray(m.image_points, np.float64).reshape(-1, 2)
    if m.method in ("aruco", "fused") and len(pts) >= 4:
        n4 = len(pts) // 4 * 4
        for q in pts[:n4].reshape(-1, 4, 2):
            cv2.polylines(img, [np.round(q).astype(np.int32)], True,
                          _TARGET if is_target else _CODE, 2, cv2.LINE_AA)
        rest = pts[n4:]
    else:
        rest = pts
    for p in rest:
        cv2.circle(img, (int(round(p[0])), int(round(p[1]))), 5,
                   _TARGET if is_target else _DOT, 2, cv2.LINE_AA)


def _draw_axes(img: np.ndarray, b: Any, camera: Camera, is_target: bool) -> None:
    """A brick's axes (x red, y green, z blue; thin when predicted) with its name and
    distance; nothing when they do not project to sensible pixels."""
    c = camera.cv_project(_AXES, b.rvec, b.tvec)
    if not np.all(np.isfinite(c)) or np.abs(c).max() > 1e5:
        return
    o = tuple(int(v) for v in np.round(c[0]))
    for k, col in ((1, (0, 0, 255)), (2, (0, 200, 0)), (3, (255, 0, 0))):
        cv2.line(img, o, tuple(int(v) for v in np.round(c[k])), col,
                 2 if b.measured else 1, cv2.LINE_AA)
    x, y = o
    name = _short(b.layout) + (f":{b.instance}" if b.instance is not None else f" #{b.track}")
    text = f"{name} {b.distance:.2f}m" + ("" if b.measured else " (pred)")
    for col, th in (((0, 0, 0), 4), (_TARGET if is_target else _WHITE, 1)):
        cv2.putText(img, text, (x + 8, y - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, col,
                    th, cv2.LINE_AA)


def annotate(image: np.ndarray, output: Any, camera: Camera | None) -> np.ndarray:
    """The frame with this frame's detections: code outlines, dot circles, each tracked
    brick's axes (10 cm) with its name and distance; the target in yellow.

    Args:
        image: The camera image, BGR (H, W, 3) or grey (H, W), uint8.
        output: The pipeline's output of this frame (None: the image alone).
        camera: The camera (None: no axes).

    Returns:
        A BGR copy (H, W, 3) with the drawing.
    """
    img = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if output is None:
        return img
    tkey = None if output.target is None else output.target.track
    for b in output.bricks:
        is_t = b.track == tkey
        m = b.measurement
        if m is not None and m.image_points is not None:
            _draw_evidence(img, m, is_t)
        if camera is not None and b.tvec[2] > 0.05:
            try:
                _draw_axes(img, b, camera, is_t)
            except cv2.error:
                pass
    return img
