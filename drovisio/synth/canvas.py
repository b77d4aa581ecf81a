"""The ray caster: colour and depth buffers at sample resolution, and planar polygons drawn
into them through the camera's lens model.

Every sub-pixel sample's viewing ray is found by undistorting its pixel position through the
camera's lens model (samples more than 90° off a fisheye's axis see the background) and is
intersected with the polygon's plane, so geometry is exact under distortion. Samples sit
``ss × ss`` a pixel, symmetric about the pixel centre; :meth:`Canvas.resolve` box-filters them
down to pixels.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np

from drovisio.camera import Camera, LensModel
from drovisio.errors import LIMITS, InputError
from drovisio.synth.textures import Texture

__all__ = ["RENDER_BYTES_PER_SAMPLE", "check_render_memory", "check_render_work", "Canvas"]


@functools.lru_cache(maxsize=4)
def _sample_rays(K_bytes: bytes, dist_bytes: bytes, model: LensModel, width: int, height: int,
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


def _edges_within(p: np.ndarray, R: float) -> list[np.ndarray]:
    """The parts of a polygon's edges (``p``: (n, 2) normalised image coordinates) within
    radius ``R``, each sampled at 17 points."""
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
    return pieces


class Canvas:
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
        pieces = _edges_within(p, R)
        ss = self.ss
        lo, hi = np.array([np.inf, np.inf]), np.array([-np.inf, -np.inf])  # (x, y) sample
        if pieces:
            xy = np.concatenate(pieces)
            px = self.camera.project(np.c_[xy, np.ones(len(xy))])
            lo = np.minimum(lo, (px.min(axis=0) + 0.5) * ss)
            hi = np.maximum(hi, (px.max(axis=0) + 0.5) * ss)
        if not pieces or any(np.hypot(*q) > R for q in p):
            lo, hi = self._border_covered(p, lo, hi)
        if not np.all(np.isfinite(lo)):
            return None
        x0 = max(int(math.floor(lo[0])) - 2 * ss, 0)
        x1 = min(int(math.ceil(hi[0])) + 2 * ss, W)
        y0 = max(int(math.floor(lo[1])) - 2 * ss, 0)
        y1 = min(int(math.ceil(hi[1])) + 2 * ss, H)
        if x0 >= x1 or y0 >= y1:
            return None
        return y0, y1, x0, x1

    def _border_covered(self, p: np.ndarray, lo: np.ndarray, hi: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
        """``lo``, ``hi`` (x, y sample) grown over the image border's samples the polygon
        ``p`` (n, 2 normalised) covers."""
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
        return lo, hi

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

