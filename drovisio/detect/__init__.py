"""Detectors: find bricks in an image by their codes (:mod:`.aruco`) or dots (:mod:`.dots`).

Every detector returns :class:`BrickPose` objects, the one result type the pipeline, the CLI
and the web tool share (see :mod:`.result`).
"""

from drovisio.detect.result import BrickPose, FrameRecord

__all__ = ["BrickPose", "FrameRecord"]
