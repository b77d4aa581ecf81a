"""Poses of bricks from image points: one engine for both detectors.

* :mod:`.ambiguity` — the planar ambiguity's one rule (what ``ambiguous`` means), the evidence
  (gravity, other bricks, the previous frame) and the canonical half-turn of symmetric layouts;
* :mod:`.solve` — one brick from its points through the full lens model (the ArUco detector);
* :mod:`.batch` — many bricks at once in normalised coordinates: homographies, IPPE's two
  solutions, Levenberg–Marquardt and Gauss–Newton steps, covariances (the dot detector; the
  arithmetic runs in compiled kernels when numba is there, chosen inside these functions);
* :mod:`.candidate` — a pose hypothesis and the chosen pose with its alternatives;
* :mod:`.refine` — Gauss–Newton in pixels through the lens model, robust weights, whole codes
  left out, the covariance (the steps of :mod:`.solve`);
* :mod:`.measures` — angles between poses, the rotation and yaw errors.

Conventions: ``camera_from_brick``: ``X_cam = R · X_brick + t`` (rvec, tvec at the edges);
metres, radians; gravity is a unit vector in the camera frame pointing down.
"""

from drovisio.pose.ambiguity import (
    HALF_TURN,
    AmbiguityRule,
    PoseEvidence,
    PoseHistory,
    alternative_plausible,
    canonical_half_turn,
    decide_flips,
    reference_up,
)
from drovisio.pose.measures import (
    is_planar,
    rotation_angle_deg,
    rotation_angles_deg,
    tilt_deg,
    yaw_about_axis_deg,
    yaw_error_deg,
)
from drovisio.pose.solve import PoseCandidate, PoseResult, solve_brick_pose

__all__ = [
    "HALF_TURN",
    "AmbiguityRule",
    "PoseCandidate",
    "PoseEvidence",
    "PoseHistory",
    "PoseResult",
    "alternative_plausible",
    "canonical_half_turn",
    "decide_flips",
    "is_planar",
    "reference_up",
    "rotation_angle_deg",
    "rotation_angles_deg",
    "solve_brick_pose",
    "tilt_deg",
    "yaw_about_axis_deg",
    "yaw_error_deg",
]
