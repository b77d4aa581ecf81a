"""The frames of a step and their truth: rendered (conditions drawn per frame) or recorded
(a video or a folder of images; the truth is the step's set-up).

Set-up (the thesis's): the camera looks straight at the brick's top face from ``distance``;
with no offset or rotation the brick's origin is on the optical axis and its x and y axes run
along the image's x and y (its top faces the camera). Offsets move the brick along the image's
x / y; rotations turn it about the camera's x, y or z axis through the brick's origin. A
recorded step must be set up the same way on the bench.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drovisio.errors import InputError
from drovisio.geometry import rotation_about
from drovisio.images import ImageError, read_image
from drovisio.study.protocol import Step
from drovisio.synth import (
    BrickInstance,
    Effects,
    Ground,
    Scene,
    brick_mesh_for,
    camera_over,
    render,
)

__all__ = ["StepFrame", "step_frames", "truth_camera_from_brick"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass
class StepFrame:
    """One frame of a step."""

    image: np.ndarray
    """BGR uint8."""
    camera_from_brick: np.ndarray
    """4×4 truth."""
    name: str
    """Where it comes from (``render seed N`` or ``FILE#frame`` / the image file)."""


def _rot(axis: np.ndarray, deg: float) -> np.ndarray:
    """Rotation by ``deg`` degrees about ``axis`` (any length)."""
    a = np.asarray(axis, np.float64)
    return rotation_about(a / np.linalg.norm(a), math.radians(deg))


def _camera_from_world(distance: float, height: float = 0.0) -> np.ndarray:
    """Straight down at the brick's origin, ``height`` above the ground, from ``distance``."""
    return camera_over((0.0, 0.0, height), distance, tilt_deg=0.0)


def _world_from_brick(step: Step, camera_from_world: np.ndarray, height: float = 0.0
                      ) -> np.ndarray:
    R_cw = camera_from_world[:3, :3]
    ax = {"x": R_cw[0], "y": R_cw[1], "z": R_cw[2]}       # camera axes in the world
    T = np.eye(4)
    T[2, 3] = height
    value = float(step.value or 0.0)
    if step.vary == "offset_x":
        T[:3, 3] += value * ax["x"]
    elif step.vary == "offset_y":
        T[:3, 3] += value * ax["y"]
    elif step.vary.startswith("rot_"):
        T[:3, :3] = _rot(ax[step.vary[-1]], value)
    return T


def truth_camera_from_brick(step: Step) -> np.ndarray:
    """The step's ``camera_from_brick`` (what a recorded step's bench set-up must be)."""
    cw = _camera_from_world(step.at_distance)
    return cw @ _world_from_brick(step, cw)


def _rendered(step: Step, layout, camera, seed: int, ss: int) -> Iterator[StepFrame]:
    # the brick stands on the ground (its body below its top face), whatever its turn; the
    # camera looks at its origin from the step's distance
    cw0 = _camera_from_world(step.at_distance)
    R = _world_from_brick(step, cw0)[:3, :3]
    height = max(0.0, -float(np.min((R @ _brick_box(layout).T)[2]))) + 1e-3
    cw = _camera_from_world(step.at_distance, height)
    wb = _world_from_brick(step, cw, height)
    for k in range(step.frames):
        rng = np.random.default_rng([seed, k])
        fx = Effects(blur_sigma_px=float(rng.uniform(0.0, 0.8)),
                     noise_sigma=float(rng.uniform(1.0, 3.0)),
                     jpeg_quality=int(rng.integers(80, 96)), gain=float(rng.uniform(0.85, 1.15)),
                     seed=int(rng.integers(1 << 30)))
        # the bench is never exact: the camera's aim wanders by a few tenths of a degree
        # (an exactly frontal square is also a degenerate case of some PnP solvers)
        jitter = np.eye(4)
        jitter[:3, :3] = _rot(rng.normal(size=3), float(rng.uniform(0.1, 0.4)))
        scene = Scene(camera=camera, camera_from_world=jitter @ cw,
                      ground=Ground(kind=("concrete", "gravel")[k % 2], seed=int(seed + k)),
                      bricks=[BrickInstance(layout=layout, world_from_brick=wb,
                                            instance=0 if layout.has_codes else None)])
        r = render(scene, fx, ss=ss)
        yield StepFrame(r.image, r.bricks[0].camera_from_brick, f"render seed {seed} #{k}")


def _brick_box(layout) -> np.ndarray:
    """The 8 corners of the brick's bounding box (brick frame, metres)."""
    mesh: Any = brick_mesh_for(layout)
    lo, hi = np.asarray(mesh.bounds, np.float64)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                     for z in (lo[2], hi[2])])


def _recorded(step: Step, base: Path) -> Iterator[StepFrame]:
    src = Path(step.source or "")
    src = src if src.is_absolute() else base / src
    if step.value is None:
        raise InputError(f"{src}: value: no truth for this recording (give the {step.vary} "
                         "measured on the bench)")
    truth = truth_camera_from_brick(step)
    if src.is_dir():
        files = sorted(p for p in src.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if len(files) < step.frames:
            raise InputError(f"{src}: {len(files)} image(s), the step asks for frames: "
                             f"{step.frames} (lower 'frames' or add pictures)")
        for f in files[: step.frames]:
            try:
                img, _ = read_image(f)
            except ImageError as e:
                raise InputError(f"{f}: {e}") from None
            yield StepFrame(img, truth, f.name)
        return
    if not src.is_file():   # a FIFO or device is no video: reading it could block
        raise InputError(f"{src}: no such video or folder, or not a regular file (source of "
                         f"step {step.label})")
    cap = cv2.VideoCapture(str(src))
    try:
        got = 0
        while got < step.frames:
            ok, img = cap.read()
            if not ok:
                raise InputError(f"{src}: the video has {got} frame(s), the step asks for "
                                 f"frames: {step.frames} (lower 'frames' or record longer)")
            yield StepFrame(img, truth, f"{src.name}#{got}")
            got += 1
    finally:
        cap.release()


def step_frames(step: Step, layout, camera, seed: int, base: Path, ss: int = 2
                ) -> Iterator[StepFrame]:
    """The frames of ``step``: recorded when it names a source, else rendered."""
    if step.source is not None:
        return _recorded(step, base)
    return _rendered(step, layout, camera, seed, ss)
