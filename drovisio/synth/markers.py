"""Drawing what a scene holds: meshes (brick bodies, props), printed codes, dots, boards,
and each brick's ground truth."""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from drovisio.camera import Camera
from drovisio.layout import MarkerLayout, aruco_code_bits
from drovisio.synth.canvas import Canvas
from drovisio.synth.scene import Board, BrickInstance, BrickTruth, Scene
from drovisio.synth.textures import Texture, board_texture, code_texture, disc_texture, solid

__all__ = ["light_factor", "brick_mesh_for", "draw_mesh", "draw_brick", "draw_board",
           "brick_truth"]


def light_factor(normal_world: np.ndarray, light_dir: np.ndarray, ambient: float) -> float:
    return ambient + (1.0 - ambient) * max(0.0, float(np.dot(normal_world, light_dir)))


def _plane_axes(normal: np.ndarray, hint: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal (u, v) with u × v = normal."""
    n = normal / np.linalg.norm(normal)
    h = np.array([1.0, 0, 0]) if hint is None else np.asarray(hint, float)
    if abs(np.dot(h, n)) > 0.9:
        h = np.array([0, 1.0, 0])
    u = h - np.dot(h, n) * n
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def draw_mesh(canvas: Canvas, mesh: Any, camera_from_object: np.ndarray,
               world_from_object: np.ndarray, bgr: tuple[float, float, float],
               scene: Scene) -> None:
    """Draw a mesh's triangles (``mesh``: a ``trimesh.Trimesh``) in one colour, lit by the
    scene's light."""
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    R, t = camera_from_object[:3, :3], camera_from_object[:3, 3]
    Vc = V @ R.T + t
    light = np.asarray(scene.light_dir, float)
    light = light / np.linalg.norm(light)
    Rw = world_from_object[:3, :3]
    tex = solid(bgr)
    for f in F:
        a, b, c = Vc[f[0]], Vc[f[1]], Vc[f[2]]
        n = np.cross(b - a, c - a)
        nn = np.linalg.norm(n)
        if nn < 1e-15:
            continue
        n /= nn
        u = (b - a) / np.linalg.norm(b - a)
        v = np.cross(n, u)
        poly = np.array([[0.0, 0.0], [np.dot(b - a, u), 0.0], [np.dot(c - a, u),
                                                                np.dot(c - a, v)]])
        shade = light_factor(Rw @ (R.T @ n), light, scene.ambient)
        canvas.draw(a, u, v, poly, tex, shade)


def brick_mesh_for(layout: MarkerLayout) -> Any:
    """The mesh a layout's brick is drawn with: the mesh it names, else (it names none) a box
    of its ``dimensions`` whose top face is z = 0 (metres).

    Raises:
        InputError: the mesh it names cannot be read
            (:func:`drovisio.mesh_file.load_layout_mesh`).
    """
    import trimesh  # heavy, and only needed once a brick is drawn

    from drovisio.mesh_file import load_layout_mesh

    mesh = load_layout_mesh(layout)
    if mesh is not None:
        return mesh
    dims = np.asarray(layout.dimensions_m, float)
    box = trimesh.creation.box(extents=dims)
    box.apply_translation([0, 0, -dims[2] / 2])
    return box


def _paint_for(layout: MarkerLayout, color_name: str) -> tuple[float, float, float]:
    b, g, r = (float(c) for c in layout.palette()[color_name].display_bgr())
    return b, g, r


def _flipped(tex: Texture) -> Texture:
    """``tex`` looked up with v negated (a code drawn on axes (u, −v))."""
    def flipped(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        return tex(u, -v)
    return flipped


def brick_truth(brick: BrickInstance, camera: Camera, camera_from_brick: np.ndarray
                 ) -> BrickTruth:
    lay = brick.layout
    ids, corners_px = [], {}
    for slot, corners in lay.code_corners_m().items():
        # a code layout's brick carries an instance (None fails in marker_id, as always)
        mid = lay.marker_id(cast(int, brick.instance), slot)
        ids.append(mid)
        corners_px[mid] = camera.project_from(corners, camera_from_brick)
    dots = lay.dot_centers_m()
    dots_px = camera.project_from(dots, camera_from_brick) if len(dots) else np.zeros((0, 2))
    return BrickTruth(layout=lay.name, instance=brick.instance if ids else None,
                      camera_from_brick=camera_from_brick, code_ids=sorted(ids),
                      code_corners_px=corners_px, dot_centers_px=dots_px)


def draw_brick(canvas: Canvas, brick: BrickInstance, camera_from_world: np.ndarray,
                scene: Scene) -> None:
    lay = brick.layout
    cfb = camera_from_world @ brick.world_from_brick
    draw_mesh(canvas, brick_mesh_for(lay), cfb, brick.world_from_brick, brick.body_bgr, scene)
    light = np.asarray(scene.light_dir, float)
    light /= np.linalg.norm(light)
    R, t = cfb[:3, :3], cfb[:3, 3]
    Rw = brick.world_from_brick[:3, :3]
    code_corners = lay.code_corners_m()
    dot_centers, dot_normals = lay.dot_centers_m(), lay.dot_normals()
    dot_diameters, dot_colors = lay.dot_diameters_m(), lay.dot_colors()
    n_dot = 0
    for index, m in enumerate(lay.markers):
        if m.kind == "dot":
            n_dot += 1
        if index in brick.hidden_markers:
            continue
        if m.kind == "aruco":
            c = code_corners[m.id]  # (4, 3) TL TR BR BL, brick frame, metres
            size = float(np.linalg.norm(c[1] - c[0]))
            u_b = (c[1] - c[0]) / size      # along the printed image's rows
            v_b = (c[3] - c[0]) / size      # down the printed image
            n_b = np.cross(u_b, v_b)        # into the face: the printed side looks along -n
            bits = aruco_code_bits(m.dictionary, lay.marker_id(cast(int, brick.instance), m.id))
            margin = 0.035 * size  # white paper around the black border
            # draw() wants axes with u × v = the printed side's normal and a CCW polygon,
            # so use v' = -v (up the printed image) and flip back in the texture lookup
            tex = code_texture(bits, size)
            poly = np.array([[-margin, -size - margin], [size + margin, -size - margin],
                             [size + margin, margin], [-margin, margin]])
            shade = light_factor(Rw @ (-n_b), light, scene.ambient)
            canvas.draw(R @ c[0] + t, R @ u_b, -(R @ v_b), poly,
                        _flipped(tex), shade, decal=True)
        elif m.kind == "dot":
            k = n_dot - 1
            normal = dot_normals[k]
            r = float(dot_diameters[k]) / 2
            ub, vb = _plane_axes(normal)
            poly = np.array([[-r, -r], [r, -r], [r, r], [-r, r]]) * 1.01
            shade = light_factor(Rw @ normal, light, scene.ambient)
            canvas.draw(R @ dot_centers[k] + t, R @ ub, R @ vb, poly,
                        disc_texture(r, _paint_for(lay, dot_colors[k])), shade, decal=True)


def draw_board(canvas: Canvas, board: Board, camera_from_world: np.ndarray,
                scene: Scene) -> None:
    cfb = camera_from_world @ board.world_from_board
    R, t = cfb[:3, :3], cfb[:3, 3]
    sq = board.square
    m = board.margin_squares * sq + sq
    poly = np.array([[-m, -m], [board.cols * sq - sq + m, -m],
                     [board.cols * sq - sq + m, board.rows * sq - sq + m],
                     [-m, board.rows * sq - sq + m]])
    # board x, y with z into the board: the printed side is seen with u × v = -z... draw
    # double-sided (a board can be held either way) and let the texture do the rest.
    light = np.asarray(scene.light_dir, float)
    light /= np.linalg.norm(light)
    shade = light_factor(board.world_from_board[:3, :3] @ np.array([0, 0, -1.0]), light,
                         scene.ambient)
    canvas.draw(t, R[:, 0], R[:, 1], poly, board_texture(board), max(shade, 0.85), cull=False)

