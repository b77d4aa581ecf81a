"""Matching stage of the dot detector: which blobs are which dots of which brick.

The thesis tried every combination of n blobs (lines of equidistant dots, then pairs of
lines): 60 blobs and n = 3 already make 34 220 triples per colour set. Here every hypothesis
starts from *two nearby blobs* and uses what a single blob already says:

* a dot is a circle of known diameter, so its blob's ellipse gives the local scale and
  foreshortening of the brick's plane (the image of a circle under a local affine map A is an
  ellipse with covariance (r²/4)·A·Aᵀ; A is known up to an in-plane turn);
* the pair (blob i → dot a, blob j → dot b) fixes that turn; the distance between the blobs,
  measured in the ellipse's metric, must equal the distance between the dots (the ratio test),
  and the colours must agree;
* the local affine map then predicts where every other dot of the layout should be; the
  hypothesis scores the dots found there (right colour, within a tolerance).

Seeds are each blob's few nearest neighbours, candidates each blob's k nearest blobs, so the
work grows with the number of blobs (linearly with bricks in view), and it is done for all
hypotheses at once with numpy. Any planar layout of four or more dots works (not only two
lines); the layout's symmetry (``rot180_z``) is used to skip hypotheses that only relabel
another one. :func:`assign_greedy` then gives blobs to the best hypotheses first; poses are
checked later (:mod:`drovisio.pose.batch`, :mod:`.dots`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drovisio import _numba
from drovisio.detect.dots import match_kernels as _k
from drovisio.layout import MarkerLayout
from drovisio.pose.batch import layout_degeneracy

__all__ = [
    "BlobGeometry",
    "DotModel",
    "Hypotheses",
    "LayoutNotSupported",
    "assign_greedy",
    "generate_hypotheses",
    "occluded_dots",
]


class LayoutNotSupported(ValueError):
    """A layout the dot detector cannot use (fewer than 4 dots, dots not coplanar...)."""


def _rot_z_pi(X: np.ndarray) -> np.ndarray:
    return X * np.array([-1.0, -1.0, 1.0])


def _plane_normal(X: np.ndarray, normals: np.ndarray, where: str) -> np.ndarray:
    """The unit normal (3,) of the plane of the dots (n, 3) with unit normals (n, 3), brick
    frame.

    Raises:
        LayoutNotSupported: the normals disagree (opposite, or > 5° apart), or a dot is more
            than 1 mm off the plane.
    """
    n = normals.mean(axis=0)
    if np.linalg.norm(n) < 1e-6:
        raise LayoutNotSupported(f"{where}: dot normals point in opposite directions; the "
                                 "dot detector needs all dots on one face")
    n /= np.linalg.norm(n)
    if np.min(normals @ n) < np.cos(np.radians(5)):
        raise LayoutNotSupported(f"{where}: dot normals differ by more than 5°; the dot "
                                 "detector needs all dots on one plane")
    off = (X - X.mean(axis=0)) @ n
    if np.max(np.abs(off)) > 1e-3:
        raise LayoutNotSupported(f"{where}: dots are up to {np.max(np.abs(off)) * 1e3:.1f} "
                                 "mm off a common plane; the dot detector needs coplanar "
                                 "dots")
    return n


def _half_turn_perm(layout: MarkerLayout, X: np.ndarray, names: list[str]
                    ) -> np.ndarray | None:
    """For a ``rot180_z`` layout whose dots (n, 3) map onto dots of the same colour under the
    half-turn: the dot each goes to (n,); else None."""
    if getattr(layout, "symmetry", "none") != "rot180_z":
        return None
    Xs = _rot_z_pi(X)
    d = np.linalg.norm(Xs[:, None, :] - X[None, :, :], axis=2)
    perm = np.argmin(d, axis=1)
    if (np.max(d[np.arange(len(X)), perm]) < 1e-6
            and np.array_equal(np.sort(perm), np.arange(len(X)))
            and all(names[i] == names[perm[i]] for i in range(len(X)))):
        return perm
    return None


def _seed_pairs(count: int, sym: np.ndarray | None) -> list[tuple[int, int]]:
    """Ordered pairs of distinct dots (a, b) that seed hypotheses; with a half-turn
    permutation ``sym``, one of each pair and its image."""
    pairs = []
    seen = set()
    for a in range(count):
        for b in range(count):
            if a == b:
                continue
            key = (a, b)
            if sym is not None:
                key = min((a, b), (int(sym[a]), int(sym[b])))
            if key in seen:
                continue
            seen.add(key)
            pairs.append((a, b))
    return pairs


@dataclass
class DotModel:
    """What the matcher and the pose stage need to know about one layout's dots.

    Attributes:
        layout: The layout.
        X: (N, 3) dot centres, brick frame, metres.
        normals: (N, 3) dot normals.
        radii: (N,) dot radii, metres.
        color_names: Colour name of each dot.
        colors: (N,) index of each dot's colour in the detector's colour list.
        P: (N, 2) dot centres in the dots' plane frame (metres).
        plane_from_brick: 4×4 transform of brick coordinates to plane coordinates (plane z=0).
        sym_perm: For ``rot180_z``: dot i ↦ sym_perm[i] under the half-turn; else None.
        pairs: (Np, 2) ordered dot pairs (a, b), a ≠ b, without pairs that only relabel
            another under the symmetry.
        min_spacing: Smallest distance between two dots, metres.
        max_extent: Largest distance between two dots, metres.
    """

    layout: MarkerLayout
    X: np.ndarray
    normals: np.ndarray
    radii: np.ndarray
    color_names: list[str]
    colors: np.ndarray
    P: np.ndarray
    plane_from_brick: np.ndarray
    sym_perm: np.ndarray | None
    pairs: np.ndarray
    min_spacing: float
    max_extent: float
    occluders: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """(T, 3, 3) triangles of the brick's mesh that rise above the dots' plane (the
    pyramids of a drick), brick frame: they can hide dots at oblique views."""
    occluders_plane: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """The same triangles in the plane frame (x, y, height above the dots' plane)."""
    axes_u: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    axes_v: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(N, 3) two unit vectors in each dot's plane (u × v = normal), brick frame."""
    n_colors: int = 0
    color_ok: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    """(n_colors,) colours this layout uses."""
    pair_color_match: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), bool))
    """(n_colors, n_colors, Np): pair p may start with blobs of colours (ci, cj)."""
    pair_vec: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pair_len: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pair_mid: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pair_ra_half: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pair_rb_half: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pair_ia: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pair_ib: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reach_per_semi_axis: float = 0.0
    """Neighbour search radius per unit of a blob's major semi-axis."""
    _degeneracy: dict = field(default_factory=dict, repr=False)
    _batch_cache: dict = field(default_factory=dict, repr=False)

    @property
    def n(self) -> int:
        return int(self.X.shape[0])

    @property
    def name(self) -> str:
        return self.layout.name

    @classmethod
    def from_layout(cls, layout: MarkerLayout, color_index: dict[str, int],
                    n_colors: int | None = None) -> DotModel:
        """Build the model.

        Args:
            layout: A layout with at least four coplanar dots.
            color_index: Colour name → index in the detector's colour list.
            n_colors: Length of the detector's colour list (default: from ``color_index``).

        Raises:
            LayoutNotSupported: fewer than 4 dots, or the dots are not on one plane, or their
                normals disagree with the plane.
        """
        X = np.asarray(layout.dot_centers_m(), np.float64).reshape(-1, 3)
        where = f"layout {layout.name!r}"
        if X.shape[0] < 4:
            raise LayoutNotSupported(f"{where}: the dot detector needs at least 4 dots, it has "
                                     f"{X.shape[0]}")
        normals = np.asarray(layout.dot_normals(), np.float64).reshape(-1, 3)
        normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        radii = np.asarray(layout.dot_diameters_m(), np.float64).ravel() / 2
        names = list(layout.dot_colors())
        n = _plane_normal(X, normals, where)
        O = X.mean(axis=0)
        hint = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
        u = hint - (hint @ n) * n
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        R_bp = np.stack([u, v, n], axis=1)          # brick_from_plane rotation
        O = O - (O @ n) * n + (X.mean(axis=0) @ n) * n
        plane_from_brick = np.eye(4)
        plane_from_brick[:3, :3] = R_bp.T
        plane_from_brick[:3, 3] = -R_bp.T @ O
        P = (X - O) @ R_bp[:, :2]
        missing = [c for c in set(names) if c not in color_index]
        if missing:
            raise LayoutNotSupported(f"{where}: colours {sorted(missing)} are not in the "
                                     "detector's palette")
        colors = np.array([color_index[c] for c in names], np.int64)
        sym = _half_turn_perm(layout, X, names)
        dist = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)
        pairs = _seed_pairs(len(X), sym)
        iu = np.triu_indices(len(X), 1)
        occ = _occluders(layout, X, n)
        occ_p = occ @ plane_from_brick[:3, :3].T + plane_from_brick[:3, 3]
        hint2 = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        au = np.cross(normals, hint2)
        au /= np.linalg.norm(au, axis=1, keepdims=True)
        av = np.cross(normals, au)
        pairs_a = np.array(pairs, np.int64)
        n_colors = max(max(color_index.values()) + 1, n_colors or 0)
        color_ok = np.zeros(n_colors, bool)
        color_ok[colors] = True
        pcm = np.zeros((n_colors, n_colors, len(pairs_a)), bool)
        pcm[colors[pairs_a[:, 0]], colors[pairs_a[:, 1]], np.arange(len(pairs_a))] = True
        pvec = P[pairs_a[:, 1]] - P[pairs_a[:, 0]]
        ra, rb = radii[pairs_a[:, 0]], radii[pairs_a[:, 1]]
        return cls(layout=layout, X=X, normals=normals, radii=radii, color_names=names,
                   colors=colors, P=P, plane_from_brick=plane_from_brick, sym_perm=sym,
                   pairs=np.array(pairs, np.int64), min_spacing=float(dist[iu].min()),
                   max_extent=float(dist[iu].max()), occluders=occ,
                   occluders_plane=occ_p, axes_u=au, axes_v=av, n_colors=n_colors,
                   color_ok=color_ok, pair_color_match=pcm, pair_vec=pvec,
                   pair_len=np.linalg.norm(pvec, axis=1),
                   pair_mid=0.5 * (P[pairs_a[:, 0]] + P[pairs_a[:, 1]]),
                   pair_ra_half=ra / 2, pair_rb_half=rb / 2, pair_ia=1.0 / ra, pair_ib=1.0 / rb,
                   reach_per_semi_axis=1.4 * float(dist[iu].max()) / float(radii.min()))

    def batch_arrays(self, B: int) -> tuple[np.ndarray, ...]:
        """X, axes_u, axes_v, normals, radii repeated for B bricks (read-only, cached)."""
        cache = self._batch_cache
        got = cache.get(B)
        if got is None:
            got = tuple(np.repeat(a[None], B, axis=0) for a in (
                self.X, self.axes_u, self.axes_v, self.normals, self.radii))
            for a in got:
                a.flags.writeable = False
            if len(cache) >= 8:
                cache.clear()
            cache[B] = got
        return got

    def degeneracy(self, dots) -> float:
        """:func:`~drovisio.pose.batch.layout_degeneracy` of a subset of dots (cached).

        Args:
            dots: Dot indices, or the subset as a bit mask (int: bit i = dot i).
        """
        key = dots if isinstance(dots, int) else int(np.sum(1 << np.asarray(dots, np.int64)))
        val = self._degeneracy.get(key)
        if val is None:
            sel = [i for i in range(self.n) if key >> i & 1]
            val = self._degeneracy[key] = layout_degeneracy(self.P[sel])
        return val


