"""The brick frame on the mesh: building, turning and reading ``brick_from_mesh`` (4x4,
metres), and the in-plane directions a face's markers and grid use.

The mesh frame is the mesh file's own axes (scaled to metres); the brick frame is the
layout's (origin and axes chosen on the mesh).
"""

from __future__ import annotations

import numpy as np
import trimesh

from drovisio.geometry import invert

__all__ = [
    "unit",
    "t3",
    "brick_axes_in_mesh",
    "brick_from_axes",
    "in_plane_x",
    "turned",
    "face_up",
    "longest_edge_direction",
]

#: Transform entries below this are rounding noise of a rotation by a multiple of 90 deg.
_ZERO = 1e-12


def unit(v: np.ndarray | list[float] | tuple[float, ...]) -> np.ndarray:
    """``v`` scaled to length 1, (3,) float64 (the zero vector stays zero)."""
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def t3(v: np.ndarray | list[float] | tuple[float, ...]) -> tuple[float, float, float]:
    """A 3-vector as a tuple of Python floats (how a :class:`DesignMarker` stores it)."""
    a = np.asarray(v, np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


def brick_axes_in_mesh(brick_from_mesh: np.ndarray) -> np.ndarray:
    """(3, 3) whose columns are the brick's x, y, z axes expressed in the mesh frame."""
    return brick_from_mesh[:3, :3].T


def brick_from_axes(origin_m: np.ndarray, x_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """``brick_from_mesh`` of a brick frame given in the mesh frame.

    Args:
        origin_m: (3,) the brick origin, mesh frame, metres.
        x_m: (3,) the brick's x direction (its part along ``z_m`` is dropped).
        z_m: (3,) the brick's z direction.

    Returns:
        4x4 rigid transform, rounding noise set to exactly 0.
    """
    z = unit(z_m)
    x = np.asarray(x_m, np.float64) - (np.asarray(x_m) @ z) * z
    x = unit(x)
    y = np.cross(z, x)
    mesh_from_brick = np.eye(4)
    mesh_from_brick[:3, 0], mesh_from_brick[:3, 1] = x, y
    mesh_from_brick[:3, 2], mesh_from_brick[:3, 3] = z, origin_m
    B = invert(mesh_from_brick)
    B[np.abs(B) < _ZERO] = 0.0
    return B


def in_plane_x(brick_from_mesh: np.ndarray, z: np.ndarray) -> np.ndarray:
    """A direction for a new brick x axis perpendicular to ``z`` (mesh frame): the current
    x axis laid on the plane, else the next candidate that is not along ``z``."""
    axes = brick_axes_in_mesh(brick_from_mesh)
    for cand in (axes[:, 0], axes[:, 1], -axes[:, 2], np.array([1.0, 0, 0]),
                 np.array([0, 1.0, 0])):
        p = cand - (cand @ z) * z
        if np.linalg.norm(p) > 0.2:
            return p
    return np.array([1.0, 0, 0])  # pragma: no cover


def turned(brick_from_mesh: np.ndarray, R_old_from_new: np.ndarray) -> np.ndarray:
    """The brick frame whose axes are the old ones rotated by ``R_old_from_new`` (3x3,
    expressed in the old brick frame); rounding noise set to exactly 0."""
    new_from_old = np.eye(4)
    new_from_old[:3, :3] = R_old_from_new.T
    B = new_from_old @ brick_from_mesh
    B[np.abs(B) < _ZERO] = 0.0
    return B


def face_up(brick_from_mesh: np.ndarray, normal_m: np.ndarray) -> np.ndarray:
    """In-plane 'up' of a face with normal ``normal_m`` (mesh frame): the brick's z laid on
    the face, or the brick's y for a face looking along z. Unit (3,)."""
    n = unit(normal_m)
    axes = brick_axes_in_mesh(brick_from_mesh)
    for cand in (axes[:, 2], axes[:, 1], axes[:, 0]):
        p = cand - (cand @ n) * n
        if np.linalg.norm(p) > 0.3:
            return unit(p)
    return unit(np.cross(n, [1.0, 0, 0]))  # pragma: no cover


def _feature_edges(mesh: trimesh.Trimesh) -> np.ndarray:
    """(E, 2) vertex indices of the edges between faces meeting at an angle (over 1 deg),
    plus the open boundary of a mesh that is not closed."""
    E = np.asarray(mesh.face_adjacency_edges, np.int64).reshape(-1, 2)
    if len(E):
        E = E[np.asarray(mesh.face_adjacency_angles) > np.radians(1.0)]
    boundary = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
    if len(boundary):
        E = np.vstack([E, mesh.edges_sorted[np.asarray(boundary).ravel()]])
    return E


def longest_edge_direction(mesh: trimesh.Trimesh, brick_from_mesh: np.ndarray
                           ) -> np.ndarray | None:
    """Brick-frame direction (unit, in the xy plane, x >= 0) of the mesh's longest *feature*
    edge (between two faces meeting at an angle; triangulation diagonals inside a flat face
    do not count) that is perpendicular to z (within 1 deg), or None.

    Args:
        mesh: the mesh in metres, mesh frame.
        brick_from_mesh: 4x4, the current brick frame.
    """
    E = _feature_edges(mesh)
    if len(E) == 0:
        return None
    V = np.asarray(mesh.vertices, np.float64)
    V = V @ brick_from_mesh[:3, :3].T + brick_from_mesh[:3, 3]
    d = V[E[:, 1]] - V[E[:, 0]]
    length = np.linalg.norm(d, axis=1)
    flat = np.abs(d[:, 2]) <= np.sin(np.radians(1.0)) * length
    if not np.any(flat & (length > 0)):
        return None
    L = np.where(flat, length, -1.0)
    best = L.max()
    cands = np.flatnonzero(L >= best * (1 - 1e-6))
    # among equally long edges, the one closest to the current x axis
    dirs = d[cands, :2] / length[cands, None]
    k = cands[int(np.argmax(np.abs(dirs[:, 0])))]
    v = unit(np.array([d[k, 0], d[k, 1], 0.0]))
    return v if v[0] >= 0 else -v
