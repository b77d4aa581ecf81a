"""What a synthetic image shows: the scene's description, the camera's pose, the truth.

Frames: world z up, ground at z = 0, metres; camera frame is OpenCV's (x right, y down,
z forward); transforms are 4×4 ``a_from_b`` matrices (``p_a = a_from_b @ p_b``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from drovisio.camera import Camera
from drovisio.geometry import rot_z, rvec_tvec, transform
from drovisio.layout import MarkerLayout

Vec3 = Sequence[float] | np.ndarray
"""A 3-vector, world frame, metres."""

__all__ = ["PAPER_WHITE", "INK_BLACK", "CONCRETE", "SKY", "look_at", "camera_over", "Effects",
           "Ground", "BrickInstance", "Prop", "Board", "Scene", "BrickTruth", "RenderResult"]

PAPER_WHITE = (235.0, 235.0, 235.0)
INK_BLACK = (22.0, 22.0, 22.0)
CONCRETE = (150.0, 152.0, 155.0)
SKY = (235.0, 215.0, 200.0)


# =================================================================================== poses
def look_at(eye: Vec3, target: Vec3, up: Vec3 = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``camera_from_world`` of an OpenCV camera at ``eye`` looking at ``target``.

    Args:
        eye: Camera centre in the world frame, metres.
        target: Point the optical axis goes through.
        up: World direction that should appear up in the image (must not be parallel to the
            viewing direction).
    """
    centre = np.asarray(eye, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - centre
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(r) < 1e-9:
        raise ValueError("look_at: 'up' is parallel to the viewing direction")
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])  # rows: camera axes in world coordinates
    return transform(R, -R @ centre)


