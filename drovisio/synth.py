"""Synthetic scenes with exact ground truth: the test bed of every detector and of calibration.

The renderer is a ray caster, not a rasteriser: every sub-pixel sample's viewing ray is found by
undistorting its pixel position through the camera's lens model (OpenCV's Brown and rational
models, or the Kannala–Brandt fisheye: samples more than 90° off a fisheye's axis see the
background), and is intersected with the scene's planar polygons (ground, mesh triangles, printed codes, dots,
chessboards). Geometry is therefore exact under distortion: a 3D point seen in the image is
where ``Camera.project`` puts it. Anti-aliasing is a box filter over ``ss × ss`` samples per
pixel, placed symmetrically about the pixel centre (pixel (0, 0) is the centre of the top-left
pixel). Image effects (blur, motion blur, lighting, noise, JPEG) are applied afterwards.

Frames: world z up, ground at z = 0, metres; camera frame is OpenCV's (x right, y down,
z forward); transforms are 4×4 ``a_from_b`` matrices (``p_a = a_from_b @ p_b``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.geometry import rot_z, rvec_tvec, transform
from drovisio.layout import aruco_code_bits

__all__ = [
    "Board", "BrickInstance", "Effects", "Ground", "Prop", "RenderResult", "Scene",
    "BrickTruth", "look_at", "camera_over", "render", "render_chessboard", "render_charuco",
    "ground_texture", "brick_mesh_for", "apply_effects",
]

Texture = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray | None]]

PAPER_WHITE = (235.0, 235.0, 235.0)
INK_BLACK = (22.0, 22.0, 22.0)
CONCRETE = (150.0, 152.0, 155.0)
SKY = (235.0, 215.0, 200.0)


# =================================================================================== poses
def look_at(eye: Sequence[float], target: Sequence[float],
            up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``camera_from_world`` of an OpenCV camera at ``eye`` looking at ``target``.

    Args:
        eye: Camera centre in the world frame, metres.
        target: Point the optical axis goes through.
        up: World direction that should appear up in the image (must not be parallel to the
            viewing direction).
    """
    eye = np.asarray(eye, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(r) < 1e-9:
        raise ValueError("look_at: 'up' is parallel to the viewing direction")
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])  # rows: camera axes in world coordinates
    return transform(R, -R @ eye)


