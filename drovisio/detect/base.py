"""What every detector is, and the evidence steps both detectors share.

A detector is built once per camera and set of layouts and then fed the frames of one
stream in order: ``Detector(camera, layouts, config, stream=True)``. With ``stream=True``
it keeps what the previous frames tell about the next (poses for the planar ambiguity,
symmetric yaws); ``reset()`` forgets it (a new stream, a seek). ``detect(image, gravity)``
returns the bricks of one frame as :class:`~drovisio.detect.result.BrickPose`, poses
``camera_from_brick`` in metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from drovisio.detect.result import BrickPose
from drovisio.pose.ambiguity import reference_up

__all__ = ["Detector", "decided_up", "unit_gravity"]


@runtime_checkable
class Detector(Protocol):
    """The shape both detectors have (:class:`~drovisio.detect.aruco.ArucoBrickDetector`,
    :class:`~drovisio.detect.dots.DotDetector`)."""

    name: str
    """Short name used in logs and status: ``"aruco"`` or ``"dots"``."""

    def detect(self, image: np.ndarray, gravity: np.ndarray | None = None) -> list[BrickPose]:
        """The bricks of one frame.

        Args:
            image: (H, W, 3) uint8 BGR frame of the detector's camera (grey accepted where
                the detector can use it).
            gravity: (3,) direction of gravity in the camera frame (pointing down), if known.
        """
        ...

    def reset(self) -> None:
        """Forget the stream's past (a new stream starts with the next frame)."""
        ...


def unit_gravity(gravity: Sequence[float] | np.ndarray | None) -> np.ndarray | None:
    """Gravity as a (3,) unit vector in the camera frame, or None when it is absent or
    unusable (not three finite numbers, zero length): a bad reading is no evidence."""
    if gravity is None:
        return None
    g = np.asarray(gravity, np.float64).ravel()
    if g.size != 3 or not np.all(np.isfinite(g)):
        return None
    n = float(np.linalg.norm(g))
    return g / n if n > 0 else None


def decided_up(R: np.ndarray, decided_by: Sequence[str], undecided: np.ndarray
               ) -> np.ndarray | None:
    """The "up" that the decided bricks of a frame give the undecided ones (bricks on one
    ground are parallel), or None when no brick is undecided or none was decided firmly.

    Args:
        R: (B, 3, 3) chosen rotations ``camera_from_brick`` of the frame's bricks.
        decided_by: What decided each brick's pose (``""`` when undecided).
        undecided: (B,) True where a brick is still undecided.
    """
    undecided = np.asarray(undecided, bool)
    if not undecided.any() or undecided.all():
        return None
    keep = np.flatnonzero(~undecided)
    return reference_up(np.asarray(R, np.float64)[keep], [decided_by[int(k)] for k in keep])