def camera_over(target: Vec3, distance: float, tilt_deg: float = 0.0,
                heading_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """``camera_from_world`` of a downward camera ``distance`` from ``target``.

    Args:
        target: World point at the image centre.
        distance: Camera-to-target distance, metres.
        tilt_deg: Angle between the optical axis and straight down.
        heading_deg: Direction the camera is displaced toward (0 = from −y, looking toward +y),
            also the image's up direction when the tilt is 0.
        roll_deg: Rotation of the image about the optical axis.
    """
    tilt, head = math.radians(tilt_deg), math.radians(heading_deg)
    fwd_h = np.array([-math.sin(head), math.cos(head), 0.0])  # horizontal look direction
    eye = np.asarray(target, float) - distance * (math.sin(tilt) * fwd_h) + [
        0.0, 0.0, distance * math.cos(tilt)]
    T = look_at(eye, target, up=fwd_h if tilt_deg < 1e-6 else (0.0, 0.0, 1.0))
    if roll_deg:
        T = transform(rot_z(math.radians(roll_deg))) @ T
    return T


# =================================================================================== scene
@dataclass
class Effects:
    """Image degradations applied after rendering (all off by default)."""

    blur_sigma_px: float = 0.0
    """Gaussian (defocus) blur, standard deviation in output pixels."""
    motion_px: float = 0.0
    """Length of a linear motion-blur streak, output pixels."""
    motion_angle_deg: float = 0.0
    """Direction of the motion streak in the image (0 = along +x)."""
    gain: float = 1.0
    """Multiplies the brightness (lighting change)."""
    gamma: float = 1.0
    """Applied to normalised intensity after the gain: I' = I^gamma."""
    noise_sigma: float = 0.0
    """Gaussian sensor noise, standard deviation in 8-bit levels."""
    jpeg_quality: int | None = None
    """Encode to JPEG at this quality and decode back (None = lossless)."""
    seed: int = 0
    """Seed of the noise."""


@dataclass
class Ground:
    """A textured ground plane at world z = 0."""

    kind: str = "concrete"
    """One of ``concrete``, ``gravel``, ``grass``, ``clutter`` or ``plain``."""
    seed: int = 0
    """Seed of the procedural texture."""
    metres_per_texel: float = 0.002
    """Texture resolution on the ground."""


@dataclass
class BrickInstance:
    """A brick of a marker layout placed in the world.

    Args:
        layout: The brick's :class:`drovisio.layout.MarkerLayout`.
        world_from_brick: 4×4 pose of the brick frame in the world.
        instance: Instance number k (chooses the code ids); None for layouts without codes.
        body_bgr: Colour of the brick's body.
        hidden_markers: Indices into ``layout.markers`` that are not painted (a worn or
            covered marker). Physical occlusion is better shown with another brick or a prop.
    """

    layout: MarkerLayout
    world_from_brick: np.ndarray
    instance: int | None = 0
    body_bgr: tuple[float, float, float] = (165.0, 168.0, 172.0)
    hidden_markers: frozenset[int] = frozenset()


@dataclass
class Prop:
    """Any mesh in the scene (clutter, a red cup, a tarpaulin, an occluding block)."""

    mesh: object  # trimesh.Trimesh
    world_from_object: np.ndarray
    bgr: tuple[float, float, float] = (120.0, 120.0, 120.0)


@dataclass
class Board:
    """A calibration chessboard (a printed target, flat).

    The board frame is OpenCV's calibration convention: origin at the first inner corner,
    x along the ``cols`` inner corners, y along the ``rows``, z into the board (so the printed
    side faces −z). Inner corner (i, j) is at (i·square, j·square, 0).
    """

    cols: int = 9
    rows: int = 6
    square: float = 0.025
    world_from_board: np.ndarray = field(default_factory=lambda: np.eye(4))
    margin_squares: float = 0.6
    """White margin around the squares, in squares."""

    def object_points(self) -> np.ndarray:
        """(rows·cols, 3) inner corners in the board frame, row-major as OpenCV finds them."""
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        return np.stack([i.ravel() * self.square, j.ravel() * self.square,
                         np.zeros(i.size)], axis=1)


@dataclass
class Scene:
    """What the camera sees.

    Args:
        camera: The calibrated camera (distortion included).
        camera_from_world: 4×4 camera pose.
        ground: Ground plane, or None for a plain background colour.
        bricks: Bricks of marker layouts.
        props: Other meshes.
        boards: Calibration chessboards.
        light_dir: Direction *toward* the sun in the world frame.
        ambient: Share of light that does not depend on the face orientation.
    """

    camera: Camera
    camera_from_world: np.ndarray
    ground: Ground | None = field(default_factory=Ground)
    bricks: list[BrickInstance] = field(default_factory=list)
    props: list[Prop] = field(default_factory=list)
    boards: list[Board] = field(default_factory=list)
    light_dir: tuple[float, float, float] = (0.3, -0.4, 1.0)
    ambient: float = 0.55
    background_bgr: tuple[float, float, float] = SKY


@dataclass
class BrickTruth:
    """Ground truth of one rendered brick."""

    layout: str
    instance: int | None
    camera_from_brick: np.ndarray
    code_ids: list[int]
    code_corners_px: dict[int, np.ndarray]
    """Marker id → (4, 2) projected outer corners (OpenCV order), distorted pixels."""
    dot_centers_px: np.ndarray
    """(N, 2) projected dot centres (true centres of the circles, not ellipse centroids)."""

    @property
    def rvec(self) -> np.ndarray:
        return rvec_tvec(self.camera_from_brick)[0]

    @property
    def tvec(self) -> np.ndarray:
        return self.camera_from_brick[:3, 3].copy()

    def to_json(self) -> dict:
        return {"layout": self.layout, "instance": self.instance,
                "rvec": self.rvec.tolist(), "tvec": self.tvec.tolist(),
                "camera_from_brick": self.camera_from_brick.tolist(),
                "markers": self.code_ids}


@dataclass
class RenderResult:
    """A rendered image (BGR uint8) and the truth of what is in it."""

    image: np.ndarray
    bricks: list[BrickTruth]
    camera_from_world: np.ndarray

