"""The dot detector's use of a stream's previous frame (kept in :class:`~.detector.DotsState`).

A symmetric brick's yaw stays in the previous frame's half-turn (instead of letting the
canonical rule flip it where the rule's boundary is), and a decided pose of the previous frame
is evidence for the planar ambiguity of the same brick now.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from drovisio.detect.dots.batch import DotBatch
from drovisio.detect.dots.model import DotModel
from drovisio.detect.result import BrickPose
from drovisio.pose import HALF_TURN

__all__ = ["PreviousBrick", "previous_flip", "previous_rotations", "remembered"]

PreviousBrick = tuple[str, np.ndarray, np.ndarray, bool]
"""(layout name, tvec, rotation matrix camera_from_brick, ambiguous) of a brick."""


def remembered(poses: Sequence[BrickPose]) -> list[PreviousBrick]:
    """This frame's bricks as the next frame will see them."""
    return [(p.layout, np.asarray(p.tvec, float).copy(),
             cv2.Rodrigues(np.asarray(p.rvec, float))[0], p.ambiguous) for p in poses]


def _previous_match(model: DotModel, t: np.ndarray, previous: list[PreviousBrick]
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


def previous_flip(model: DotModel, R: np.ndarray, t: np.ndarray,
                  previous: list[PreviousBrick]) -> bool | None:
    """With a brick of the same layout in the previous frame: whether to half-turn the
    pose (R, t) to stay in that brick's half-turn."""
    m = _previous_match(model, t, previous)
    return None if m is None else float(R[:, 0] @ m[0][:, 0]) < 0


def previous_rotations(bt: DotBatch, rows: np.ndarray, R2: np.ndarray, t2: np.ndarray,
                       previous: list[PreviousBrick] | None) -> list[np.ndarray | None] | None:
    """Per brick, the rotation of the same brick in the previous frame when that pose was
    decided (evidence for the planar ambiguity), else None. A symmetric layout's pose
    was reported in one of its half-turns: the one nearer to either candidate.

    Args:
        rows: (n,) the bricks of the batch.
        R2: (n, 2, 3, 3) and t2: (n, 2, 3): both solutions of each.
        previous: The previous frame's bricks (None: not a stream).
    """
    if previous is None or not any(not p[3] for p in previous):
        return None
    out: list[np.ndarray | None] = []
    for k, r in enumerate(rows.tolist()):
        m = bt.models[r]
        hit = _previous_match(m, t2[k, 0], previous)
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
