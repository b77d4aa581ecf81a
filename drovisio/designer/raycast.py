"""Cast a viewer's click ray against a mesh, and the mesh's flat faces.

A 3D viewer (viser) reports a click on a scene node as a *ray in the world frame*, not as a
point. The mesh is drawn with a pose ``world_from_mesh`` (rotation and translation), so the
ray is first brought into the mesh's own frame (the pose undone), then intersected with the
triangles by trimesh's rtree-accelerated ray/triangle test (no embree, no scipy).

:class:`FlatFaces` groups the triangles into *flat faces* (connected triangles sharing one
plane, e.g. the two triangles of a box side): a marker lies on one flat face, "snap to face
centre" uses its area-weighted centroid, and "does the marker overhang its face" tests points
against its triangles.

Units: whatever the mesh is in (the designer passes metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh
from numpy.typing import ArrayLike
from trimesh.ray.ray_triangle import RayMeshIntersector

__all__ = ["RayHit", "cast_ray", "FlatFace", "FlatFaces"]

#: Adjacent triangles whose normals differ by less than this are one flat face.
COPLANAR_ANGLE_DEG = 0.5


@dataclass(frozen=True)
class RayHit:
    """Where a ray first meets the mesh, in the mesh's frame.

    Attributes:
        point: (3,) hit point.
        normal: (3,) unit normal of the hit triangle (the mesh's outward normal).
        face_index: index of the hit triangle in ``mesh.faces``.
        distance: distance from the ray origin along the (unit) ray direction, in the
            world frame's length unit (rigid poses keep lengths).
    """

    point: np.ndarray
    normal: np.ndarray
    face_index: int
    distance: float


def _intersector(mesh: trimesh.Trimesh) -> RayMeshIntersector:
    # trimesh caches the intersector on the mesh (mesh.ray); force the rtree-based one so
    # results do not depend on whether embree happens to be installed.
    cached = getattr(mesh, "_drovisio_ray", None)
    if cached is None:
        cached = RayMeshIntersector(mesh)
        mesh._drovisio_ray = cached  # type: ignore[attr-defined]
    return cached


def cast_ray(mesh: trimesh.Trimesh, origin_world: ArrayLike, direction_world: ArrayLike,
             world_from_mesh: np.ndarray | None = None) -> RayHit | None:
    """First intersection of a world-frame ray with a posed mesh.

    Args:
        mesh: the mesh, in its own frame.
        origin_world: (3,) ray origin in the world frame (e.g. viser's ``ray_origin``).
        direction_world: (3,) ray direction in the world frame (need not be unit length).
        world_from_mesh: 4x4 rigid pose the mesh is drawn with (identity if None).

    Returns:
        The nearest hit in front of the origin, in the mesh's frame, or None when the ray
        misses the mesh (or the direction is zero/non-finite).
    """
    o = np.asarray(origin_world, np.float64).reshape(3)
    d = np.asarray(direction_world, np.float64).reshape(3)
    n = float(np.linalg.norm(d))
    if not (np.all(np.isfinite(o)) and np.isfinite(n)) or n < 1e-12:
        return None
    d = d / n
    if world_from_mesh is not None:
        T = np.asarray(world_from_mesh, np.float64)
        R, t = T[:3, :3], T[:3, 3]
        o = R.T @ (o - t)  # undo the translation, then the rotation
        d = R.T @ d
    if len(mesh.faces) == 0:
        return None
    locs, _, tri = _intersector(mesh).intersects_location(
        o[None], d[None], multiple_hits=True)
    if len(locs) == 0:
        return None
    dist = (locs - o) @ d
    ahead = dist >= -1e-9
    if not np.any(ahead):
        return None
    k = int(np.argmin(np.where(ahead, dist, np.inf)))
    face = int(tri[k])
    return RayHit(point=np.asarray(locs[k], np.float64), normal=np.asarray(
        mesh.face_normals[face], np.float64), face_index=face, distance=float(dist[k]))


@dataclass
class FlatFace:
    """One flat face of a mesh: connected triangles in one plane.

    Attributes:
        index: index in :attr:`FlatFaces.faces`.
        triangles: indices of its triangles in ``mesh.faces``.
        normal: (3,) outward unit normal.
        centroid: (3,) area-weighted centroid (may lie outside a non-convex face; see
            :meth:`FlatFaces.centre`).
        area: total area.
    """

    index: int
    triangles: np.ndarray
    normal: np.ndarray
    centroid: np.ndarray
    area: float


class FlatFaces:
    """The flat faces of a mesh and point-in-face tests (mesh frame).

    Args:
        mesh: a triangle mesh (vertices merged, as ``trimesh.load`` gives them).
        angle_deg: adjacent triangles whose normals differ less than this are merged.
    """

    def __init__(self, mesh: trimesh.Trimesh, angle_deg: float = COPLANAR_ANGLE_DEG):
        self.mesh = mesh
        F = len(mesh.faces)
        normals = np.asarray(mesh.face_normals, np.float64)
        labels = np.arange(F)
        if F:
            adj = np.asarray(mesh.face_adjacency, np.int64).reshape(-1, 2)
            if len(adj):
                same = np.einsum("ij,ij->i", normals[adj[:, 0]], normals[adj[:, 1]]) >= \
                    np.cos(np.radians(angle_deg))
                a, b = adj[same, 0], adj[same, 1]
                # Connected components by min-label propagation with pointer jumping.
                while True:
                    m = np.minimum(labels[a], labels[b])
                    new = labels.copy()
                    np.minimum.at(new, a, m)
                    np.minimum.at(new, b, m)
                    new = new[new]
                    if np.array_equal(new, labels):
                        break
                    labels = new
        if F:
            # Chains of nearly coplanar triangles (a finely tessellated curved surface) are
            # not flat: a group whose triangles stray from its mean normal is split into
            # single triangles (a marker there then "overhangs", which is the truth).
            _, inv = np.unique(labels, return_inverse=True)
            inv = inv.reshape(-1)
            w = np.asarray(mesh.area_faces, np.float64)
            mean = np.zeros((int(inv.max()) + 1, 3))
            np.add.at(mean, inv, normals * w[:, None])
            mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
            cos_dev = np.einsum("ij,ij->i", normals, mean[inv])
            bad = np.zeros(len(mean), bool)
            np.logical_or.at(bad, inv, cos_dev < np.cos(np.radians(2 * angle_deg)))
            labels = np.where(bad[inv], -1 - np.arange(F), labels)
        _, self.face_of_triangle = np.unique(labels, return_inverse=True)
        self.face_of_triangle = self.face_of_triangle.reshape(-1)
        areas = np.asarray(mesh.area_faces, np.float64) if F else np.zeros(0)
        centres = np.asarray(mesh.triangles_center, np.float64) if F else np.zeros((0, 3))
        self.faces: list[FlatFace] = []
        n_faces = int(self.face_of_triangle.max()) + 1 if F else 0
        order = np.argsort(self.face_of_triangle, kind="stable")
        bounds = np.searchsorted(self.face_of_triangle[order], np.arange(n_faces + 1))
        for f in range(n_faces):
            tris = order[bounds[f]:bounds[f + 1]]
            w = areas[tris]
            total = float(w.sum())
            nrm = (normals[tris] * w[:, None]).sum(axis=0)
            nn = np.linalg.norm(nrm)
            nrm = nrm / nn if nn > 0 else normals[tris[0]]
            cen = (centres[tris] * w[:, None]).sum(axis=0) / total if total > 0 else \
                centres[tris].mean(axis=0)
            self.faces.append(FlatFace(index=f, triangles=tris, normal=nrm, centroid=cen,
                                       area=total))

    def __len__(self) -> int:
        return len(self.faces)

    def of_triangle(self, triangle: int) -> FlatFace:
        """The flat face a triangle belongs to."""
        return self.faces[int(self.face_of_triangle[triangle])]

    @cached_property
    def _triangles(self) -> np.ndarray:
        return np.asarray(self.mesh.triangles, np.float64)

    def contains(self, face: FlatFace, points: np.ndarray, tol: float = 0.0,
                 plane_tol: float | None = None) -> np.ndarray:
        """Which points lie on a flat face (inside one of its triangles, within ``tol``).

        Args:
            face: the flat face.
            points: (N, 3) points (projected onto the face's plane before the test).
            tol: distance a point may lie outside the face's outline and still count.
            plane_tol: if given, points farther than this from the face's plane are outside.

        Returns:
            (N,) bool.
        """
        P = np.asarray(points, np.float64).reshape(-1, 3)
        tris = self._triangles[face.triangles]  # (T, 3, 3)
        n = face.normal
        ok_plane = np.ones(len(P), bool)
        if plane_tol is not None:
            ok_plane = np.abs((P - tris[0, 0]) @ n) <= plane_tol
        # 2D coordinates in the face plane.
        u = tris[0, 1] - tris[0, 0]
        u = u - (u @ n) * n
        nu = np.linalg.norm(u)
        if nu < 1e-15:
            u = np.cross(n, [1.0, 0.0, 0.0])
            if np.linalg.norm(u) < 1e-6:
                u = np.cross(n, [0.0, 1.0, 0.0])
            nu = np.linalg.norm(u)
        u /= nu
        v = np.cross(n, u)
        p2 = np.stack([P @ u, P @ v], axis=1)  # (N, 2)
        t2 = np.stack([tris @ u, tris @ v], axis=2)  # (T, 3, 2)
        a, b, c = t2[:, 0], t2[:, 1], t2[:, 2]
        # signed area orientation per triangle (handle either winding)
        orient = np.sign((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                         - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
        orient[orient == 0] = 1.0
        inside = np.ones((len(P), len(tris)), bool)
        for e0, e1 in ((a, b), (b, c), (c, a)):
            ev = e1 - e0  # (T, 2)
            length = np.linalg.norm(ev, axis=1)
            length[length == 0] = 1.0
            rel = p2[:, None, :] - e0[None]  # (N, T, 2)
            cross = (ev[None, :, 0] * rel[..., 1] - ev[None, :, 1] * rel[..., 0])
            signed = cross * orient[None] / length[None]  # >= 0 inside (distance to edge)
            inside &= signed >= -tol
        return np.any(inside, axis=1) & ok_plane

    def centre(self, face: FlatFace) -> np.ndarray:
        """The face's centre for snapping: its centroid if that lies on the face, else the
        centre of the face's largest triangle."""
        if self.contains(face, face.centroid[None], tol=1e-9)[0]:
            return face.centroid.copy()
        areas = np.asarray(self.mesh.area_faces)[face.triangles]
        tri = face.triangles[int(np.argmax(areas))]
        return np.asarray(self.mesh.triangles_center[tri], np.float64)
