"""Stage 7, the output: the frame's solved bricks as :class:`BrickPose` records.

Bricks come out sorted by (layout name, instance, copy). A decided pose of a brick (not a
duplicated code's copy) is remembered in the stream's pose history for the next frame's flip.
"""

from __future__ import annotations

import numpy as np

from drovisio.detect.aruco.codes import BrickKey, CodeDetection
from drovisio.detect.aruco.pose import Solved
from drovisio.detect.result import BrickPose
from drovisio.pose import PoseHistory

__all__ = ["brick_poses"]


def _image_points(group: list[CodeDetection]) -> np.ndarray:
    """(4G, 2) refined corners, px, of a brick's G codes."""
    px = [c.refined.corners_px for c in group if c.refined is not None]
    return px[0].copy() if len(group) == 1 else np.concatenate(px)


def brick_poses(results: dict[BrickKey, Solved], history: PoseHistory | None
                ) -> list[BrickPose]:
    """The bricks of a frame, sorted by key; decided poses update ``history``.

    Args:
        results: Brick key -> (pose, codes).
        history: The stream's pose history, or None outside a stream.
    """
    out: list[BrickPose] = []
    for key in sorted(results):
        res, group = results[key]
        lay = group[0].layout
        duplicate = key[2] > 0
        if history is not None and not res.ambiguous and not duplicate:
            history.update(key[:2], res.rvec, res.tvec)
        out.append(BrickPose(
            layout=lay.name, instance=int(key[1]), method="aruco",
            rvec=np.asarray(res.rvec, np.float64), tvec=np.asarray(res.tvec, np.float64),
            reprojection_rmse_px=float(res.rmse_px),
            markers=sorted(c.marker_id for c in group), ambiguous=bool(res.ambiguous),
            alternatives=[(a.rvec, a.tvec) for a in res.alternatives],
            symmetric=False, covariance=res.covariance, image_points=_image_points(group),
            duplicate=duplicate))
    return out
