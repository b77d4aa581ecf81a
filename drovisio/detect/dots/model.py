"""The layout's dots as the dot detector sees them (:class:`DotModel`), and which of them the
brick's own mesh hides under a pose (:func:`occluded_dots`).

A model is built once per layout: the dots' plane (``plane_from_brick``), their colours, a
``rot180_z`` layout's half-turn permutation, the seed pairs of the matching stage, and the
mesh triangles that can hide a dot (a drick's pyramids). Poses are ``camera_from_brick``
(X_cam = R · X_brick + t), metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio import _numba
from drovisio.detect.dots import model_kernels as _k
from drovisio.layout import MarkerLayout
from drovisio.pose.batch import layout_degeneracy

__all__ = ["DotModel", "LayoutNotSupported", "occluded_dots"]


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
    """Triangles of the layout's mesh above the dots' plane (brick frame, metres).

    Raises:
        InputError: the mesh cannot be read (:func:`drovisio.mesh_file.load_layout_mesh`).
    """
    from drovisio.mesh_file import load_layout_mesh  # heavy (trimesh): a layout with a mesh

    mesh = load_layout_mesh(layout)
    if mesh is None:
        return np.zeros((0, 3, 3))
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
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
