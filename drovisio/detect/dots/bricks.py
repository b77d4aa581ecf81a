"""The dot detector's output: one :class:`~drovisio.detect.result.BrickPose` per accepted
brick, with its unbiased dot centres in pixels, its dots' labels and its pose covariance.

The covariance takes the dot centres' standard deviation from the brick's own reprojection
residuals (at least ``covariance_floor_px``) and the normal equations of the last
Gauss–Newton step (:func:`drovisio.pose.batch.pose_covariance_from_normal`): 6×6, rotation
vector then translation, camera frame.
"""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.detect.dots.ambiguity import Decision
from drovisio.detect.dots.batch import Context, DotBatch
from drovisio.detect.result import BrickPose
from drovisio.pose import HALF_TURN, canonical_half_turn
from drovisio.pose.batch import pose_covariance_from_normal, rotation_vectors

__all__ = ["brick_poses"]


def brick_poses(ctx: Context, bt: DotBatch, rmse: np.ndarray, d: Decision
                ) -> list[BrickPose]:
    """The bricks of a decision.

    Args:
        rmse: (B, 2) RMS reprojection error of both solutions of every brick, pixels.
        d: The accepted bricks and their reported solutions.
    """
    rows = d.rows
    B = rows.size
    ar = np.arange(B)
    rm = rmse[rows][ar, d.choose]
    qsel = bt.q[rows] - bt.offset[rows][ar, d.choose]
    # unbiased centres in pixels
    img_pts = ctx.camera.project_fast(np.concatenate([qsel, np.ones(qsel.shape[:2] + (1,))],
                                                     axis=2))
    rvecs, cov = _covariance(ctx, bt, d, rm)
    N = bt.blob.shape[1]
    used = bt.used[rows]
    key = np.where(used, _labels(bt, d), N + 1)
    order = np.argsort(key, axis=1)                          # (B, N) dots by label
    counts = used.sum(axis=1).tolist()
    lab_sorted = np.take_along_axis(key, order, axis=1).tolist()
    pts_sorted = img_pts[ar[:, None], order]
    names = [bt.single.name] * B if bt.single is not None else \
        [bt.models[r].name for r in rows.tolist()]
    out = []
    amb, syml, rml = d.ambiguous.tolist(), d.symmetric.tolist(), rm.tolist()
    for k in range(B):
        nk = counts[k]
        out.append(BrickPose(
            layout=names[k], instance=None, method="dots", rvec=rvecs[k], tvec=d.t[k],
            reprojection_rmse_px=rml[k], markers=lab_sorted[k][:nk],
            ambiguous=amb[k], alternatives=_alternative(d, k) if amb[k] else [],
            symmetric=syml[k], covariance=None if cov is None else cov[k],
            image_points=pts_sorted[k, :nk]))
    return out


def _covariance(ctx: Context, bt: DotBatch, d: Decision, rm: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray | None]:
    """Rotation vectors (n, 3) of the reported poses and their covariances (n, 6, 6), or
    None when the settings ask for none."""
    cfg = ctx.config
    rows = d.rows
    if not cfg.covariance:
        return rotation_vectors(d.R), None
    ar = np.arange(rows.size)
    n = bt.used[rows].sum(axis=1)
    sig = np.maximum(cfg.covariance_floor_px, rm * np.sqrt(2 * n / np.maximum(
        2 * n - 6, 1))) / ctx.f
    A = bt.normal_eq[rows][ar, d.choose]
    rvecs = rotation_vectors(d.R)
    return rvecs, pose_covariance_from_normal(A, d.R, d.t, rvecs, sig)


def _labels(bt: DotBatch, d: Decision) -> np.ndarray:
    """(n, N) label of each dot slot in the reported (possibly half-turned) frame."""
    rows, flip = d.rows, d.flip
    B, N = rows.size, bt.blob.shape[1]
    lab = np.broadcast_to(np.arange(N), (B, N))
    if flip.any() and bt.single is not None:
        perm = bt.single.sym_perm
        assert perm is not None, "only a symmetric layout's pose is half-turned"
        lab = np.where(flip[:, None], perm, lab)
    elif flip.any():
        models = [bt.models[r] for r in rows.tolist()]
        if N == max(m.n for m in models):
            perm = np.stack([m.sym_perm if m.sym_perm is not None else np.arange(m.n)
                             for m in models])
            lab = np.where(flip[:, None], perm, lab)
    return lab


def _alternative(d: Decision, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The other planar solution of an ambiguous brick, as (rvec, tvec), in the same
    canonical half-turn rule."""
    other = 1 - int(d.choose[k])
    Ra = d.R2[k, other]
    if d.symmetric[k] and canonical_half_turn(Ra):
        Ra = Ra * HALF_TURN
    return [(cv2.Rodrigues(Ra)[0].ravel(), d.t2[k, other].copy())]