def _occluders(layout: MarkerLayout, X: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Triangles of the layout's mesh above the dots' plane (brick frame, metres)."""
    try:
        path = layout.mesh_path()
    except Exception:  # noqa: BLE001 - a layout without a usable mesh has no occluders
        path = None
    if path is None or not path.exists():
        return np.zeros((0, 3, 3))
    try:
        import trimesh  # heavy: loaded only for a layout with a mesh

        mesh: Any = trimesh.load(path, force="mesh")
        V = np.asarray(mesh.vertices, np.float64) * float(layout.scale_to_m)
        F = np.asarray(mesh.faces, np.int64)
    except Exception:  # noqa: BLE001 - unreadable mesh: no occlusion model
        return np.zeros((0, 3, 3))
    tris = V[F]
    height = (tris - X.mean(axis=0)) @ n
    return tris[height.max(axis=1) > 1e-3].copy()


def occluded_dots(model: DotModel, R: np.ndarray, t: np.ndarray,
                  clearance: bool = False) -> np.ndarray:
    """Which dots the brick's own mesh (e.g. a drick's pyramids) hides, fully or partly.

    Each occluding triangle is projected from the camera centre onto the dots' plane (its
    "shadow" as the camera sees it); a dot is hidden where its disc meets a shadow. This is
    exact for a pinhole camera (the disc lies in that plane).

    Args:
        model: The layout model (its ``occluders``).
        R, t: (B, 3, 3), (B, 3) ``camera_from_brick`` poses.

        clearance: Return the clearance instead: the distance from each dot's centre to the
            nearest shadow, in dot radii (0 when the centre is in a shadow; ≥ 1 = fully
            visible).

    Returns:
        (B, N) bool: True where some part of the dot is hidden (or the clearance, float).
    """
    B = R.shape[0]
    T = model.occluders.shape[0]
    if T == 0:
        return np.full((B, model.n), np.inf) if clearance else np.zeros((B, model.n), bool)
    Tpb = model.plane_from_brick
    C = -np.einsum("bji,bj->bi", R, t)                      # camera centre, brick frame
    Cp = C @ Tpb[:3, :3].T + Tpb[:3, 3]                      # ... plane frame (B, 3)
    if _numba.enabled():
        clear = _k.occlusion_clearance(model.occluders_plane, model.P, model.radii, Cp)
        return clear if clearance else clear < 1.0
    V = model.occluders_plane                                # (T, 3, 3): x, y, height
    h = np.maximum(V[..., 2], 0.0)[None]                     # (1, T, 3)
    ch = Cp[:, 2][:, None, None]                             # (B, 1, 1)
    k = ch / np.maximum(ch - h, 1e-9)                        # central projection factor
    S = Cp[:, None, None, :2] + (V[None, ..., :2] - Cp[:, None, None, :2]) * k[..., None]
    valid = np.all(h < ch, axis=2) & (Cp[:, 2] > 0)[:, None]  # (B, T)
    E = np.roll(S, -1, axis=2) - S                           # (B, T, 3, 2) edges
    W = model.P[None, :, None, None, :] - S[:, None]         # (B, N, T, 3, 2)
    Eb = E[:, None]
    cr = Eb[..., 0] * W[..., 1] - Eb[..., 1] * W[..., 0]     # (B, N, T, 3)
    inside = np.all(cr >= 0, axis=3) | np.all(cr <= 0, axis=3)
    ee = np.maximum((E * E).sum(axis=3), 1e-18)[:, None]     # (B, 1, T, 3)
    tt = np.clip((W * Eb).sum(axis=4) / ee, 0.0, 1.0)
    gap = W - tt[..., None] * Eb
    d2 = (gap * gap).sum(axis=4).min(axis=3)                 # (B, N, T)
    d2 = np.where(inside, 0.0, d2)
    d2 = np.where(valid[:, None, :], d2, np.inf).min(axis=2)          # (B, N)
    if clearance:
        return np.sqrt(d2) / model.radii[None, :]
    return d2 < (model.radii ** 2)[None, :]


@dataclass
class Hypotheses:
    """Scored hypotheses of one model (arrays, one row per hypothesis).

    Attributes:
        model: The layout model.
        assign: (H, N) blob index of each dot (-1: none found).
        score: (H,) higher is better (dots found, then closeness).
        scale: (H,) image size of the layout's smallest spacing (normalised units).
        affine: (H, 2, 2) local affine map plane → image of the hypothesis.
        origin: (H, 2) image point of the plane origin under that map.
    """

    model: DotModel
    assign: np.ndarray
    score: np.ndarray
    scale: np.ndarray
    affine: np.ndarray
    origin: np.ndarray

    @staticmethod
    def empty(model: DotModel) -> Hypotheses:
        return Hypotheses(model, np.zeros((0, model.n), np.int64), np.zeros(0), np.zeros(0),
                          np.zeros((0, 2, 2)), np.zeros((0, 2)))


def _sqrt_2x2(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Square roots and inverse square roots of SPD 2×2 matrices (n, 2, 2)."""
    c00, c01, c11 = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
    s = np.sqrt(np.maximum(c00 * c11 - c01 * c01, 1e-300))
    tt = np.sqrt(np.maximum(c00 + c11 + 2 * s, 1e-300))
    S = np.empty_like(C)
    S[:, 0, 0] = (c00 + s) / tt
    S[:, 1, 1] = (c11 + s) / tt
    S[:, 0, 1] = S[:, 1, 0] = c01 / tt
    # inverse: adj(S) / det(S), det(S) = sqrt(det C)
    Si = np.empty_like(C)
    Si[:, 0, 0] = S[:, 1, 1] / s
    Si[:, 1, 1] = S[:, 0, 0] / s
    Si[:, 0, 1] = Si[:, 1, 0] = -S[:, 0, 1] / s
    return S, Si


