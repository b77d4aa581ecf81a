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

import numpy as np

from drovisio.camera import Camera
from drovisio.errors import InputError
from drovisio.geometry import rotation_about
from drovisio.images import VIDEO_SUFFIXES, is_video_file
from drovisio.raw_frame import EndOfStream
from drovisio.sources import ImageFolderReader, VideoFileReader
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
from drovisio.textfile import missing_reason

__all__ = ["StepFrame", "step_frames", "truth_camera_from_brick"]


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


def _recorded_reader(src: Path, step: Step) -> ImageFolderReader | VideoFileReader:
    """The reader of a recorded step's source, chosen before anything is opened: a folder
    of images or a video file; anything else (a text file, a device) is refused."""
    why = missing_reason(src)
    if why:
        raise InputError(f"{src}: source: {why} (step {step.label})")
    if src.is_dir():
        return ImageFolderReader(src)
    if src.is_file() and is_video_file(src):
        return VideoFileReader(src)
    raise InputError(f"{src}: source: not a video ({', '.join(sorted(VIDEO_SUFFIXES))}) nor a "
                     f"folder of images; give the recording of step {step.label}")


def _recorded(step: Step, base: Path, camera: Camera) -> Iterator[StepFrame]:
    src = Path(step.source or "")
    src = src if src.is_absolute() else base / src
    if step.value is None:
        raise InputError(f"{src}: value: no truth for this recording (give the {step.vary} "
                         "measured on the bench)")
    truth = truth_camera_from_brick(step)
    reader = _recorded_reader(src, step)
    try:
        reader.open()
    except OSError as e:   # the reader's own one line, naming the file
        raise InputError(str(e)) from None
    try:
        if isinstance(reader, ImageFolderReader) and len(reader.files) < step.frames:
            raise InputError(f"{src}: {len(reader.files)} image(s), the step asks for frames: "
                             f"{step.frames} (lower 'frames' or add pictures)")
        for got in range(step.frames):
            try:
                fr = reader.read()
            except EndOfStream:
                fr = None
            if fr is None:
                raise InputError(f"{src}: the video has {got} frame(s), the step asks for "
                                 f"frames: {step.frames} (lower 'frames' or record longer)")
            name = fr.name or f"{src.name}#{fr.index}"
            where = src / fr.name if fr.name else src
            if fr.image is None:
                raise InputError(f"{where}: {fr.error or 'cannot be decoded'}")
            h, w = fr.image.shape[:2]
            if (w, h) != (camera.width, camera.height):
                # every method's detector is made for the study's camera, at its size
                raise InputError(f"{where}: the frame is {w}x{h} but the study's camera is "
                                 f"for {camera.width}x{camera.height}; record at that size, "
                                 "or give the protocol the recording camera's file (camera:)")
            yield StepFrame(fr.image, truth, name)
    finally:
        reader.close()


def step_frames(step: Step, layout, camera, seed: int, base: Path, ss: int = 2
                ) -> Iterator[StepFrame]:
    """The frames of ``step``: recorded when it names a source, else rendered."""
    if step.source is not None:
        return _recorded(step, base, camera)
    return _rendered(step, layout, camera, seed, ss)
