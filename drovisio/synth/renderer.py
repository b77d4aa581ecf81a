"""The renderers: a scene, a chessboard view, a ChArUco view (image and truth)."""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.geometry import transform
from drovisio.synth.canvas import Canvas
from drovisio.synth.effects import apply_effects
from drovisio.synth.markers import brick_truth, draw_board, draw_brick, draw_mesh, light_factor
from drovisio.synth.scene import (
    INK_BLACK,
    PAPER_WHITE,
    SKY,
    Board,
    Effects,
    Ground,
    RenderResult,
    Scene,
)
from drovisio.synth.textures import ground_sampler

__all__ = ["render", "render_chessboard", "render_charuco"]


def render(scene: Scene, effects: Effects | None = None, ss: int = 4) -> RenderResult:
    """Render a scene.

    Args:
        scene: What to draw.
        effects: Degradations applied to the image (none by default).
        ss: Samples per pixel along each axis (anti-aliasing); 4 gives edge positions
            unbiased to ~0.01 px after the box filter.

    Returns:
        The BGR uint8 image and each brick's true pose and projected markers.
    """
    cam = scene.camera
    canvas = Canvas(cam, ss, scene.background_bgr)
    cfw = np.asarray(scene.camera_from_world, np.float64)
    light = np.asarray(scene.light_dir, float)
    light /= np.linalg.norm(light)
    if scene.ground is not None:
        canvas.draw_world_plane_full(cfw, ground_sampler(scene.ground),
                                     light_factor(np.array([0, 0, 1.0]), light, scene.ambient))
    for prop in scene.props:
        draw_mesh(canvas, prop.mesh, cfw @ prop.world_from_object, prop.world_from_object,
                   prop.bgr, scene)
    for board in scene.boards:
        draw_board(canvas, board, cfw, scene)
    truths = []
    for brick in scene.bricks:
        draw_brick(canvas, brick, cfw, scene)
        truths.append(brick_truth(brick, cam, cfw @ brick.world_from_brick))
    image = apply_effects(canvas.resolve(), effects or Effects())
    return RenderResult(image=image, bricks=truths, camera_from_world=cfw)



def render_chessboard(camera: Camera, camera_from_board: np.ndarray, cols: int = 9,
                      rows: int = 6, square: float = 0.025, effects: Effects | None = None,
                      ground: Ground | None = None, ss: int = 4
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a chessboard view for calibration.

    Args:
        camera: The camera.
        camera_from_board: 4×4 pose of the board frame (see :class:`Board`) in the camera.
        cols: Inner corners per row.
        rows: Inner corners per column.
        square: Square side, metres.
        effects: Image degradations.
        ground: Background far behind the board (a textured plane 3 m away), or None for a
            plain background.
        ss: Samples per pixel per axis.

    Returns:
        (image BGR uint8, true inner corners (rows·cols, 2) in distorted pixels, object points
        (rows·cols, 3) in metres), corners in OpenCV's row-major order.
    """
    board = Board(cols=cols, rows=rows, square=square, world_from_board=np.eye(4))
    # the "world" is the board frame here; a background plane 3 m behind it
    scene = Scene(camera=camera, camera_from_world=np.asarray(camera_from_board, float),
                  ground=None, boards=[board], light_dir=(0, 0, -1.0))
    canvas = Canvas(camera, ss, scene.background_bgr)
    if ground is not None:
        behind = np.asarray(camera_from_board, float) @ transform(
            np.diag([1.0, -1.0, -1.0]), [0, 0, 3.0])
        canvas.draw_world_plane_full(behind, ground_sampler(ground), 0.8)
    draw_board(canvas, board, scene.camera_from_world, scene)
    img = apply_effects(canvas.resolve(), effects or Effects())
    obj = board.object_points()
    return img, camera.project_from(obj, camera_from_board), obj


def render_charuco(camera: Camera, camera_from_board: np.ndarray, charuco, square: float,
                   effects: Effects | None = None, ss: int = 3, px_per_square: int = 48
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a ChArUco board (printed on a large white sheet) for calibration.

    The board's own image (``charuco.generateImage``, ``px_per_square`` pixels a square) is
    mapped onto the board plane and sampled through the camera model, distortion included,
    ``ss``×``ss`` rays a pixel.

    Args:
        camera: The camera.
        camera_from_board: 4×4 pose of the board frame: OpenCV's (origin at the first inner
            chessboard corner, x along a row, y down the board, z into the board).
        charuco: A ``cv2.aruco.CharucoBoard``.
        square: Square side, metres.
        effects: Image degradations.
        ss: Samples per pixel per axis.
        px_per_square: Resolution of the board's image.

    Returns:
        (image BGR uint8, true inner corners (N, 2) in distorted pixels in ChArUco id order,
        object points (N, 3) in metres).
    """
    cols, rows = charuco.getChessboardSize()          # squares
    img = charuco.generateImage((cols * px_per_square, rows * px_per_square), marginSize=0)
    tex = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR).astype(np.float32) * (
        (PAPER_WHITE[0] - INK_BLACK[0]) / 255.0) + INK_BLACK[0]
    canvas = Canvas(camera, ss, SKY)

    def sample(u: np.ndarray, v: np.ndarray):
        # board metres (u, −v in the flipped plane) → image pixels; white sheet around it
        mx = ((u / square + 1.0) * px_per_square - 0.5).astype(np.float32)
        my = ((-v / square + 1.0) * px_per_square - 0.5).astype(np.float32)
        width = 2048
        n = mx.size
        rows_ = -(-n // width)
        pad = rows_ * width - n
        out = cv2.remap(tex, np.pad(mx, (0, pad)).reshape(rows_, width),
                        np.pad(my, (0, pad)).reshape(rows_, width), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=PAPER_WHITE)
        return out.reshape(-1, 3)[:n], None

    # the plane drawn faces the camera: the board frame turned half about its x axis
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    canvas.draw_world_plane_full(np.asarray(camera_from_board, float) @ flip, sample, 1.0)
    out = apply_effects(canvas.resolve(), effects or Effects())
    obj = np.asarray(charuco.getChessboardCorners(), np.float64).reshape(-1, 3) - [square,
                                                                                   square, 0]
    return out, camera.project_from(obj, camera_from_board), obj
