"""Which dots of a posed brick to trust: dots hidden in part, wrong blobs, missing dots.

* A dot hidden in part (by the brick's own relief, a drick's pyramids, or by something in
  front: a blob smaller than the pose predicts) has an off centre: it is dropped, or the brick
  is when too few dots would remain.
* A dot far from where the pose puts it is a wrong blob: the worst is dropped (twice at most).
* A dot a partial match missed is looked for where the pose puts it (a free blob of its
  colour), and removed again if it does not fit.

Every change solves the brick again (:func:`.poses.resolve`). ``taken`` (n_blobs,) marks
the blobs that belong to a brick's dot (or may not be used).
"""

from __future__ import annotations

import numpy as np

from drovisio.detect.dots.batch import Context, DotBatch, DotViews, set_centers
from drovisio.detect.dots.blobs import Blobs, refine_centers
from drovisio.detect.dots.model import occluded_dots
from drovisio.detect.dots.poses import alt_plausible, residuals_px, resolve

__all__ = ["complete", "drop_hidden", "drop_wrong", "self_occluded", "shape_outliers"]


def drop_hidden(ctx: Context, bt: DotBatch, cov_n: np.ndarray, views: DotViews,
                taken: np.ndarray, alive: np.ndarray) -> None:
    """Drop the dots hidden in part (sets ``bt.hidden``); a brick left with too few dots is
    no longer ``alive`` unless its other planar solution is plausible and sees no dot cut.

    Args:
        cov_n: (n_blobs, 2, 2) second-moment matrices of the blobs, normalised.
    """
    cfg = ctx.config
    clear = self_occluded(bt)
    bt.hidden = clear < 1.0
    short = shape_outliers(ctx, bt, cov_n, views)
    u = bt.used
    bad = (bt.hidden | short) & u
    if not bad.any():
        return
    keep_ok = (u.sum(axis=1) - bad.sum(axis=1)) >= cfg.min_dots
    cut = ((bt.hidden & u & (clear < 0.95)) | (short & u)).any(axis=1) & ~keep_ok
    if cut.any():
        # too few dots to drop the cut one: its pose would be off; unless the other
        # planar solution is plausible and sees no dot cut (the cut came from a
        # mirrored pose)
        rows = np.flatnonzero(cut)
        alt = self_occluded(bt, sol=1, rows=rows)
        plaus = alt_plausible(ctx, bt, rows)
        cut[rows] &= ~(plaus & ~(u[rows] & (alt < 0.95)).any(axis=1))
    alive &= ~cut
    drop = bad & keep_ok[:, None]
    if drop.any():
        taken[bt.blob[drop]] = False
        bt.blob[drop] = -1
        resolve(ctx, bt, np.flatnonzero(drop.any(axis=1)).tolist())


def drop_wrong(ctx: Context, bt: DotBatch, taken: np.ndarray, alive: np.ndarray) -> None:
    """A dot far from where the pose puts it (a wrong blob): drop the worst of each brick
    that keeps enough dots, twice at most."""
    cfg = ctx.config
    B = bt.blob.shape[0]
    for _ in range(2):
        res = residuals_px(ctx, bt)
        worst = res.argmax(axis=1)
        wv = res[np.arange(B), worst]
        drop = alive & (wv > cfg.max_dot_residual_px) & (bt.used.sum(axis=1) > cfg.min_dots)
        if not drop.any():
            break
        rows = np.flatnonzero(drop)
        taken[bt.blob[rows, worst[rows]]] = False
        bt.blob[rows, worst[rows]] = -1
        resolve(ctx, bt, rows.tolist())


def complete(ctx: Context, bt: DotBatch, blobs: Blobs, centers: np.ndarray,
             refined: np.ndarray, taken: np.ndarray, img: np.ndarray) -> None:
    """Add dots a partial match missed: a free blob of the right colour where the pose
    puts a missing dot.

    Args:
        centers: (n_blobs, 2) blob centres, pixels (sub-pixel where ``refined``; completed
            dots are refined here).
        refined: (n_blobs,) which centres are sub-pixel ones.
        img: The BGR frame (for the sub-pixel centres).
    """
    found = _missing_dots(ctx, bt, blobs, centers, taken)
    if found is None:
        return
    bi, di, free, best, ok = found
    changed, new = set(), []
    for k in np.flatnonzero(ok).tolist():
        blob = int(free[best[k]])
        if taken[blob]:
            continue
        taken[blob] = True
        bt.blob[bi[k], di[k]] = blob
        changed.add(int(bi[k]))
        new.append(blob)
    if not changed:
        return
    new_a = np.array(new)
    need = new_a[~refined[new_a]]
    if need.size:
        centers[need] = refine_centers(img, blobs, need)[0]
        refined[need] = True
    rows = np.array(sorted(changed))
    set_centers(ctx.camera, bt, centers, rows)
    resolve(ctx, bt, rows.tolist())
    # a completed dot that does not fit is removed again
    res = residuals_px(ctx, bt)
    bad = (res > ctx.config.max_dot_residual_px) & np.isin(bt.blob, new_a)
    if bad.any():
        taken[bt.blob[bad]] = False
        bt.blob[bad] = -1
        resolve(ctx, bt, np.flatnonzero(bad.any(axis=1)))


