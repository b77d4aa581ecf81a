"""Click rays against a posed mesh, and the mesh's flat faces."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from drovisio.designer.raycast import FlatFaces, cast_ray
from drovisio.meshes import drick_mesh


def _pose(angle_deg: float, axis, t) -> np.ndarray:
    T = trimesh.transformations.rotation_matrix(math.radians(angle_deg), axis)
    T[:3, 3] = t
    return T


def test_ray_hits_top_of_pyramid_in_mesh_frame():
    mesh = drick_mesh()
    hit = cast_ray(mesh, [-0.075, 0.01, 1.0], [0, 0, -1])
    assert hit is not None
    np.testing.assert_allclose(hit.point, [-0.075, 0.01, 0.02], atol=1e-9)
    np.testing.assert_allclose(hit.normal, [0, 0, 1], atol=1e-9)
    assert math.isclose(hit.distance, 0.98, abs_tol=1e-9)


def test_pose_is_undone_before_casting():
    """The mesh drawn rotated and moved: a world ray toward the world image of a mesh point
    hits that mesh point (rotation and translation both undone)."""
    mesh = drick_mesh()
    world_from_mesh = _pose(37.0, [0.3, -0.5, 0.8], [0.4, -1.2, 0.7])
    target_mesh = np.array([0.075, -0.02, 0.02])  # on the +x pyramid's top
    target_world = world_from_mesh[:3, :3] @ target_mesh + world_from_mesh[:3, 3]
    normal_world = world_from_mesh[:3, :3] @ np.array([0, 0, 1.0])
    origin = target_world + 0.5 * normal_world + np.array([0.01, 0.0, 0.0])
    hit = cast_ray(mesh, origin, target_world - origin, world_from_mesh)
    assert hit is not None
    np.testing.assert_allclose(hit.point, target_mesh, atol=1e-9)
    np.testing.assert_allclose(hit.normal, [0, 0, 1], atol=1e-9)
    # without undoing the pose the same ray misses that spot
    raw = cast_ray(mesh, origin, target_world - origin)
    assert raw is None or np.linalg.norm(raw.point - target_mesh) > 0.01


def test_ray_miss_and_bad_direction():
    mesh = drick_mesh()
    assert cast_ray(mesh, [5, 5, 1], [0, 0, -1]) is None
    assert cast_ray(mesh, [0, 0, 1], [0, 0, 1]) is None  # pointing away
    assert cast_ray(mesh, [0, 0, 1], [0, 0, 0]) is None
    assert cast_ray(mesh, [0, 0, 1], [float("nan"), 0, -1]) is None


def test_flat_faces_of_the_drick():
    mesh = drick_mesh()
    faces = FlatFaces(mesh)
    # body: top (with two holes), 4 sides, bottom; each pyramid: top + 4 slanted sides
    assert len(faces) == 16
    top = faces.of_triangle(cast_ray(mesh, [0.0, 0.06, 1], [0, 0, -1]).face_index)
    np.testing.assert_allclose(top.normal, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(faces.centre(top), [0, 0, 0], atol=1e-9)
    assert math.isclose(top.area, 0.30 * 0.15 - 2 * 0.075 ** 2, rel_tol=1e-9)
    inside = faces.contains(top, np.array([[0.0, 0.0, 0.0], [0.14, 0.07, 0.0],
                                            [-0.075, 0.0, 0.0], [0.2, 0.0, 0.0]]))
    assert inside.tolist() == [True, True, False, False]  # hole under a pyramid; off the brick
    pyr = faces.of_triangle(cast_ray(mesh, [0.075, 0, 1], [0, 0, -1]).face_index)
    np.testing.assert_allclose(faces.centre(pyr), [0.075, 0, 0.02], atol=1e-9)
    assert math.isclose(pyr.area, 0.07 ** 2, rel_tol=1e-9)


def test_curved_surface_is_not_one_flat_face():
    """A finely tessellated cylinder: neighbours differ by < 0.5 deg, but the side is not
    flat, so it must not become one face (the caps stay whole)."""
    cyl = trimesh.creation.cylinder(radius=0.1, height=0.2, sections=2000)
    faces = FlatFaces(cyl)
    assert len(faces) == 4000 + 2
    cap = faces.of_triangle(cast_ray(cyl, [0.01, 0.02, 1.0], [0, 0, -1]).face_index)
    assert math.isclose(cap.area, math.pi * 0.1 ** 2, rel_tol=1e-4)
