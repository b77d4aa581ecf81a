"""The dot detector's batch poses: both planar solutions of every brick, solved again when its
dots change, and the planar ambiguity's plausibility test.

IPPE on the normalised points for all bricks of a layout at once (compiled or numpy, chosen
inside :mod:`drovisio.pose.batch`); SQPnP and its mirrored pose where three of four dots are
in a line; Levenberg–Marquardt for both solutions of bricks whose dots changed. Solution 0
of each brick is the one that reprojects best, or the one gravity speaks for.
"""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.detect.dots.batch import Context, DotBatch
from drovisio.pose import alternative_plausible, decide_flips
from drovisio.pose.batch import ippe_batch, mirror_pose, project_normalized, refine_poses

__all__ = ["alt_plausible", "chi2", "initial_poses", "prefer_level", "residuals_px",
           "resolve"]

_BITS = 1 << np.arange(16)
_EYE3 = np.eye(3)


def initial_poses(ctx: Context, bt: DotBatch, rows: list[int]) -> None:
    """Both planar solutions of the given bricks (IPPE on the normalised points: compiled,
    or OpenCV's; SQPnP and its mirrored pose, refined, where three of four dots are in a
    line). Solution 0 reprojects best."""
    bits = (bt.used * _BITS[:bt.blob.shape[1]]).sum(axis=1).tolist()
    special: list[int] = []
    warm: list[int] = []
    fit: list[int] = []
    for r in rows:
        if bt.models[r].degeneracy(bits[r]) <= 0.02:   # no homography from these dots
            (warm if np.isfinite(bt.cost[r, 0]) else special).append(r)
        else:
            fit.append(r)
    if fit:
        special += _ippe(bt, fit)
    if special:
        _special_poses(bt, np.array(special))
    if warm:
        _refine_both(bt, np.array(warm))
    prefer_level(ctx, bt, rows, bt.gravity)


def _ippe(bt: DotBatch, rows: list[int]) -> list[int]:
    """Both planar solutions of the given bricks, all bricks of a layout at once; returns
    the bricks it failed on."""
    groups: dict[int, list[int]] = {}
    for r in rows:
        groups.setdefault(id(bt.models[r]), []).append(r)
    failed: list[int] = []
    for g in groups.values():
        m = bt.models[g[0]]
        ga = np.asarray(g, np.int64)
        Pm = np.zeros((ga.size, bt.blob.shape[1], 2))
        Pm[:, :m.n] = m.P
        R, t, cost, ok = ippe_batch(Pm, bt.q[ga], bt.w[ga], m.plane_from_brick)
        bt.R[ga[ok]] = R[ok]
        bt.t[ga[ok]] = t[ok]
        bt.cost[ga[ok]] = cost[ok]
        failed.extend(ga[~ok].tolist())
    return failed


def resolve(ctx: Context, bt: DotBatch, rows: list[int] | np.ndarray) -> None:
    """Solve again bricks whose dots changed: both solutions refined from where they are
    (one batch for all bricks), then the gravity preference."""
    rows = np.asarray(rows, np.int64)
    if rows.size:
        _refine_both(bt, rows, iterations=3)
        prefer_level(ctx, bt, rows, bt.gravity)


def _refine_both(bt: DotBatch, rows: np.ndarray, iterations: int = 4) -> None:
    """Refine both solutions of bricks that already have poses (their dots changed)."""
    _refine_pair(bt, rows, bt.R[rows, 0], bt.R[rows, 1], bt.t[rows, 0], bt.t[rows, 1],
                 iterations)


def _refine_pair(bt: DotBatch, rows: np.ndarray, R0: np.ndarray, R1: np.ndarray,
                 t0: np.ndarray, t1: np.ndarray, iterations: int) -> None:
    """Refine two starting poses of each brick (one batch), store them best first."""
    B = rows.size
    X, w, q = bt.X[rows], bt.w[rows], bt.q[rows]
    Rr, tr, cost = refine_poses(np.concatenate([X, X]), np.concatenate([q, q]),
                                np.concatenate([w, w]), np.concatenate([R0, R1]),
                                np.concatenate([t0, t1]), iterations=iterations)
    bt.R[rows, 0], bt.R[rows, 1] = Rr[:B], Rr[B:]
    bt.t[rows, 0], bt.t[rows, 1] = tr[:B], tr[B:]
    bt.cost[rows, 0], bt.cost[rows, 1] = cost[:B], cost[B:]
    _swap(bt, rows[bt.cost[rows, 1] < bt.cost[rows, 0]])


