"""The working state of the dot detector's pose stages: the bricks of one frame as one batch.

B bricks of up to N dots each (a padded dot has blob ``-1`` and colour ``-1``). Poses are
``camera_from_brick`` (X_cam = R · X_brick + t); each brick carries both solutions of the
planar ambiguity, the working one first. Image points are normalised (x/z, y/z of the OpenCV
camera frame) unless named ``px`` (distorted pixels).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio.camera import Camera
from drovisio.detect.dots.config import DotsConfig
from drovisio.detect.dots.match import Candidate
from drovisio.detect.dots.model import DotModel

__all__ = ["Context", "DotBatch", "DotViews", "EllipseMoments", "make_batch", "set_centers",
           "dot_views"]


def _unset() -> np.ndarray:
    return np.zeros(0)


@dataclass(frozen=True)
class Context:
    """What every pose stage needs besides the batch."""

    config: DotsConfig
    camera: Camera
    f: float
    """Focal length in pixels (geometric mean of fx and fy): normalised units → pixels."""


@dataclass
class DotBatch:
    """Working arrays of the bricks of one frame (B bricks, up to N dots each); the stages
    fill the later fields in order and change them in place."""

    models: list[DotModel]
    blob: np.ndarray
    """(B, N) blob index per dot, -1 absent."""
    X: np.ndarray
    """(B, N, 3) dot centres, brick frame, metres."""
    U: np.ndarray
    """(B, N, 3) first in-plane axis of each dot, brick frame."""
    V: np.ndarray
    """(B, N, 3) second in-plane axis of each dot, brick frame."""
    normals: np.ndarray
    """(B, N, 3) dot normals, brick frame."""
    radii: np.ndarray
    """(B, N) dot radii, metres."""
    colors: np.ndarray
    """(B, N) colour index of each dot, -1 for padding."""
    R: np.ndarray
    """(B, 2, 3, 3) the two planar solutions, best first."""
    t: np.ndarray
    """(B, 2, 3) their translations, metres."""
    cost: np.ndarray
    """(B, 2) sums of squared residuals (normalised units²); inf before a pose."""
    single: DotModel | None = None
    """The model of every brick, when they share one."""
    px: np.ndarray = field(default_factory=_unset)
    """(B, N, 2) measured (ellipse) centres, pixels (set by :func:`set_centers`)."""
    q: np.ndarray = field(default_factory=_unset)
    """(B, N, 2) the same, normalised."""
    hidden: np.ndarray = field(default_factory=_unset)
    """(B, N) dots hidden by the brick's own relief (set by the occlusion stage)."""
    offset: np.ndarray = field(default_factory=_unset)
    """(B, 2, N, 2) ellipse-centre offsets, normalised (set by the perspective step)."""
    normal_eq: np.ndarray = field(default_factory=_unset)
    """(B, 2, 6, 6) JᵀJ of each solution (the covariance; set by the perspective step)."""
    gravity: np.ndarray | None = None
    """(3,) unit gravity in the camera frame, if known."""

    @property
    def used(self) -> np.ndarray:
        """(B, N) dots that have a blob."""
        return self.blob >= 0

    @property
    def w(self) -> np.ndarray:
        """(B, N) weights of the dots: 1 used, 0 absent."""
        return (self.blob >= 0).astype(np.float64)


@dataclass(frozen=True)
class EllipseMoments:
    """Second-moment matrices [[c00, c01], [c01, c11]] of the dots' projected ellipses,
    normalised units², each (B, N)."""

    c00: np.ndarray
    c01: np.ndarray
    c11: np.ndarray


@dataclass(frozen=True)
class DotViews:
    """The dots under the working solution."""

    Y: np.ndarray
    """(B, N, 3) dot centres, camera frame, metres."""
    cos_view: np.ndarray
    """(B, N) cosine between each dot's normal and its line of sight (1: seen head-on)."""
    moments: EllipseMoments


