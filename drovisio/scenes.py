"""Random drick scenes for evaluation: bricks on the ground seen by a drone camera.

One function, :func:`random_scene`, draws a scene like the ones the detectors are judged on
(DESIGN.md): 640×480, 60° lens with distortion, 0.4–2 m, camera tilt up to
40°, gravel, grass or photo clutter on the ground, blur, noise and JPEG. Everything is drawn
from a seed, so a test or a benchmark names its data by (spec, seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from drovisio.camera import Camera
from drovisio.synth import (
    BrickInstance,
    Effects,
    Ground,
    Prop,
    RenderResult,
    Scene,
    brick_mesh_for,
    camera_over,
    render,
    rot_z,
    transform,
)

__all__ = ["SceneSpec", "gravity_in_camera", "level_drone_over_code", "random_scene",
           "render_random"]


@dataclass
class SceneSpec:
    """How to draw a random scene (ranges are uniform, inclusive)."""

    layouts: list = field(default_factory=list)
    """Layouts the bricks are drawn from, in turn (brick i uses layouts[i % len])."""
    n_bricks: int = 4
    """Bricks in the scene (0 for a scene of ground and clutter only)."""
    distance: tuple[float, float] = (0.4, 2.0)
    """Camera to scene-centre distance, metres."""
    tilt_deg: tuple[float, float] = (0.0, 40.0)
    """Angle of the optical axis from straight down."""
    grounds: tuple[str, ...] = ("gravel", "grass", "clutter")
    """Ground textures to choose from."""
    spread: float = 0.6
    """Bricks are placed within ± spread · distance · 0.45 of the scene centre (so that they
    stay in view)."""
    blur_sigma_px: tuple[float, float] = (0.0, 1.0)
    motion_px: tuple[float, float] = (0.0, 1.5)
    noise_sigma: tuple[float, float] = (1.0, 4.0)
    jpeg_quality: tuple[int, int] = (75, 95)
    gain: tuple[float, float] = (0.8, 1.2)
    gamma: tuple[float, float] = (0.9, 1.1)
    stack_prob: float = 0.0
    """Chance that a brick carries a plain brick across part of its top (hides markers)."""
    props: int = 0
    """Coloured clutter objects on the ground (red cups, blue tarpaulins, boxes)."""
    instances: int = 15
    """Instance numbers are drawn from range(instances) (capped by each layout's block)."""


def gravity_in_camera(camera_from_world: np.ndarray) -> np.ndarray:
    """Unit vector of gravity (world −z) in the camera frame."""
    return np.asarray(camera_from_world)[:3, :3] @ np.array([0.0, 0.0, -1.0])


def _u(rng: np.random.Generator, rng_pair) -> float:
    lo, hi = rng_pair
    return float(rng.uniform(lo, hi)) if hi > lo else float(lo)


def _props(rng: np.random.Generator, n: int, radius: float) -> list[Prop]:
    import trimesh  # heavy: loaded only when a scene has props

    out = []
    bgr: tuple[float, float, float]
    for _ in range(n):
        kind = rng.integers(0, 3)
        x, y = rng.uniform(-radius, radius, 2)
        yaw = rng.uniform(0, 2 * math.pi)
        if kind == 0:  # a red cup
            mesh = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=24)
            mesh.apply_translation([0, 0, 0.05])
            bgr = (35.0, 30.0, 200.0)
        elif kind == 1:  # a blue tarpaulin, flat on the ground
            mesh = trimesh.creation.box(extents=[rng.uniform(0.3, 0.8), rng.uniform(0.2, 0.6),
                                                 0.004])
            mesh.apply_translation([0, 0, 0.002])
            bgr = (170.0, 95.0, 25.0)
        else:  # a box of some colour
            mesh = trimesh.creation.box(extents=rng.uniform(0.05, 0.2, 3))
            mesh.apply_translation([0, 0, mesh.extents[2] / 2])
            b, g, r = (float(c) for c in rng.uniform(20, 235, 3))
            bgr = (b, g, r)
        out.append(Prop(mesh=mesh, world_from_object=transform(rot_z(yaw), [x, y, 0.0]),
                        bgr=bgr))
    return out