@dataclass
class BlobGeometry:
    """Per-frame blob data the matcher needs (shared by all layouts).

    Attributes:
        q: (M, 2) centres, normalised image coordinates.
        S, Si: (M, 2, 2) square root of each blob's second-moment matrix and its inverse.
        semi_major: (M,) major semi-axis, normalised units.
        color: (M,) colour index.
        usable: (M,) may be used.
    """

    q: np.ndarray
    S: np.ndarray
    Si: np.ndarray
    semi_major: np.ndarray
    color: np.ndarray
    usable: np.ndarray

    @classmethod
    def build(cls, q: np.ndarray, cov: np.ndarray, color: np.ndarray, usable: np.ndarray
              ) -> BlobGeometry:
        S, Si = _sqrt_2x2(cov)
        tr = cov[:, 0, 0] + cov[:, 1, 1]
        det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
        lmax = tr / 2 + np.sqrt(np.maximum(tr * tr / 4 - det, 0))
        return cls(q=q, S=S, Si=Si, semi_major=2 * np.sqrt(lmax), color=color, usable=usable)


def generate_hypotheses(model: DotModel, geo: BlobGeometry, seeds_per_blob: int = 4,
                        ratio_tol: float = 1.5, match_tol: float = 0.3, min_dots: int = 4,
                        orientation: float = -1.0) -> Hypotheses:
    """All pair-seeded hypotheses for one layout, scored (vectorised).

    Args:
        model: The layout.
        geo: The frame's blobs (:class:`BlobGeometry`).
        seeds_per_blob: Nearest usable neighbours of each blob tried as its pair.
        ratio_tol: Largest factor between the blob distance in the ellipse's metric and the
            dot distance.
        match_tol: Tolerance of a predicted dot position, in units of the hypothesis' smallest
            dot spacing.
        min_dots: Fewest dots a hypothesis must find.
        orientation: Sign of the determinant of the plane → image map for a face seen from
            its front (-1 for OpenCV's camera frame with plane axes u × v = normal).

    Returns:
        Hypotheses with at least ``min_dots`` dots found, best first.
    """
    N = model.n
    idx = np.flatnonzero(model.color_ok[geo.color] & geo.usable)
    M = idx.size
    if M < min_dots:
        return Hypotheses.empty(model)
    if _numba.enabled():
        assign, score, scale, A, origin = _k.hypotheses(
            geo.q[idx], geo.color[idx], geo.S[idx], geo.Si[idx], geo.semi_major[idx],
            model.pairs, model.pair_color_match, model.pair_len, model.pair_vec,
            model.pair_mid, model.pair_ra_half, model.pair_rb_half, model.pair_ia,
            model.pair_ib, model.P, model.colors, float(model.min_spacing),
            float(model.reach_per_semi_axis), int(seeds_per_blob), float(ratio_tol),
            float(match_tol), int(min_dots), float(orientation))
        if score.size == 0:
            return Hypotheses.empty(model)
        sel = np.argsort(-score, kind="stable")
        assign = assign[sel]
        assign = np.where(assign >= 0, idx[np.maximum(assign, 0)], -1)
        return Hypotheses(model, assign, score[sel], scale[sel], A[sel], origin[sel])
    qq, col = geo.q[idx], geo.color[idx]
    S, Si = geo.S[idx], geo.Si[idx]
    reach = geo.semi_major[idx] * model.reach_per_semi_axis
    diff = qq[:, None, :] - qq[None, :, :]
    D2 = (diff * diff).sum(axis=2)
    D2.flat[::M + 1] = np.inf
    K = min(M - 1, N + 3)
    order = np.argsort(D2, axis=1)[:, :K]                     # (M, K) nearest blobs
    near = D2[np.arange(M)[:, None], order] <= (reach * reach)[:, None]
    # ---- seed pairs: each blob with its nearest few (within reach), layout pairs by colour
    ks = min(seeds_per_blob, K)
    okp = near[:, :ks].ravel()
    si = np.repeat(np.arange(M), ks)[okp]
    sj = order[:, :ks].ravel()[okp]
    # (i, j) and (j, i) give the same hypotheses (the layout's pairs come in both orders)
    key = np.unique(np.minimum(si, sj) * M + np.maximum(si, sj))
    si, sj = key // M, key % M
    hs, hp = np.nonzero(model.pair_color_match[col[si], col[sj]])
    if hs.size == 0:
        return Hypotheses.empty(model)
    i, j = si[hs], sj[hs]
    a, b = model.pairs[hp, 0], model.pairs[hp, 1]
    le = model.pair_len[hp]
    f = qq[j] - qq[i]                                         # (H, 2) image
    # distance in each ellipse's metric: (r/2)·Σ^{-1/2}·f has the length of e
    fc = f[:, :, None]
    gi = (Si[i] @ fc)[:, :, 0]
    gj = (Si[j] @ fc)[:, :, 0]
    ri = np.sqrt((gi * gi).sum(axis=1)) * model.pair_ra_half[hp] / le
    rj = np.sqrt((gj * gj).sum(axis=1)) * model.pair_rb_half[hp] / le
    lo = 1.0 / ratio_tol
    keep = np.flatnonzero((ri < ratio_tol) & (ri > lo) & (rj < ratio_tol) & (rj > lo))
    if keep.size == 0:
        return Hypotheses.empty(model)
    i, j, a, b, hp, f = i[keep], j[keep], a[keep], b[keep], hp[keep], f[keep]
    e, le = model.pair_vec[hp], model.pair_len[hp]
    # ---- local affine map A (plane → image) with A·e = f, A = S̄·Q·s
    Sbar = S[i] * model.pair_ia[hp][:, None, None] + S[j] * model.pair_ib[hp][:, None, None]
    s00, s01, s11 = Sbar[:, 0, 0], Sbar[:, 0, 1], Sbar[:, 1, 1]
    dS = s00 * s11 - s01 * s01
    g0 = (s11 * f[:, 0] - s01 * f[:, 1]) / dS                 # g = S̄⁻¹·f
    g1 = (s00 * f[:, 1] - s01 * f[:, 0]) / dS
    lg = np.sqrt(g0 * g0 + g1 * g1)
    e0, e1 = e[:, 0] / le, e[:, 1] / le
    h0, h1 = g0 / lg, g1 / lg
    Q = np.empty_like(Sbar)
    if orientation < 0:   # reflection taking ê to ĝ
        c2 = e0 * h0 - e1 * h1
        s2 = e0 * h1 + e1 * h0
        Q[:, 0, 0], Q[:, 0, 1], Q[:, 1, 0], Q[:, 1, 1] = c2, s2, s2, -c2
    else:                 # rotation taking ê to ĝ
        c1 = e0 * h0 + e1 * h1
        s1 = e0 * h1 - e1 * h0
        Q[:, 0, 0], Q[:, 0, 1], Q[:, 1, 0], Q[:, 1, 1] = c1, -s1, s1, c1
    A = (Sbar @ Q) * (lg / le)[:, None, None]
    origin = 0.5 * (qq[i] + qq[j]) - (A @ model.pair_mid[hp][:, :, None])[:, :, 0]
    pred = origin[:, None, :] + model.P[None, :, :] @ A.transpose(0, 2, 1)   # (H, N, 2)
    # smallest singular value of A × smallest dot spacing → position tolerance
    ata = A.transpose(0, 2, 1) @ A
    tr = ata[:, 0, 0] + ata[:, 1, 1]
    dt = ata[:, 0, 0] * ata[:, 1, 1] - ata[:, 0, 1] ** 2
    sv_min = np.sqrt(np.maximum(tr / 2 - np.sqrt(np.maximum(tr * tr / 4 - dt, 0)), 0))
    scale = sv_min * model.min_spacing
    tol2 = (match_tol * scale) ** 2
    # ---- look for each dot among the nearest blobs of the seed (and the seed itself)
    cand = np.concatenate([i[:, None], order[i]], axis=1)    # (H, K+1)
    cand_ok = np.concatenate([np.ones((i.size, 1), bool), near[i]], axis=1)
    dq = pred[:, :, None, :] - qq[cand][:, None, :, :]        # (H, N, K+1, 2)
    dist2 = (dq * dq).sum(axis=3)
    right = (col[cand][:, None, :] == model.colors[None, :, None]) & cand_ok[:, None, :]
    dist2[~right] = np.inf
    best = dist2.argmin(axis=2)                               # (H, N)
    H = i.size
    rows = np.arange(H)[:, None]
    bd = dist2[rows, np.arange(N)[None, :], best]
    found = bd <= tol2[:, None]
    assign = np.where(found, cand[rows, best], -1)
    r1 = np.arange(H)
    assign[r1, a] = i
    assign[r1, b] = j
    found[r1, a] = True
    found[r1, b] = True
    count = found.sum(axis=1)
    close = np.where(found, np.sqrt(bd / tol2[:, None]), 0.0)
    close[r1, a] = 0.0
    close[r1, b] = 0.0
    score = count - 0.5 * close.sum(axis=1) / np.maximum(count - 2, 1)
    sel = np.flatnonzero(count >= min_dots)
    if sel.size == 0:
        return Hypotheses.empty(model)
    sel = sel[np.argsort(-score[sel], kind="stable")]
    assign = assign[sel]
    assign = np.where(assign >= 0, idx[np.maximum(assign, 0)], -1)
    return Hypotheses(model, assign, score[sel], scale[sel], A[sel], origin[sel])


