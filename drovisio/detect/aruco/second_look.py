"""Stage 3, the second look: codes too small or too blurred for the first pass.

Around the quads the rescue could not read but that show a code's frame (or read close to one
of our codes), the region is enlarged twice (bilinear) and searched again by OpenCV with a
wider, softer threshold: at twice the size a code's cells are 3–4 px and the 1-px white rim
between a code and a dark brick face survives. Only families with small cells get it
(:attr:`drovisio.detect.aruco.families.CodeFamily.small_cells`). Codes read here go through
the same corner fit and cell check as all others.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.detect.aruco.codes import CodeDetection
from drovisio.detect.aruco.families import CodeFamily, second_look_detector
from drovisio.detect.aruco.params import ArucoParams

__all__ = ["second_look"]


def _window(quad: np.ndarray, side: float, shape: tuple[int, ...]
            ) -> tuple[int, int, int, int] | None:
    """The region (x0, y0, x1, y1), px, searched around a quad: its box padded by three
    quarters of its side, clipped to the image; None when under 8 px."""
    H, W = shape[:2]
    pad = 0.75 * side
    x0, y0 = np.maximum(np.floor(quad.min(axis=0) - pad), 0).astype(int)
    x1, y1 = np.minimum(np.ceil(quad.max(axis=0) + pad), [W, H]).astype(int)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    return int(x0), int(y0), int(x1), int(y1)


def _near(centre: np.ndarray, centres: list[np.ndarray], radius: float) -> bool:
    return any(np.hypot(*(centre - c)) < radius for c in centres)


def second_look(gray: np.ndarray, quads: np.ndarray, found: Sequence[np.ndarray],
                family: CodeFamily, params: ArucoParams, camera: Camera
                ) -> list[CodeDetection]:
    """The codes found by searching around unread quads at twice the size.

    Args:
        gray: (H, W) uint8 frame.
        quads: (U, 4, 2) unread quads, px (from the rescue); the largest
            ``second_look_max`` of those up to ``second_look_max_side_px`` are looked at.
        found: Corners (4, 2) px of the family's codes already read (not looked for again).
        family: The code family.
        params: The detector's tuning (the second look's group).
        camera: The camera (the detector's perimeter limit is set from its image size).

    Returns:
        The new codes, corners in px of the frame.
    """
    p = params
    det = second_look_detector(family, params, camera)
    centres = [np.asarray(f, np.float64).reshape(4, 2).mean(axis=0) for f in found]
    out: list[CodeDetection] = []
    done: set[int] = set()
    side = np.sqrt((np.diff(quads, axis=1, append=quads[:, :1]) ** 2).sum(axis=2)).mean(1)
    small = np.nonzero(side <= p.second_look_max_side_px)[0]
    for q in small[np.argsort(-side[small])][: p.second_look_max]:
        if _near(quads[q].mean(axis=0), centres, 0.5 * side[q]):
            continue
        box = _window(quads[q], side[q], gray.shape)
        if box is None:
            continue
        x0, y0, x1, y1 = box
        up = cv2.resize(gray[y0:y1, x0:x1], None, fx=2.0, fy=2.0,
                        interpolation=cv2.INTER_LINEAR)
        corners, idx, _ = det.detectMarkers(up)
        if idx is None:
            continue
        for c, i in zip(corners, np.ravel(idx)):
            mid = int(family.ids[int(i)])
            if mid in done:
                continue
            # pixel centres: x_up = 2 x + 0.5
            cq = (np.asarray(c, np.float64).reshape(4, 2) - 0.5) / 2.0 + [x0, y0]
            if _near(cq.mean(axis=0), centres, 0.5 * side[q]):
                continue
            lay, k, slot = family.owners[mid]
            out.append(CodeDetection(mid, lay, k, slot, cq))
            centres.append(cq.mean(axis=0))
            done.add(mid)
    return out