def random_scene(seed: int, spec: SceneSpec, camera: Camera | None = None
                 ) -> tuple[Scene, Effects]:
    """Draw a scene and its image effects from ``seed``.

    Bricks lie flat on the ground (z = 0 under their body), at random yaw, without
    overlapping; instance numbers are distinct per layout.

    Args:
        seed: Seed of everything random in the scene.
        spec: What to draw.
        camera: The camera; the thesis's 60° drone webcam by default.

    Returns:
        The scene and the effects to render it with.
    """
    rng = np.random.default_rng(seed)
    cam = camera or Camera.drone_webcam()
    dist = _u(rng, spec.distance)
    tilt = _u(rng, spec.tilt_deg)
    heading = float(rng.uniform(0, 360))
    # the scene centre is where the optical axis meets the ground
    radius = spec.spread * dist * 0.45 * (1 - 0.4 * tilt / 90)
    bricks: list[BrickInstance] = []
    placed: list[tuple[float, float, float]] = []
    used: dict[str, set[int]] = {}
    for i in range(spec.n_bricks):
        layout = spec.layouts[i % len(spec.layouts)]
        dims = layout.dimensions_m
        r_brick = 0.5 * math.hypot(dims[0], dims[1])
        for _attempt in range(200):
            x, y = rng.uniform(-radius, radius, 2)
            if all(math.hypot(x - px, y - py) > r_brick + pr + 0.02 for px, py, pr in placed):
                break
        else:
            continue  # no room left: fewer bricks
        placed.append((x, y, r_brick))
        yaw = float(rng.uniform(-math.pi, math.pi))
        instance = None
        if layout.has_codes:
            free = [k for k in range(min(spec.instances, layout.instances))
                    if k not in used.setdefault(layout.name, set())]
            instance = int(rng.choice(free))
            used[layout.name].add(instance)
        body_h = _body_height(layout)
        body = rng.uniform(140, 190) * np.array([0.98, 1.0, 1.02])
        bricks.append(BrickInstance(layout=layout, instance=instance,
                                    world_from_brick=transform(rot_z(yaw), [x, y, body_h]),
                                    body_bgr=(float(body[0]), float(body[1]), float(body[2]))))
    props = _props(rng, spec.props, radius * 1.6)
    if spec.stack_prob > 0:
        props += _stacked(rng, bricks, spec.stack_prob)
    scene = Scene(camera=cam, camera_from_world=camera_over(
        [0.0, 0.0, 0.0], dist, tilt, heading, roll_deg=float(rng.uniform(-10, 10))),
        ground=Ground(kind=str(rng.choice(spec.grounds)), seed=int(rng.integers(0, 4))),
        bricks=bricks, props=props,
        light_dir=(float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)), 1.0))
    fx = Effects(blur_sigma_px=_u(rng, spec.blur_sigma_px), motion_px=_u(rng, spec.motion_px),
                 motion_angle_deg=float(rng.uniform(0, 180)), gain=_u(rng, spec.gain),
                 gamma=_u(rng, spec.gamma), noise_sigma=_u(rng, spec.noise_sigma),
                 jpeg_quality=int(round(_u(rng, spec.jpeg_quality))), seed=seed)
    return scene, fx


def _body_height(layout) -> float:
    """Height of the brick's top face (the layout origin) above its lowest point."""
    return float(-brick_mesh_for(layout).bounds[0][2])


def _stacked(rng: np.random.Generator, bricks: list[BrickInstance], prob: float) -> list[Prop]:
    """Plain bricks laid across part of some bricks' tops, as in a wall's next course."""
    import trimesh  # heavy: loaded only when bricks are stacked

    out = []
    for b in bricks:
        if rng.random() >= prob:
            continue
        dims = b.layout.dimensions_m
        mesh = trimesh.creation.box(extents=[dims[0], dims[1], 0.10])
        # shifted along the brick's length so that one end (and its markers) stays visible
        shift = float(rng.choice([-1, 1])) * dims[0] * rng.uniform(0.45, 0.6)
        mesh.apply_translation([shift, 0, 0.02 + 0.05])
        out.append(Prop(mesh=mesh, world_from_object=b.world_from_brick.copy(),
                        bgr=(150.0, 152.0, 156.0)))
    return out


def render_random(seed: int, spec: SceneSpec, camera: Camera | None = None,
                  ss: int = 3) -> RenderResult:
    """:func:`random_scene` then :func:`drovisio.synth.render`."""
    scene, fx = random_scene(seed, spec, camera)
    return render(scene, fx, ss=ss)


def level_drone_over_code(body_from_camera: np.ndarray, layout, heading_deg: float,
                          brick_yaw_deg: float, height_m: float = 1.0, seed: int = 0,
                          camera: Camera | None = None) -> RenderResult:
    """The drone standing level, its body origin ``height_m`` above the ground and heading
    ``heading_deg``; a brick of ``layout`` lying flat where the optical axis meets the ground,
    turned ``brick_yaw_deg`` from the nose (0: its x axis toward the nose). What measuring the
    mount sees (:mod:`drovisio.calibration.mount`).

    Args:
        body_from_camera: The mount (4×4, body FRD from OpenCV camera).
        camera: The camera (default: the drone webcam).
    """
    h = np.radians(heading_deg)
    world_from_body = transform(rot_z(h) @ np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, height_m])
    world_from_camera = world_from_body @ np.asarray(body_from_camera, np.float64)
    axis = world_from_camera[:3, 2]
    c = world_from_camera[:3, 3]
    hit = c + axis * (-c[2] / axis[2])
    brick = BrickInstance(layout=layout, instance=0, world_from_brick=transform(
        rot_z(h + np.radians(brick_yaw_deg)), [hit[0], hit[1], 0.01]))
    scene = Scene(camera=camera or Camera.drone_webcam(),
                  camera_from_world=np.linalg.inv(world_from_camera),
                  ground=Ground(kind="gravel", seed=seed), bricks=[brick])
    return render(scene, ss=3)
