"""Image degradations applied after rendering: blur, motion blur, lighting, noise, JPEG."""

from __future__ import annotations

import math
from typing import cast

import cv2
import numpy as np

from drovisio.synth.scene import Effects

__all__ = ["apply_effects", "motion_kernel"]


def motion_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """A linear motion-blur streak of ``length_px`` pixels at ``angle_deg`` (0 = along +x):
    the streak's points splatted bilinearly, (4n + 1, 4n + 1), not normalised."""
    n = int(math.ceil(length_px)) | 1
    k = np.zeros((n * 4 + 1, n * 4 + 1), np.float32)
    c = n * 2
    a = math.radians(angle_deg)
    for s in np.linspace(-length_px / 2, length_px / 2, int(length_px * 8) + 1):
        x, y = c + s * math.cos(a), c + s * math.sin(a)
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        wx, wy = x - x0, y - y0
        k[y0, x0] += (1 - wx) * (1 - wy)
        k[y0, x0 + 1] += wx * (1 - wy)
        k[y0 + 1, x0] += (1 - wx) * wy
        k[y0 + 1, x0 + 1] += wx * wy
    return k


def apply_effects(img: np.ndarray, fx: Effects) -> np.ndarray:
    """Blur, motion blur, lighting, noise and JPEG on a float BGR image → uint8."""
    out: np.ndarray = np.asarray(img, np.float32)
    if fx.blur_sigma_px > 0:
        out = cv2.GaussianBlur(out, (0, 0), fx.blur_sigma_px)
    if fx.motion_px > 0:
        k = motion_kernel(fx.motion_px, fx.motion_angle_deg)
        out = cv2.filter2D(out, -1, k / k.sum())
    if fx.gain != 1.0 or fx.gamma != 1.0:
        out = 255.0 * np.power(np.clip(out * fx.gain / 255.0, 0, 1), fx.gamma)
    if fx.noise_sigma > 0:
        rng = np.random.default_rng(fx.seed)
        out = out + rng.normal(0, fx.noise_sigma, out.shape).astype(np.float32)
    u8: np.ndarray = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    if fx.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, int(fx.jpeg_quality)])
        u8 = cast(np.ndarray, cv2.imdecode(buf, cv2.IMREAD_COLOR))
    return u8