@dataclass
class Candidate:
    """A brick candidate: one layout, the blob of each of its dots (-1 = not found)."""

    model: DotModel
    assign: np.ndarray
    score: float
    scale: float


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """A well-mixed 64-bit hash of each element (sums of these identify sets of blobs)."""
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def assign_greedy(hyps: list[Hypotheses], n_blobs: int, min_dots: int = 4,
                  taken: np.ndarray | None = None) -> list[Candidate]:
    """Give blobs to hypotheses, best first; a blob belongs to at most one brick.

    Hypotheses of all layouts compete on their score. Many hypotheses describe the same brick
    (every seed pair of its dots): rows with the same (layout, set of blobs) are merged first
    (by a sum of well-mixed 64-bit hashes of its blobs; the best scored is kept). Then, in
    rounds, every row that no better row still in play competes with for a blob is accepted
    (the same result as taking rows one by one, best first), and rows left with fewer than
    ``min_dots`` free blobs drop out. A hypothesis keeps the dots whose blobs are still free
    (a blob met twice in one hypothesis goes to its first dot).

    Args:
        hyps: Hypotheses of each layout (best first within each).
        n_blobs: Number of blobs (indices in ``assign`` are below it).
        min_dots: Fewest dots per brick.
        taken: Blobs already used (updated in place).
    """
    taken = np.zeros(n_blobs, bool) if taken is None else taken
    hyps = [h for h in hyps if h.assign.shape[0]]
    if not hyps:
        return []
    W = max(h.model.n for h in hyps)
    A, scores, which, row = _stacked(hyps, W)
    order = np.argsort(-scores, kind="stable")

    def candidate(o: int, r: np.ndarray) -> Candidate:
        h = hyps[int(which[o])]
        return Candidate(h.model, r[:h.model.n], float(scores[o]), float(h.scale[int(row[o])]))

    if _numba.enabled():
        A = np.ascontiguousarray(A[order])
        acc, rows_a = _k.assign_greedy(A, int(min_dots), taken)
        return [candidate(int(order[k]), r) for k, r in zip(acc.tolist(), rows_a)]
    if order.size > 64:     # many rows: merge duplicates first (few rows: the rounds do it)
        order = _unique_rows(A, order, which, n_blobs)
    A = A[order].copy()
    _first_dot_keeps(A, W)
    out: list[Candidate] = []
    # rounds of "locally best" rows: a row is accepted when no better row still in play uses
    # any of its free blobs; rows left with too few free blobs drop out
    while A.shape[0]:
        free = (A >= 0) & ~taken[np.maximum(A, 0)]
        ok = free.sum(axis=1) >= min_dots
        if not ok.all():
            A, order, free = A[ok], order[ok], free[ok]
            if A.shape[0] == 0:
                break
        owner = np.full(n_blobs, A.shape[0], np.int64)
        rows_of = np.broadcast_to(np.arange(A.shape[0])[:, None], A.shape)
        np.minimum.at(owner, A[free], rows_of[free])
        best = np.where(free, owner[np.maximum(A, 0)], np.arange(A.shape[0])[:, None])
        win = (best == np.arange(A.shape[0])[:, None]).all(axis=1)
        for k in np.flatnonzero(win).tolist():
            r = np.where(free[k], A[k], -1)
            taken[r[r >= 0]] = True
            out.append(candidate(int(order[k]), r))
        keep = ~win
        A, order = A[keep], order[keep]
    return out