def _missing_dots(ctx: Context, bt: DotBatch, blobs: Blobs, centers: np.ndarray,
                  taken: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """The missing dots in front of the camera (brick ``bi``, dot ``di``), the free blobs,
    the nearest free blob of the right colour to each (index into ``free``) and whether it
    is near enough; None when there is nothing to look for."""
    missing = ~bt.used & ~bt.hidden & (bt.colors >= 0)
    if not missing.any():
        return None
    free = np.flatnonzero(~taken)
    if free.size == 0:
        return None
    bi, di = np.nonzero(missing)
    Y = (bt.R[bi, 0] @ bt.X[bi, di][:, :, None])[:, :, 0] + bt.t[bi, 0]
    front = Y[:, 2] > 1e-6
    bi, di, Y = bi[front], di[front], Y[front]
    if bi.size == 0:
        return None
    pred = ctx.camera.project_fast(Y)
    size_px = ctx.f * bt.radii[bi, di] * 2 / Y[:, 2]
    tol2 = np.maximum(1.5, 0.25 * size_px) ** 2
    dd = pred[:, None, :] - centers[free][None, :, :]
    d2 = (dd * dd).sum(axis=2)
    want = bt.colors[bi, di]
    d2[blobs.color[free][None, :] != want[:, None]] = np.inf
    best = d2.argmin(axis=1)
    ok = d2[np.arange(bi.size), best] <= tol2
    if not ok.any():
        return None
    return bi, di, free, best, ok


def shape_outliers(ctx: Context, bt: DotBatch, cov_n: np.ndarray, views: DotViews
                   ) -> np.ndarray:
    """(B, N) dots whose blob is clearly smaller (or larger) than the brick's other dots,
    relative to the size the pose predicts (a dot cut by an edge in front of it)."""
    u = bt.used
    Cm = cov_n[np.maximum(bt.blob, 0)]
    mo = views.moments
    c00, c01, c11 = mo.c00, mo.c01, mo.c11
    det_p = np.maximum(c00 * c11 - c01 * c01, 1e-30)
    det_m = np.maximum(Cm[..., 0, 0] * Cm[..., 1, 1] - Cm[..., 0, 1] ** 2, 0)
    rho = np.sqrt(np.sqrt(det_m / det_p))                 # linear size ratio
    srt = np.sort(np.where(u, rho, np.inf), axis=1)
    n = u.sum(axis=1)
    med = srt[np.arange(rho.shape[0]), np.maximum(n - 1, 0) // 2]
    # predicted minor semi-axis in pixels: small dots are measured ±1 px
    tr = c00 + c11
    lmin = tr / 2 - np.sqrt(np.maximum(tr * tr / 4 - det_p, 0))
    b_px = 2 * np.sqrt(np.maximum(lmin, 0)) * ctx.f
    tol = np.maximum(0.2, 1.2 / np.maximum(b_px, 0.5))
    rel = rho / med[:, None]
    return u & ((rel < 1 - tol) | (rel > 1 / (1 - tol)))


def self_occluded(bt: DotBatch, sol: int = 0, rows: np.ndarray | None = None) -> np.ndarray:
    """(B, N) (or (len(rows), N)) clearance of the dots from the shadows of the brick's
    own mesh under solution ``sol``, in dot radii (< 1: partly hidden)."""
    if bt.single is not None:
        m = bt.single
        if not m.occluders.shape[0]:
            n = bt.blob.shape[0] if rows is None else len(rows)
            return np.full((n, bt.blob.shape[1]), np.inf)
        if rows is None:
            return occluded_dots(m, bt.R[:, sol], bt.t[:, sol], clearance=True)
        rr = np.asarray(rows, np.int64)
        return occluded_dots(m, bt.R[rr, sol], bt.t[rr, sol], clearance=True)
    rl = list(range(bt.blob.shape[0])) if rows is None else list(rows)
    out = np.full((len(rl), bt.blob.shape[1]), np.inf)
    groups: dict[int, list[int]] = {}
    for k, r in enumerate(rl):
        m = bt.models[r]
        if m.occluders.shape[0]:
            groups.setdefault(id(m), []).append(k)
    for ks in groups.values():
        m = bt.models[rl[ks[0]]]
        kk = np.array(ks)
        rr = np.array(rl)[kk]
        out[kk, :m.n] = occluded_dots(m, bt.R[rr, sol], bt.t[rr, sol], clearance=True)
    return out