def _swap(bt: DotBatch, rows: np.ndarray) -> None:
    """Make the second solution of the given bricks the working one."""
    if rows.size:
        bt.R[rows] = bt.R[rows][:, ::-1]
        bt.t[rows] = bt.t[rows][:, ::-1]
        bt.cost[rows] = bt.cost[rows][:, ::-1]


def _special_poses(bt: DotBatch, rows: np.ndarray) -> None:
    """Poses where no homography can be fitted (three of four dots in a line): SQPnP, the
    mirrored pose, both refined by Levenberg–Marquardt."""
    B = rows.size
    R0 = np.tile(np.eye(3), (B, 1, 1))
    t0 = np.tile(np.array([0.0, 0.0, 1.0]), (B, 1))
    Rpb = np.zeros((B, 3, 3))
    tpb = np.zeros((B, 3))
    for k, r in enumerate(rows.tolist()):
        T = bt.models[r].plane_from_brick
        Rpb[k], tpb[k] = T[:3, :3], T[:3, 3]
        m = bt.blob[r] >= 0
        try:
            ok, rv, tv = cv2.solvePnP(bt.X[r][m].reshape(-1, 1, 3),
                                      bt.q[r][m].reshape(-1, 1, 2), _EYE3, None,
                                      flags=cv2.SOLVEPNP_SQPNP)
        except cv2.error:
            ok = False
        if ok:
            R0[k] = cv2.Rodrigues(rv)[0]
            t0[k] = tv.ravel()
    X, w = bt.X[rows], bt.w[rows]
    Pl = X @ Rpb.transpose(0, 2, 1) + tpb[:, None, :]
    Rcp = R0 @ Rpb.transpose(0, 2, 1)
    tcp = t0 - (Rcp @ tpb[:, :, None])[:, :, 0]
    cen = (Pl * w[..., None]).sum(axis=1) / np.maximum(w.sum(axis=1), 1)[:, None]
    cen[:, 2] = 0.0
    Rm, tm = mirror_pose(Rcp, tcp, cen)
    R1 = Rm @ Rpb
    t1 = (Rm @ tpb[:, :, None])[:, :, 0] + tm
    _refine_pair(bt, rows, R0, R1, t0, t1, iterations=8)


def residuals_px(ctx: Context, bt: DotBatch) -> np.ndarray:
    """(B, N) distance of each dot from where the working solution puts it (≈ pixels)."""
    _, proj = project_normalized(bt.X, bt.R[:, 0], bt.t[:, 0])
    d = bt.q - proj
    return np.where(bt.used, np.sqrt((d * d).sum(axis=2)) * ctx.f, 0.0)


def chi2(ctx: Context, bt: DotBatch, rows: np.ndarray | list[int]
         ) -> tuple[np.ndarray, np.ndarray]:
    """χ² (n, 2) of both solutions of the given bricks at ``centroid_sigma_px``, and the
    degrees of freedom (n,) of their fits."""
    rows = np.asarray(rows)
    n = bt.used[rows].sum(axis=1)
    c2 = bt.cost[rows] * (ctx.f / ctx.config.centroid_sigma_px) ** 2
    return c2, np.maximum(2 * n - 6, 1)


def alt_plausible(ctx: Context, bt: DotBatch, rows: np.ndarray) -> np.ndarray:
    """Whether the second planar solution of the given bricks is plausible (the rule's
    test, on the current costs)."""
    c2, dof = chi2(ctx, bt, rows)
    return alternative_plausible(c2, dof, ctx.config.ambiguity)


def prefer_level(ctx: Context, bt: DotBatch, rows: np.ndarray | list[int],
                 gravity: np.ndarray | None) -> None:
    """With gravity: where the second solution is plausible and gravity speaks for it
    (bricks lie roughly flat), make it the working solution."""
    if gravity is None or not len(rows):
        return
    rows = np.asarray(rows)
    c2, dof = chi2(ctx, bt, rows)
    plaus = alternative_plausible(c2, dof, ctx.config.ambiguity)
    if not plaus.any():
        return
    rows, c2, dof = rows[plaus], c2[plaus], dof[plaus]
    pick, _ = decide_flips(bt.R[rows], c2, dof, gravity=gravity,
                           rule=ctx.config.ambiguity, use_fit=False)
    _swap(bt, rows[pick == 1])