def _stacked(hyps: list[Hypotheses], W: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All hypotheses' rows as one (rows, W) assignment (padded with -1), their scores, the
    hypotheses each came from and its row there."""
    if len(hyps) == 1:
        A = hyps[0].assign
        return A, hyps[0].score, np.zeros(A.shape[0], np.int64), np.arange(A.shape[0])
    A = np.concatenate([np.pad(h.assign, ((0, 0), (0, W - h.model.n)), constant_values=-1)
                        for h in hyps])
    scores = np.concatenate([h.score for h in hyps])
    which = np.concatenate([np.full(h.score.size, k) for k, h in enumerate(hyps)])
    row = np.concatenate([np.arange(h.score.size) for h in hyps])
    return A, scores, which, row


def _unique_rows(A: np.ndarray, order: np.ndarray, which: np.ndarray, n_blobs: int
                 ) -> np.ndarray:
    """``order`` without the rows that repeat a better row's (layout, set of blobs)."""
    with np.errstate(over="ignore"):
        hv = _splitmix64(np.arange(n_blobs, dtype=np.uint64))
        key = np.where(A >= 0, hv[np.maximum(A, 0)], np.uint64(0)).sum(axis=1) \
            + _splitmix64(which.astype(np.uint64) + np.uint64(1 << 40))
    _, first = np.unique(key[order], return_index=True)
    return order[np.sort(first)]


def _first_dot_keeps(A: np.ndarray, W: int) -> None:
    """One blob for two dots of a row: the first dot keeps it (A changed in place)."""
    srt = np.sort(np.where(A >= 0, A, -np.arange(1, W + 1)[None, :]), axis=1)
    dup_rows = np.flatnonzero((srt[:, 1:] == srt[:, :-1]).any(axis=1))
    for rr in dup_rows.tolist():
        seen: set[int] = set()
        for d, bl in enumerate(A[rr].tolist()):
            if bl >= 0:
                if bl in seen:
                    A[rr, d] = -1
                seen.add(bl)