def make_batch(cands: list[Candidate]) -> DotBatch:
    """The batch of the matched candidates (no poses yet: identity, cost inf)."""
    B = len(cands)
    N = max(c.model.n for c in cands)
    R = np.tile(np.eye(3), (B, 2, 1, 1))
    t = np.zeros((B, 2, 3))
    cost = np.full((B, 2), np.inf)
    if all(c.model is cands[0].model for c in cands):
        m = cands[0].model
        X, U, V, nrm, rad = m.batch_arrays(B)
        return DotBatch(models=[m] * B, blob=np.stack([c.assign for c in cands]),
                        X=X.copy(), U=U, V=V, normals=nrm, radii=rad, single=m,
                        colors=np.broadcast_to(m.colors, (B, N)), R=R, t=t, cost=cost)
    blob = np.full((B, N), -1, np.int64)
    X = np.zeros((B, N, 3))
    U = np.tile(np.array([1.0, 0, 0]), (B, N, 1))
    V = np.tile(np.array([0, 1.0, 0]), (B, N, 1))
    normals = np.tile(np.array([0, 0, 1.0]), (B, N, 1))
    radii = np.full((B, N), 0.01)
    colors = np.full((B, N), -1, np.int64)
    for k, c in enumerate(cands):
        m = c.model
        n = m.n
        blob[k, :n] = c.assign
        colors[k, :n] = m.colors
        X[k, :n], U[k, :n], V[k, :n] = m.X, m.axes_u, m.axes_v
        normals[k, :n] = m.normals
        radii[k, :n] = m.radii
    return DotBatch(models=[c.model for c in cands], blob=blob, X=X, U=U, V=V,
                    normals=normals, radii=radii, colors=colors, R=R, t=t, cost=cost)


def set_centers(camera: Camera, bt: DotBatch, centers: np.ndarray,
                rows: np.ndarray | None = None) -> None:
    """Put the blobs' centres (n_blobs, 2) pixels on the dots of all bricks (or of ``rows``),
    in pixels and normalised."""
    m = bt.used
    if rows is None:
        bt.px = np.where(m[..., None], centers[np.maximum(bt.blob, 0)], 0.0)
        bt.q = np.zeros_like(bt.px)
        bt.q[m] = camera.normalize_fast(bt.px[m])
    else:
        mr = m[rows]
        px = np.where(mr[..., None], centers[np.maximum(bt.blob[rows], 0)], 0.0)
        q = np.zeros_like(px)
        q[mr] = camera.normalize_fast(px[mr])
        bt.px[rows] = px
        bt.q[rows] = q


def dot_views(bt: DotBatch) -> DotViews:
    """The dots under the working solution: camera-frame centres, view cosines, and the
    second-moment matrices of their ellipses (normalised), (r²/4)·A·Aᵀ with A the local
    projection of the dot's plane."""
    R, t = bt.R[:, 0], bt.t[:, 0]
    Rt = R.transpose(0, 2, 1)
    Y = bt.X @ Rt + t[:, None, :]
    uc, vc, nc = bt.U @ Rt, bt.V @ Rt, bt.normals @ Rt
    z = np.maximum(Y[..., 2], 1e-9)
    iz = 1.0 / z
    x, y = Y[..., 0] * iz, Y[..., 1] * iz
    a00 = (uc[..., 0] - x * uc[..., 2]) * iz
    a10 = (uc[..., 1] - y * uc[..., 2]) * iz
    a01 = (vc[..., 0] - x * vc[..., 2]) * iz
    a11 = (vc[..., 1] - y * vc[..., 2]) * iz
    k = bt.radii * bt.radii / 4
    c00 = k * (a00 * a00 + a01 * a01)
    c01 = k * (a00 * a10 + a01 * a11)
    c11 = k * (a10 * a10 + a11 * a11)
    dist = np.sqrt((Y * Y).sum(axis=2))
    return DotViews(Y=Y, cos_view=-(nc * Y).sum(axis=2) / np.maximum(dist, 1e-12),
                    moments=EllipseMoments(c00=c00, c01=c01, c11=c11))
