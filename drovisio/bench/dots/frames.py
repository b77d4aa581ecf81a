"""The dot benchmark's frames: rendered scenes with their truth per dot (visible, size),
cached on disk (PNG + truth JSON), and the timing part's grid of bricks."""

from __future__ import annotations

import hashlib
import math
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drovisio.bench.cache import read_entry, write_entry
from drovisio.camera import Camera
from drovisio.detect.dots.model import DotModel, occluded_dots
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.scenes import SceneSpec, gravity_in_camera, random_scene
from drovisio.synth import (
    BrickInstance,
    Effects,
    Ground,
    Scene,
    brick_mesh_for,
    camera_over,
    render,
    rot_z,
    transform,
)


@dataclass
class DotTruth:
    layout: str
    camera_from_brick: list
    centers_px: list
    visible: list
    size_px: list


@dataclass
class Frame:
    image: np.ndarray
    gravity: np.ndarray
    bricks: list[DotTruth] = field(default_factory=list)


_MODELS: dict = {}
_RIM = np.linspace(0, 2 * np.pi, 16, endpoint=False)


def _visibility(scene, result, camera) -> list[DotTruth]:
    """Per brick and dot: fully visible? projected size (equivalent diameter, px)."""
    import trimesh  # heavy: loaded only when a frame is rendered

    world_from_camera = np.linalg.inv(result.camera_from_world)
    meshes = []
    for prop in scene.props:
        m = prop.mesh.copy()
        m.apply_transform(prop.world_from_object)
        meshes.append(m)
    brick_meshes = []
    for b in scene.bricks:
        bm: Any = brick_mesh_for(b.layout)
        bm = bm.copy()
        bm.apply_transform(b.world_from_brick)
        brick_meshes.append(bm)
    out = []
    for k, (b, truth) in enumerate(zip(scene.bricks, result.bricks)):
        others = [m for j, m in enumerate(brick_meshes) if j != k] + meshes
        other: Any = trimesh.util.concatenate(others) if others else None
        cfb = truth.camera_from_brick
        vis, size = _brick_dots(b, cfb, camera, other, world_from_camera)
        out.append(DotTruth(layout=truth.layout, camera_from_brick=cfb.tolist(),
                            centers_px=np.asarray(truth.dot_centers_px).tolist(), visible=vis,
                            size_px=size))
    return out


def _dot_model(lay) -> DotModel:
    """The layout's dot model (cached by layout)."""
    model = _MODELS.get(id(lay))
    if model is None:
        colors = {c: i for i, c in enumerate(dict.fromkeys(lay.dot_colors()))}
        model = _MODELS[id(lay)] = DotModel.from_layout(lay, colors)
    return model


