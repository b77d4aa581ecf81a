"""Measure the camera mount from pictures: the drone stands level, a shipped code lies flat
in view (the landing pad is best). Each picture's largest unambiguous code brick gives one
``camera_from_brick``; :func:`drovisio.mount.measure_mount` turns them into tilt and roll (and
pan when the code's x axis points to the nose). Used by ``drovisio calibrate mount`` and by the
web tool's mount page.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drovisio.detect.aruco import ArucoBrickDetector
from drovisio.errors import InputError
from drovisio.geometry import transform
from drovisio.mount import BODY_FROM_ALIGNED_BRICK, MountError, angles_of, measure_mount

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
    coded = [lay for lay in layouts if lay.has_codes]
    if not coded:
        raise InputError("none of these layouts has ArUco codes; measuring the mount needs a "
                         "code lying flat (the shipped landing-pad.json is best)")
    poses, names, lines = _flat_codes(images, camera, coded)
    if not poses:
        said = "; ".join(lines[:3]) + (f"; and {len(lines) - 3} more" if len(lines) > 3 else "")
        raise MountError("no code lying flat was found in view" + (f" ({said})" if said else "")
                         + ": put a shipped code flat on the ground in front of the drone")
    refused = None
    if aligned:
        refused = pan_refusal(poses, names)
    result = measure_mount(poses, aligned=aligned and refused is None)
    result["pan_refused"] = refused
    if refused:
        lines.insert(0, refused)
    return MountMeasurement(result, lines)


def _flat_codes(images: Iterable[tuple[str, np.ndarray | str]], camera: Any,
                coded: list[Any]) -> tuple[list[np.ndarray], list[str], list[str]]:
    """Per picture, the largest code brick lying flat (unambiguous) in view.

    Returns:
        (its ``camera_from_brick`` 4×4 per picture that showed one, its layout's name, one
        line per picture in plain words).
    """
    det, det_camera = None, None
    poses: list[np.ndarray] = []
    names: list[str] = []
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
            best = max(found, key=lambda p: len(p.markers))
            poses.append(best.camera_from_brick())
            names.append(best.layout)
    return poses, names, lines


#: Pan tolerance: pictures of one pad, its arrow toward the nose, agree within this (degrees).
PAN_AGREEMENT_DEG = 5.0


def is_nose_marker(layout_name: str) -> bool:
    """Layouts whose x axis is laid toward the drone's nose for measuring the pan: the
    landing pads (their arrow is printed along x). A brick lies wherever it was put."""
    return layout_name.startswith("landing-pad")


def pan_refusal(poses: Sequence[np.ndarray], layout_names: Sequence[str]) -> str | None:
    """Why the pan cannot be known from these poses, or None when it can.

    The pan is the code's heading seen from the camera: it means the camera's pan only if
    the code's x axis points to the nose. That is known of a landing pad laid with its arrow
    to the nose, never of a brick; and the pictures must agree on it.
    """
    others = sorted({n for n in layout_names if not is_nose_marker(n)})
    if others:
        return ("pan not measured: the codes seen are on " + ", ".join(others)
                + ", whose x axis need not point to the nose; lay the landing pad flat with "
                  "its arrow toward the nose (tilt and roll are measured all the same)")
    pans = [angles_of(transform(BODY_FROM_ALIGNED_BRICK @ np.asarray(T)[:3, :3].T,
                                (0.0, 0.0, 0.0)))["pan_deg"] for T in poses]
    ref = pans[0]
    off = [((p - ref + 180.0) % 360.0) - 180.0 for p in pans]
    if max(off) - min(off) > PAN_AGREEMENT_DEG:
        return (f"pan not measured: the pictures disagree on the nose's direction by "
                f"{max(off) - min(off):.0f}° (more than {PAN_AGREEMENT_DEG:g}°): keep the pad "
                "still, its arrow toward the nose, and the drone level")
    return None
