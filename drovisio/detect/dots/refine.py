"""The dot detector's last pose step and its checks.

The measured centres are ellipse centres, not projected circle centres: under perspective
they differ. For both solutions of all bricks (one batch of 2B problems: [solution 0 |
solution 1]) the offset the pose predicts is subtracted and one Gauss–Newton step taken
(:func:`drovisio.pose.batch.gn_step`), which also turns IPPE's pose into the least-squares
one. Then the bricks are checked: enough dots, a small reprojection error, every dot near
where the pose puts it, in front of the camera, facing it, of the size the pose predicts.
"""

from __future__ import annotations

import math

import numpy as np

from drovisio.detect.dots.batch import Context, DotBatch, DotViews
from drovisio.detect.dots.blobs import Blobs
from drovisio.pose.batch import conic_center_offsets, gn_step

__all__ = ["accepted", "perspective_step"]


def perspective_step(bt: DotBatch) -> np.ndarray:
    """Correct the ellipse-centre offsets and take one Gauss–Newton step for both solutions
    of every brick (sets ``R``, ``t``, ``cost``, ``offset``, ``normal_eq``; the working
    solution first).

    Returns:
        (B, 2, N) residual of each dot under each solution, normalised units.
    """
    B = bt.blob.shape[0]
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
    return resid


def accepted(ctx: Context, bt: DotBatch, blobs: Blobs, views: DotViews, resid: np.ndarray,
             alive: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bricks that pass every check, and the RMS reprojection error (B, 2) of both
    solutions of every brick, pixels.

    Args:
        views: The dots under the working solution before :func:`perspective_step` (the
            size and facing checks need no better).
        resid: What :func:`perspective_step` returned.
        alive: (B,) bricks still standing after the occlusion stage.
    """
    cfg = ctx.config
    count = bt.used.sum(axis=1)
    rmse = np.sqrt(bt.cost / np.maximum(count, 1)[:, None] / 2) * ctx.f  # (B, 2)
    res = resid[:, 0] * ctx.f
    alive &= (count >= cfg.min_dots) & (rmse[:, 0] <= cfg.max_rmse_px)
    alive &= res.max(axis=1) <= cfg.max_dot_residual_px
    alive &= _plausible(ctx, bt, blobs, views)
    return np.flatnonzero(alive), rmse


def _plausible(ctx: Context, bt: DotBatch, blobs: Blobs, views: DotViews) -> np.ndarray:
    """Dots in front, facing the camera, of the size the pose predicts."""
    cfg = ctx.config
    u = bt.used
    Y = views.Y
    ok_front = np.all(~u | ((Y[..., 2] > 0.02) & (views.cos_view >= _COS_MAX_VIEW[
        cfg.max_view_angle_deg])), axis=1)
    a_pred = ctx.f * bt.radii / np.maximum(Y[..., 2], 1e-6)   # major semi-axis, approx.
    ratio = np.where(u, blobs.a[np.maximum(bt.blob, 0)] / np.maximum(a_pred, 1e-9), 1.0)
    lo, hi = cfg.size_ratio
    slack = 1.0 / np.maximum(a_pred, 0.5)                   # small blobs: ±1 px
    return ok_front & np.all((ratio >= lo - slack) & (ratio <= hi + slack), axis=1)


class _CosTable(dict):
    """cos of an angle in degrees, computed once per angle."""

    def __missing__(self, deg: float) -> float:
        val = self[deg] = math.cos(math.radians(deg))
        return val


_COS_MAX_VIEW = _CosTable()