def _brick_dots(b, cfb: np.ndarray, camera, other: Any, world_from_camera: np.ndarray
                ) -> tuple[list[bool], list[float]]:
    """Per dot of one brick (camera_from_brick ``cfb``): fully visible (inside the image,
    painted, not hidden by its own relief or by ``other``, the scene's other meshes), and its
    projected size (equivalent diameter, px)."""
    lay = b.layout
    X = lay.dot_centers_m()
    nrm = lay.dot_normals()
    rad = lay.dot_diameters_m() / 2
    dot_marker_index = [i for i, m in enumerate(lay.markers) if m.kind == "dot"]
    own = occluded_dots(_dot_model(lay), cfb[None, :3, :3], cfb[None, :3, 3])[0]
    vis, size = [], []
    for d in range(len(X)):
        u = np.cross(nrm[d], [1.0, 0, 0] if abs(nrm[d][0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(nrm[d], u)
        rim = X[d] + rad[d] * (np.cos(_RIM)[:, None] * u + np.sin(_RIM)[:, None] * v)
        px = camera.project_from(rim, cfb)
        x, y = px[:, 0], px[:, 1]
        x1, y1 = np.roll(x, -1), np.roll(y, -1)
        area = abs(float((x * y1 - x1 * y).sum()) / 2)
        size.append(2 * math.sqrt(area / math.pi))
        ok = (dot_marker_index[d] not in b.hidden_markers) and not own[d]
        ok = ok and bool(np.all((x >= 1) & (x <= camera.width - 2) & (y >= 1)
                                & (y <= camera.height - 2)))
        Yc = rim @ cfb[:3, :3].T + cfb[:3, 3]
        ok = ok and bool(np.all(Yc[:, 2] > 0)) and float(
            -(cfb[:3, :3] @ nrm[d]) @ (cfb[:3, :3] @ X[d] + cfb[:3, 3])) > 0
        if ok and other is not None:
            ok = not _blocked(other, Yc, world_from_camera)
        vis.append(bool(ok))
    return vis, size


def _blocked(other: Any, Yc: np.ndarray, world_from_camera: np.ndarray) -> bool:
    """Whether a mesh lies between the camera and any of the rim points ``Yc`` (n, 3),
    camera frame."""
    cam_w = world_from_camera[:3, 3]
    rim_w = (world_from_camera[:3, :3] @ Yc.T).T + world_from_camera[:3, 3]
    dirs = rim_w - cam_w
    dist = np.linalg.norm(dirs, axis=1)
    dirs /= dist[:, None]
    locs, idx_ray, _ = other.ray.intersects_location(
        np.repeat(cam_w[None], len(dirs), 0), dirs, multiple_hits=False)
    if len(idx_ray):
        hit_d = np.linalg.norm(locs - cam_w, axis=1)
        return bool(np.any(hit_d < dist[idx_ray] - 1e-4))
    return False


class FrameSource:
    """Renders (or loads from the cache) frames named by (part, seed, spec)."""

    def __init__(self, layout, cache: Path | None):
        self.layout = layout
        self.camera = Camera.drone_webcam()
        self.cache = cache
        self.stale_said = False
        """A stale entry was said (the first only: the others are rendered again quietly)."""
        if cache is not None:
            cache.mkdir(parents=True, exist_ok=True)

    def get(self, key: str, seed: int, spec, hide: tuple[int, int] | None = None) -> Frame:
        tag = hashlib.sha1(repr((key, seed, _spec_repr(spec), hide, self.layout.name,
                                 "v2")).encode()).hexdigest()[:16]
        hit, png, js = self._cached(key, seed, tag)
        if hit is not None:
            return hit
        scene, fx = random_scene(seed, spec, self.camera)
        return self._render(scene, fx, png, js, seed, hide)

    def _cached(self, key: str, seed: int, tag: str):
        """(frame from the cache or None, png path, json path); paths are None without a
        cache."""

        if self.cache is None:
            return None, None, None
        stem = f"{key}-{seed}-{tag}"
        png, js = self.cache / f"{stem}.png", self.cache / f"{stem}.json"
        try:
            got = read_entry(png, js)
            if got is not None:
                img, meta = got
                return (Frame(image=img, gravity=np.array(meta["gravity"]),
                              bricks=[DotTruth(**b) for b in meta["bricks"]]), png, js)
        except (OSError, ValueError, KeyError, TypeError) as e:
            # a broken or stale entry is rendered again; said once, as bench aruco does
            if not self.stale_said:
                self.stale_said = True
                why = str(e) if isinstance(e, ValueError) else f"{js}: not an entry of this version"
                print(f"bench dots --cache: {why}; rendering the frame again (and any other "
                      "stale entry)", file=sys.stderr)
        return None, png, js

    def get_scene(self, key: str, seed: int, build) -> Frame:
        """A frame of a scene made by ``build() -> (Scene, Effects)`` (cached by key, seed)."""
        tag = hashlib.sha1(repr((key, seed, self.layout.name, "v2")).encode()).hexdigest()[:16]
        hit, png, js = self._cached(key, seed, tag)
        if hit is not None:
            return hit
        scene, fx = build()
        return self._render(scene, fx, png, js, seed, None)

    def _render(self, scene, fx, png, js, seed, hide) -> Frame:
        if hide is not None:
            rng = np.random.default_rng(seed + 99991)
            dots = [i for i, m in enumerate(self.layout.markers) if m.kind == "dot"]
            for b in scene.bricks:
                k = int(rng.integers(hide[0], hide[1] + 1))
                b.hidden_markers = frozenset(int(i) for i in rng.choice(dots, k, replace=False))
        res = render(scene, fx, ss=3)
        frame = Frame(image=res.image, gravity=gravity_in_camera(res.camera_from_world),
                      bricks=_visibility(scene, res, self.camera))
        if png is not None:
            write_entry(png, js, frame.image, {"gravity": frame.gravity.tolist(),
                                               "bricks": [asdict(b) for b in frame.bricks]})
        return frame


def _spec_repr(spec) -> str:
    d = dict(vars(spec))
    d["layouts"] = [x.name for x in spec.layouts]
    return repr(sorted(d.items()))


def bench_layout(path: str | None):
    return load_layout(path or shipped_layouts_dir() / "drick-dots-2x3.json")


def scene_spec(layout, **kw):
    base = {"layouts": [layout], "n_bricks": 3, "props": 2}
    base.update(kw)
    return SceneSpec(**base)


_GROUNDS = ("gravel", "grass", "clutter")


def timing_frames(src, args, nbricks: int, n: int) -> list[Frame]:
    """Bricks on a 5 × 4 grid seen from 1.75 m (so that 20 fit in view, dots ≈ 6–7 px): 1, 5
    or 20 of its cells filled, on gravel, grass or photo clutter; the same camera poses for
    every brick count."""

    cells = [((c - 2) * 0.40, (r - 1.5) * 0.26) for r in range(4) for c in range(5)]
    pick = {1: [7], 5: [6, 8, 11, 13, 2], 20: list(range(20))}.get(nbricks)
    if pick is None:
        pick = list(range(min(nbricks, 20)))
    frames = []
    for k in range(n):
        seed = args.seed + k

        def build(seed=seed):
            rng = np.random.default_rng(1000 + seed)
            bricks = [BrickInstance(src.layout, transform(rot_z(float(rng.uniform(-0.25, 0.25))),
                                                          [cells[c][0], cells[c][1], 0.1]),
                                    instance=None) for c in pick]
            cfw = camera_over([0.0, 0.0, 0.1], 1.75, float(rng.uniform(0, 10)),
                              float(rng.choice([0.0, 180.0])) + float(rng.uniform(-5, 5)))
            scene = Scene(camera=src.camera, camera_from_world=cfw,
                          ground=Ground(_GROUNDS[seed % 3], seed=seed % 4), bricks=bricks)
            fx = Effects(blur_sigma_px=0.5, noise_sigma=2.0, jpeg_quality=90, seed=seed)
            return scene, fx
        frames.append(src.get_scene(f"tim{nbricks}", seed, build))
    return frames
