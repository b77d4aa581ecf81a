"""Measure the camera mount from pictures: the drone stands level, a shipped code lies flat
in view (the landing pad is best). Each picture's largest unambiguous code brick gives one
``camera_from_brick``; :func:`drovisio.mount.measure_mount` turns them into tilt and roll (and
pan when the code's x axis points to the nose). Used by ``drovisio calibrate mount`` and by the
web tool's mount page.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from drovisio.errors import InputError
from drovisio.mount import MountError, measure_mount

__all__ = ["MountMeasurement", "measure_from_images"]


@dataclass
class MountMeasurement:
    """What the pictures gave.

    Attributes:
        result: :func:`drovisio.mount.measure_mount`'s answer (tilt, roll, pan or None,
            spread, n).
        lines: One line per picture in plain words (what was found in it, or why it was
            skipped).
    """

    result: dict
    lines: list[str] = field(default_factory=list)


def measure_from_images(images: Iterable[tuple[str, np.ndarray | str]], camera,
                        layouts: Sequence, aligned: bool = False) -> MountMeasurement:
    """The mount's angles from pictures of a code lying flat, the drone level.

    Args:
        images: ``(name, BGR image)`` pairs, or ``(name, why it could not be read)``.
        camera: The camera (its file's size; other sizes of the same aspect are scaled).
        layouts: Layouts to look for; only those with ArUco codes are used.
        aligned: The code's x axis points to the drone's nose (then the pan is measured).

    Raises:
        InputError: No layout has codes, or no picture showed a code lying flat.
    """
    from drovisio.detect.aruco import ArucoBrickDetector

    coded = [lay for lay in layouts if lay.has_codes]
    if not coded:
        raise InputError("none of these layouts has ArUco codes; measuring the mount needs a "
                         "code lying flat (the shipped landing-pad.json is best)")
    det, det_camera = None, None
    poses: list[np.ndarray] = []
    lines: list[str] = []
    for name, img in images:
        if isinstance(img, str):
            lines.append(f"{name}: skipped: {img}")
            continue
        try:
            cam, _ = camera.for_image(img.shape[1], img.shape[0])
        except ValueError as e:
            lines.append(f"{name}: skipped: {e}")
            continue
        if det is None or cam is not det_camera:
            det, det_camera = ArucoBrickDetector(cam, coded), cam
        found = [p for p in det.detect(img) if not p.ambiguous]
        lines.append(f"{name}: {len(found)} code brick(s) lying flat"
                     + (f" ({', '.join(sorted({p.layout for p in found}))})" if found else ""))
        # the largest in view: its normal is the best known
        if found:
            poses.append(max(found, key=lambda p: len(p.markers)).camera_from_brick())
    if not poses:
        said = "; ".join(lines[:3]) + (f"; and {len(lines) - 3} more" if len(lines) > 3 else "")
        raise MountError("no code lying flat was found in view" + (f" ({said})" if said else "")
                         + ": put a shipped code flat on the ground in front of the drone")
    return MountMeasurement(measure_mount(poses, aligned=aligned), lines)