def camera_over(target: Sequence[float], distance: float, tilt_deg: float = 0.0,
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

    layout: object
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


# ============================================================================= rasteriser
@functools.lru_cache(maxsize=4)
def _sample_rays(K_bytes: bytes, dist_bytes: bytes, model: str, width: int, height: int,
                 ss: int) -> np.ndarray:
    """Normalised (x/z, y/z) of every sub-pixel sample, shape (H·ss, W·ss, 2), float64 (NaN
    where no ray of the lens reaches: a fisheye's view beyond 90° from its axis)."""
    cam = Camera(K=np.frombuffer(K_bytes).reshape(3, 3), dist=np.frombuffer(dist_bytes),
                 model=model, width=width, height=height)
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    xs = (np.arange(width)[:, None] + offs[None, :]).ravel()
    ys = (np.arange(height)[:, None] + offs[None, :]).ravel()
    gx, gy = np.meshgrid(xs, ys)
    xy = cam.normalize(np.stack([gx.ravel(), gy.ravel()], axis=1))
    out = xy.reshape(height * ss, width * ss, 2)
    out.flags.writeable = False
    return out


RENDER_BYTES_PER_SAMPLE = 136
"""Peak memory of a render per sample (rays, colour, depth, radius and the drawing's
temporaries), bytes: tracemalloc gives 133 for a 640x480 drick scene at 2x2 and 3x3 samples."""


def check_render_memory(camera: Camera, ss: int, what: str = "the camera") -> int:
    """The memory a render of ``camera`` at ``ss`` × ``ss`` samples a pixel needs, bytes;
    refused in one line before anything is allocated when it is over the work cap
    (:attr:`drovisio.errors.Limits.max_work_bytes`).

    Raises:
        InputError: naming the image size, the supersampling and what to do.
    """
    from drovisio.errors import LIMITS, InputError

    need = int(camera.width) * int(camera.height) * int(ss) ** 2 * RENDER_BYTES_PER_SAMPLE
    if need > LIMITS.max_work_bytes:
        raise InputError(
            f"{what}: rendering {camera.width}x{camera.height} pixels at {ss}x{ss} samples "
            f"each needs about {need / 2**30:.1f} GiB, more than the "
            f"{LIMITS.max_work_bytes / 2**30:.1f} GiB cap; give a smaller image size (or "
            "fewer samples; DROVISIO_MAX_WORK_MIB raises the cap)")
    return need


def check_render_work(camera: Camera, ss: int, rendered_frames: int, detected_frames: int,
                      detectors: int = 1, what: str = "the protocol") -> int:
    """The pixel samples a job needs in all: ``rendered_frames`` renders of ``camera`` at
    ``ss`` × ``ss`` samples a pixel, and ``detected_frames`` frames each read by
    ``detectors`` methods; refused in one line before anything starts when over
    :attr:`drovisio.errors.Limits.max_work_samples`. The memory of one render is checked too
    (:func:`check_render_memory`).

    Raises:
        InputError: naming the frames, the image size and what to do.
    """
    from drovisio.errors import LIMITS, InputError

    if rendered_frames:
        check_render_memory(camera, ss, what)
    px = int(camera.width) * int(camera.height)
    need = rendered_frames * px * int(ss) ** 2 + detected_frames * px * max(1, detectors)
    if need > LIMITS.max_work_samples:
        raise InputError(
            f"{what}: {rendered_frames} rendered and {detected_frames} detected frames of "
            f"{camera.width}x{camera.height} pixels ({max(1, detectors)} methods) are about "
            f"{need / 1e9:.0f} G pixel samples of work, more than the "
            f"{LIMITS.max_work_samples / 1e9:.0f} G cap; give fewer steps or frames, or a "
            "smaller image size (DROVISIO_MAX_WORK_GSAMPLES raises the cap)")
    return need


class _Canvas:
    """Colour and depth buffers at sample resolution, with polygon drawing."""

    def __init__(self, camera: Camera, ss: int, background: Sequence[float]):
        check_render_memory(camera, ss)   # before any buffer is allocated
        self.camera = camera
        self.ss = ss
        self.rays = _sample_rays(camera.K.tobytes(), camera.dist.tobytes(), camera.model,
                                 camera.width, camera.height, ss)
        H, W = self.rays.shape[:2]
        self.color = np.empty((H, W, 3), np.float32)
        self.color[:] = np.asarray(background, np.float32)
        self.depth = np.full((H, W), np.inf, np.float64)
        # Normalised radius beyond which the distortion polynomial is not trusted (projecting
        # farther points can fold back into the image): a bit beyond the image's own rays.
        r = np.hypot(self.rays[..., 0], self.rays[..., 1])
        self.max_r = float(np.nanmax(r)) * 1.2
        # the image border's rays, to find where a polygon reaching beyond max_r covers it
        ys = np.r_[np.zeros(W, int), np.full(W, H - 1), np.arange(H), np.arange(H)]
        xs = np.r_[np.arange(W), np.arange(W), np.zeros(H, int), np.full(H, W - 1)]
        ring = self.rays[ys, xs]
        ok = np.isfinite(ring[:, 0])
        self.border_xy, self.border_yx = ring[ok], np.stack([ys[ok], xs[ok]], axis=1)

    def _bbox(self, verts_c: np.ndarray) -> tuple[int, int, int, int] | None:
        """Sample-space bounding box (y0, y1, x0, x1) of a polygon in the camera frame.

        The polygon's outline in the image is made of its edges (projected where they lie
        within max_r, densely so that distorted, curved edges are enclosed) and of the parts
        of the image border it covers.
        """
        H, W = self.depth.shape
        z = verts_c[:, 2]
        if np.all(z <= 1e-6):
            return None
        if np.any(z <= 1e-6):
            return 0, H, 0, W
        p = verts_c[:, :2] / verts_c[:, 2:3]
        R = self.max_r
        pieces = []
        for k in range(len(p)):
            p0, d = p[k], p[(k + 1) % len(p)] - p[k]
            a, b, c = float(d @ d), 2 * float(p0 @ d), float(p0 @ p0) - R * R
            if a < 1e-30:
                s0, s1 = (0.0, 0.0) if c <= 0 else (1.0, 0.0)
            else:
                disc = b * b - 4 * a * c
                if disc < 0:
                    continue
                q = math.sqrt(disc)
                s0, s1 = max(0.0, (-b - q) / (2 * a)), min(1.0, (-b + q) / (2 * a))
            if s0 <= s1:
                s = np.linspace(s0, s1, 17)[:, None]
                pieces.append(p0 + s * d)
        ss = self.ss
        lo, hi = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf])  # (x, y) sample
        if pieces:
            xy = np.concatenate(pieces)
            px = self.camera.project(np.c_[xy, np.ones(len(xy))])
            lo = np.minimum(lo, (px.min(axis=0) + 0.5) * ss)
            hi = np.maximum(hi, (px.max(axis=0) + 0.5) * ss)
        if not pieces or any(np.hypot(*q) > R for q in p):
            e = np.roll(p, -1, axis=0) - p
            area = float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
            sign = 1.0 if area >= 0 else -1.0
            bx, by = self.border_xy[:, 0], self.border_xy[:, 1]
            inside = np.ones(len(bx), bool)
            for k in range(len(p)):
                inside &= sign * (e[k, 0] * (by - p[k, 1]) - e[k, 1] * (bx - p[k, 0])) >= 0
            if inside.any():
                yx = self.border_yx[inside]
                lo = np.minimum(lo, [yx[:, 1].min(), yx[:, 0].min()])
                hi = np.maximum(hi, [yx[:, 1].max() + 1, yx[:, 0].max() + 1])
        if not np.all(np.isfinite(lo)):
            return None
        x0 = max(int(math.floor(lo[0])) - 2 * ss, 0)
        x1 = min(int(math.ceil(hi[0])) + 2 * ss, W)
        y0 = max(int(math.floor(lo[1])) - 2 * ss, 0)
        y1 = min(int(math.ceil(hi[1])) + 2 * ss, H)
        if x0 >= x1 or y0 >= y1:
            return None
        return y0, y1, x0, x1

    def draw(self, origin: np.ndarray, axis_u: np.ndarray, axis_v: np.ndarray,
             poly_uv: np.ndarray, texture: Texture, shade: float, decal: bool = False,
             cull: bool = True) -> None:
        """Draw a planar convex polygon.

        Args:
            origin: A point of the plane, camera frame.
            axis_u: Unit vector of the plane's u axis, camera frame.
            axis_v: Unit vector of the plane's v axis (⊥ u), camera frame.
            poly_uv: (n, 2) convex polygon in (u, v), counter-clockwise about u × v.
            texture: (u, v) arrays → (bgr (N, 3), mask (N,) or None for opaque).
            shade: Light factor applied to the texture.
            decal: Printed on a face drawn before: wins depth ties with it.
            cull: Skip the polygon when seen from behind (u × v away from the camera).
        """
        normal = np.cross(axis_u, axis_v)
        if cull and float(np.dot(normal, origin)) >= 0.0:
            return
        verts = origin + poly_uv[:, :1] * axis_u + poly_uv[:, 1:2] * axis_v
        box = self._bbox(verts)
        if box is None:
            return
        y0, y1, x0, x1 = box
        rx = self.rays[y0:y1, x0:x1, 0]
        ry = self.rays[y0:y1, x0:x1, 1]
        if np.all(verts[:, 2] > 1e-6):
            # In front of the camera, a convex polygon projects to a convex polygon of
            # normalised coordinates (the distortion is in the rays already): test samples
            # against its edges there, and intersect only the samples inside with the plane.
            p = verts[:, :2] / verts[:, 2:3]
            e = np.roll(p, -1, axis=0) - p
            area = float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
            if abs(area) < 1e-15:
                return  # seen edge-on
            sign = 1.0 if area > 0 else -1.0
            inside = np.ones(rx.shape, bool)
            for k in range(len(p)):
                inside &= sign * (e[k, 0] * (ry - p[k, 1]) - e[k, 1] * (rx - p[k, 0])) >= 0
            iy, ix = np.nonzero(inside)
            if iy.size == 0:
                return
            sx, sy = rx[iy, ix], ry[iy, ix]
        else:  # crosses the camera plane: work in the polygon's plane (slower, rare)
            iy, ix = np.nonzero(np.ones(rx.shape, bool))
            sx, sy = rx.ravel(), ry.ravel()
        denom = sx * normal[0] + sy * normal[1] + normal[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = float(np.dot(normal, origin)) / denom  # depth z of the hit (ray z = 1)
        zb = self.depth[y0:y1, x0:x1]
        zcur = zb[iy, ix]
        ok = np.isfinite(t) & (t > 1e-6) & ((t < zcur * (1 + 1e-6)) if decal else (t < zcur))
        dx, dy, dz = sx * t - origin[0], sy * t - origin[1], t - origin[2]
        u = dx * axis_u[0] + dy * axis_u[1] + dz * axis_u[2]
        v = dx * axis_v[0] + dy * axis_v[1] + dz * axis_v[2]
        if not np.all(verts[:, 2] > 1e-6):
            ep = np.roll(poly_uv, -1, axis=0) - poly_uv
            for k in range(len(poly_uv)):  # inside all half-planes of a CCW convex polygon
                ok &= ep[k, 0] * (v - poly_uv[k, 1]) - ep[k, 1] * (u - poly_uv[k, 0]) >= 0
        if not ok.any():
            return
        iy, ix, t, u, v = iy[ok], ix[ok], t[ok], u[ok], v[ok]
        bgr, mask = texture(u, v)
        if mask is not None:
            iy, ix, t, bgr = iy[mask], ix[mask], t[mask], bgr[mask]
            if iy.size == 0:
                return
        self.color[y0:y1, x0:x1][iy, ix] = bgr * shade
        zb[iy, ix] = t

    def draw_world_plane_full(self, camera_from_plane: np.ndarray, texture: Texture,
                              shade: float) -> None:
        """Draw an unbounded plane (the ground: the plane's z = 0) over the whole image."""
        R, o = camera_from_plane[:3, :3], camera_from_plane[:3, 3]
        normal = R[:, 2]
        if float(np.dot(normal, o)) >= 0.0:
            return  # camera below the ground
        rx, ry = self.rays[..., 0], self.rays[..., 1]
        denom = rx * normal[0] + ry * normal[1] + normal[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = float(np.dot(normal, o)) / denom
        ok = np.isfinite(t) & (t > 1e-6) & (t < self.depth)
        dx, dy, dz = rx * t - o[0], ry * t - o[1], t - o[2]
        u = dx * R[0, 0] + dy * R[1, 0] + dz * R[2, 0]
        v = dx * R[0, 1] + dy * R[1, 1] + dz * R[2, 1]
        bgr, _ = texture(u[ok], v[ok])
        self.color[ok] = bgr * shade
        self.depth[ok] = t[ok]

    def resolve(self) -> np.ndarray:
        """Box-filter the samples down to pixels (float32 BGR)."""
        H, W = self.depth.shape
        ss = self.ss
        return self.color.reshape(H // ss, ss, W // ss, ss, 3).mean(axis=(1, 3))


# ================================================================================ textures
def _solid(bgr: Sequence[float]) -> Texture:
    c = np.asarray(bgr, np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        return np.broadcast_to(c, (u.size, 3)), None
    return tex


def _code_texture(bits: np.ndarray, size: float) -> Texture:
    """An ArUco code: ``bits`` (cells × cells, 0 = black) over [0, size]², paper outside."""
    cells = bits.shape[0]
    pal = np.array([INK_BLACK, PAPER_WHITE], np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        col = np.floor(u / size * cells).astype(np.int64)
        row = np.floor(v / size * cells).astype(np.int64)
        inside = (col >= 0) & (col < cells) & (row >= 0) & (row < cells)
        val = np.ones(u.size, np.int64)
        val[inside] = bits[row[inside], col[inside]]
        return pal[val], None
    return tex


def _disc_texture(radius: float, bgr: Sequence[float]) -> Texture:
    c = np.asarray(bgr, np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        return np.broadcast_to(c, (u.size, 3)), (u * u + v * v) <= radius * radius
    return tex


def _checker_texture(square: float) -> Texture:
    pal = np.array([INK_BLACK, PAPER_WHITE], np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        # u, v measured from the first inner corner; square (0, 0) is the one at +u, +v of it
        parity = (np.floor(u / square).astype(np.int64) + np.floor(v / square).astype(np.int64))
        return pal[(parity & 1)], None  # (0,0) square black: corner (0,0) has black at +u+v
    return tex


def _inside_board(board: Board) -> Texture:
    sq = board.square
    checker = _checker_texture(sq)
    white = np.asarray(PAPER_WHITE, np.float32)

    def tex(u: np.ndarray, v: np.ndarray):
        bgr, _ = checker(u, v)
        bgr = np.array(bgr)
        outside = (u < -sq) | (u > board.cols * sq) | (v < -sq) | (v > board.rows * sq)
        bgr[outside] = white
        return bgr, None
    return tex


@functools.lru_cache(maxsize=8)
def ground_texture(kind: str, seed: int, size: int = 1024) -> np.ndarray:
    """A procedural, tileable ground texture (BGR float32, ``size``²).

    Kinds: ``concrete`` (grey, mottled), ``gravel`` (pebbles), ``grass`` (green blades),
    ``clutter`` (a photo-like mess: coloured shapes including red and blue objects, black and
    white blocks that look like codes, text, lines), ``plain`` (uniform grey).
    """
    rng = np.random.default_rng(seed)

    def noise(scale: int, amp: float) -> np.ndarray:
        small = rng.normal(0, 1, (size // scale, size // scale)).astype(np.float32)
        big = cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
        return amp * big

    if kind == "plain":
        return np.full((size, size, 3), CONCRETE, np.float32)
    if kind == "concrete":
        g = 140 + noise(64, 10) + noise(8, 6) + rng.normal(0, 4, (size, size)).astype(np.float32)
        img = np.stack([g, g + 2, g + 5], axis=2)
    elif kind == "gravel":
        img = np.full((size, size, 3), 110, np.float32) + noise(16, 10)[..., None]
        for _ in range(size * size // 90):
            c = (int(rng.integers(0, size)), int(rng.integers(0, size)))
            ax = (int(rng.integers(2, 9)), int(rng.integers(2, 7)))
            tone = float(rng.uniform(60, 200))
            col = (tone * rng.uniform(0.85, 1.0), tone * rng.uniform(0.9, 1.05), tone)
            cv2.ellipse(img, c, ax, float(rng.uniform(0, 180)), 0, 360, col, -1,
                        lineType=cv2.LINE_AA)
        img += rng.normal(0, 6, img.shape).astype(np.float32)
    elif kind == "grass":
        img = np.zeros((size, size, 3), np.float32)
        img[:] = (40, 95, 60)
        img += noise(32, 12)[..., None]
        for _ in range(size * size // 60):
            x, y = int(rng.integers(0, size)), int(rng.integers(0, size))
            ang = rng.uniform(0, 2 * math.pi)
            ln = rng.uniform(4, 14)
            g = float(rng.uniform(70, 170))
            col = (g * 0.35, g, g * 0.55)
            cv2.line(img, (x, y), (int(x + ln * math.cos(ang)), int(y + ln * math.sin(ang))),
                     col, 1, lineType=cv2.LINE_AA)
        img += rng.normal(0, 5, img.shape).astype(np.float32)
    elif kind == "clutter":
        img = np.clip(ground_texture("concrete", seed + 1, size), 0, 255).astype(np.uint8)
        for _ in range(140):
            shape = rng.integers(0, 6)
            col = tuple(float(c) for c in rng.uniform(0, 255, 3))
            if rng.random() < 0.25:  # strong reds and blues: cups, tarpaulins, tape
                col = (40.0, 35.0, 200.0) if rng.random() < 0.5 else (190.0, 110.0, 30.0)
            x, y = int(rng.integers(0, size)), int(rng.integers(0, size))
            s = int(rng.integers(6, 60))
            if shape == 0:
                cv2.circle(img, (x, y), s // 2, col, -1, lineType=cv2.LINE_AA)
            elif shape == 1:
                cv2.rectangle(img, (x, y), (x + s, y + int(s * rng.uniform(0.3, 1.5))), col, -1)
            elif shape == 2:
                cv2.line(img, (x, y), (x + int(rng.integers(-80, 80)), y + int(
                    rng.integers(-80, 80))), col, int(rng.integers(1, 5)), lineType=cv2.LINE_AA)
            elif shape == 3:  # code-like black and white blocks: detector decoys
                n = int(rng.integers(4, 8))
                cell = max(2, s // n)
                blk = (rng.random((n, n)) < 0.5).astype(np.float32) * 210 + 20
                blk[0, :] = blk[-1, :] = blk[:, 0] = blk[:, -1] = 20
                patch = cv2.resize(blk, (n * cell, n * cell), interpolation=cv2.INTER_NEAREST)
                ye, xe = min(size, y + n * cell), min(size, x + n * cell)
                img[y:ye, x:xe] = patch[: ye - y, : xe - x, None].astype(np.uint8)
            elif shape == 4:
                cv2.putText(img, "".join(rng.choice(list("ABCDEFGH0123456789"), 4)), (x, y),
                            cv2.FONT_HERSHEY_SIMPLEX, float(rng.uniform(0.5, 2.0)), col,
                            int(rng.integers(1, 4)), cv2.LINE_AA)
            else:
                pts = rng.integers(-s, s, (5, 2)) + [x, y]
                cv2.fillConvexPoly(img, cv2.convexHull(pts.astype(np.int32)), col,
                                   lineType=cv2.LINE_AA)
        img = img.astype(np.float32) + rng.normal(0, 3, img.shape).astype(np.float32)
    else:
        raise ValueError(f"unknown ground kind {kind!r}; use concrete, gravel, grass, clutter "
                         "or plain")
    # Make it tile without seams: blend with itself shifted by half a tile, weighting the
    # shifted copy fully at the tile's borders (where it is continuous across the wrap).
    ramp = np.sin(np.pi * (np.arange(size) + 0.5) / size) ** 2
    w = (ramp[:, None] * ramp[None, :])[..., None].astype(np.float32)
    img = np.asarray(img, np.float32)
    img = w * img + (1 - w) * np.roll(img, (size // 2, size // 2), axis=(0, 1))
    out = np.clip(img, 0, 255).astype(np.float32)
    out.flags.writeable = False
    return out


def _ground_sampler(ground: Ground) -> Texture:
    tex = ground_texture(ground.kind, ground.seed)
    n = tex.shape[0]
    scale = 1.0 / ground.metres_per_texel

    def sample(u: np.ndarray, v: np.ndarray):
        # bilinear, tiled; remap wants 2-D maps narrower than SHRT_MAX: fold into rows
        width = 2048
        rows = -(-u.size // width)
        pad = rows * width - u.size
        mx = np.pad(np.mod(u * scale, n), (0, pad)).astype(np.float32).reshape(rows, width)
        my = np.pad(np.mod(v * scale, n), (0, pad)).astype(np.float32).reshape(rows, width)
        out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return out.reshape(-1, 3)[: u.size], None
    return sample


# ================================================================================ geometry
def _shade(normal_world: np.ndarray, light_dir: np.ndarray, ambient: float) -> float:
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


def _draw_mesh(canvas: _Canvas, mesh, camera_from_object: np.ndarray,
               world_from_object: np.ndarray, bgr, scene: Scene) -> None:
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    R, t = camera_from_object[:3, :3], camera_from_object[:3, 3]
    Vc = V @ R.T + t
    light = np.asarray(scene.light_dir, float)
    light = light / np.linalg.norm(light)
    Rw = world_from_object[:3, :3]
    tex = _solid(bgr)
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
        shade = _shade(Rw @ (R.T @ n), light, scene.ambient)
        canvas.draw(a, u, v, poly, tex, shade)


def brick_mesh_for(layout) -> object:
    """The mesh a layout's brick is drawn with: its ``mesh`` file if it has one, else a box
    of its ``dimensions`` whose top face is z = 0 (metres)."""
    import trimesh

    mesh_path = getattr(layout, "mesh_path", None)
    path = mesh_path() if callable(mesh_path) else None
    scale = float(getattr(layout, "scale_to_m", 1.0))
    if path is not None and path.exists():
        mesh = trimesh.load(path, force="mesh")
        mesh = mesh.copy()
        mesh.apply_scale(scale)
        return mesh
    dims = np.asarray(layout.dimensions_m, float)
    box = trimesh.creation.box(extents=dims)
    box.apply_translation([0, 0, -dims[2] / 2])
    return box


def _paint_for(layout, color_name: str) -> tuple[float, float, float]:
    entry = layout.palette()[color_name]
    return tuple(float(c) for c in entry.display_bgr())


def _brick_truth(brick: BrickInstance, camera: Camera, camera_from_brick: np.ndarray
                 ) -> BrickTruth:
    lay = brick.layout
    ids, corners_px = [], {}
    for slot, corners in lay.code_corners_m().items():
        mid = lay.marker_id(brick.instance, slot)
        ids.append(mid)
        corners_px[mid] = camera.project_from(corners, camera_from_brick)
    dots = lay.dot_centers_m()
    dots_px = camera.project_from(dots, camera_from_brick) if len(dots) else np.zeros((0, 2))
    return BrickTruth(layout=lay.name, instance=brick.instance if ids else None,
                      camera_from_brick=camera_from_brick, code_ids=sorted(ids),
                      code_corners_px=corners_px, dot_centers_px=dots_px)


def _draw_brick(canvas: _Canvas, brick: BrickInstance, camera_from_world: np.ndarray,
                scene: Scene) -> None:
    lay = brick.layout
    cfb = camera_from_world @ brick.world_from_brick
    _draw_mesh(canvas, brick_mesh_for(lay), cfb, brick.world_from_brick, brick.body_bgr, scene)
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
            bits = aruco_code_bits(m.dictionary, lay.marker_id(brick.instance, m.id))
            margin = 0.035 * size  # white paper around the black border
            # draw() wants axes with u × v = the printed side's normal and a CCW polygon,
            # so use v' = -v (up the printed image) and flip back in the texture lookup
            tex = _code_texture(bits, size)
            poly = np.array([[-margin, -size - margin], [size + margin, -size - margin],
                             [size + margin, margin], [-margin, margin]])
            shade = _shade(Rw @ (-n_b), light, scene.ambient)
            canvas.draw(R @ c[0] + t, R @ u_b, -(R @ v_b), poly,
                        lambda uu, vv, tx=tex: tx(uu, -vv), shade, decal=True)
        elif m.kind == "dot":
            k = n_dot - 1
            normal = dot_normals[k]
            r = float(dot_diameters[k]) / 2
            ub, vb = _plane_axes(normal)
            poly = np.array([[-r, -r], [r, -r], [r, r], [-r, r]]) * 1.01
            shade = _shade(Rw @ normal, light, scene.ambient)
            canvas.draw(R @ dot_centers[k] + t, R @ ub, R @ vb, poly,
                        _disc_texture(r, _paint_for(lay, dot_colors[k])), shade, decal=True)


def _draw_board(canvas: _Canvas, board: Board, camera_from_world: np.ndarray,
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
    shade = _shade(board.world_from_board[:3, :3] @ np.array([0, 0, -1.0]), light, scene.ambient)
    canvas.draw(t, R[:, 0], R[:, 1], poly, _inside_board(board), max(shade, 0.85), cull=False)


# ================================================================================ render
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
    canvas = _Canvas(cam, ss, scene.background_bgr)
    cfw = np.asarray(scene.camera_from_world, np.float64)
    light = np.asarray(scene.light_dir, float)
    light /= np.linalg.norm(light)
    if scene.ground is not None:
        canvas.draw_world_plane_full(cfw, _ground_sampler(scene.ground),
                                     _shade(np.array([0, 0, 1.0]), light, scene.ambient))
    for prop in scene.props:
        _draw_mesh(canvas, prop.mesh, cfw @ prop.world_from_object, prop.world_from_object,
                   prop.bgr, scene)
    for board in scene.boards:
        _draw_board(canvas, board, cfw, scene)
    truths = []
    for brick in scene.bricks:
        _draw_brick(canvas, brick, cfw, scene)
        truths.append(_brick_truth(brick, cam, cfw @ brick.world_from_brick))
    image = apply_effects(canvas.resolve(), effects or Effects())
    return RenderResult(image=image, bricks=truths, camera_from_world=cfw)


def apply_effects(img: np.ndarray, fx: Effects) -> np.ndarray:
    """Blur, motion blur, lighting, noise and JPEG on a float BGR image → uint8."""
    out = np.asarray(img, np.float32)
    if fx.blur_sigma_px > 0:
        out = cv2.GaussianBlur(out, (0, 0), fx.blur_sigma_px)
    if fx.motion_px > 0:
        L = fx.motion_px
        n = int(math.ceil(L)) | 1
        k = np.zeros((n * 4 + 1, n * 4 + 1), np.float32)
        c = n * 2
        a = math.radians(fx.motion_angle_deg)
        for s in np.linspace(-L / 2, L / 2, int(L * 8) + 1):
            x, y = c + s * math.cos(a), c + s * math.sin(a)
            x0, y0 = int(math.floor(x)), int(math.floor(y))
            wx, wy = x - x0, y - y0
            k[y0, x0] += (1 - wx) * (1 - wy)
            k[y0, x0 + 1] += wx * (1 - wy)
            k[y0 + 1, x0] += (1 - wx) * wy
            k[y0 + 1, x0 + 1] += wx * wy
        out = cv2.filter2D(out, -1, k / k.sum())
    if fx.gain != 1.0 or fx.gamma != 1.0:
        out = 255.0 * np.power(np.clip(out * fx.gain / 255.0, 0, 1), fx.gamma)
    if fx.noise_sigma > 0:
        rng = np.random.default_rng(fx.seed)
        out = out + rng.normal(0, fx.noise_sigma, out.shape).astype(np.float32)
    u8 = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    if fx.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, int(fx.jpeg_quality)])
        u8 = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return u8


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
    canvas = _Canvas(camera, ss, scene.background_bgr)
    if ground is not None:
        behind = np.asarray(camera_from_board, float) @ transform(
            np.diag([1.0, -1.0, -1.0]), [0, 0, 3.0])
        canvas.draw_world_plane_full(behind, _ground_sampler(ground), 0.8)
    _draw_board(canvas, board, scene.camera_from_world, scene)
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
    canvas = _Canvas(camera, ss, SKY)

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
