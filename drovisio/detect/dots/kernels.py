"""Every compiled kernel the colour-dot detector runs, gathered from the subjects they sit
beside (the warm-up, the first-compile notice and the tests use this list).

Each stage chooses its own kernel (the lens model in :mod:`drovisio.camera_kernels`, the blob,
colour and matching stages in :mod:`.blobs_kernels`, :mod:`.color_kernels`,
:mod:`.match_kernels`, the dot model's occlusion in :mod:`.model_kernels`, the batched poses
in :mod:`drovisio.pose.batch_kernels` and :mod:`drovisio.pose.ippe_kernels`); numba compiles
each once per machine (``cache=True``, kept in ``__pycache__`` beside its module).
"""

from __future__ import annotations

import logging

from drovisio._numba import AVAILABLE, enabled, missing_cache, set_enabled
from drovisio.camera_kernels import project, undistort
from drovisio.detect.dots.blobs_kernels import measure_contours, polygon_areas, refine_centers
from drovisio.detect.dots.color_kernels import clahe_at
from drovisio.detect.dots.match_kernels import assign_greedy, hypotheses
from drovisio.detect.dots.model_kernels import occlusion_clearance
from drovisio.pose.batch_kernels import (
    conic_center_offsets,
    gn_step,
    pose_covariance,
    refine_poses,
    so3_log,
)
from drovisio.pose.ippe_kernels import ippe

__all__ = [
    "AVAILABLE",
    "assign_greedy",
    "clahe_at",
    "conic_center_offsets",
    "enabled",
    "gn_step",
    "hypotheses",
    "ippe",
    "measure_contours",
    "missing_cache",
    "notice_first_compile",
    "occlusion_clearance",
    "polygon_areas",
    "pose_covariance",
    "project",
    "refine_centers",
    "refine_poses",
    "set_enabled",
    "so3_log",
    "undistort",
]

_NOTICED = False


def notice_first_compile(log: logging.Logger) -> None:
    """Once per process: tell the user when the kernels have no compiled cache yet (the first
    frame then waits for numba, ~30 s once per machine)."""
    global _NOTICED
    if _NOTICED or not enabled():
        return
    _NOTICED = True
    missing = missing_cache(globals())
    if missing:
        log.warning("first use of the colour-dot detector on this machine: compiling its "
                    "kernels (%d functions, about 3 min on a small laptop, kept for later runs)", len(missing))
