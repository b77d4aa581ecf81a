"""Settings of the colour-dot detector (defaults are what the benchmark measured)."""

from __future__ import annotations

from dataclasses import dataclass, field

from drovisio.pose import AmbiguityRule

__all__ = ["DotsConfig"]


@dataclass(frozen=True)
class DotsConfig:
    """Settings of the dot detector (defaults are what the benchmark measured)."""

    clahe: bool = True
    """Judge the palette's V range on CLAHE-equalised V (per blob); False: on raw V, per
    pixel, exactly as ``cv2.inRange`` with the palette ranges."""
    clahe_clip: float = 2.0
    clahe_tiles: tuple[int, int] = (8, 8)
    clahe_stride: int = 4
    """Histogram subsampling of the CLAHE tables (1 = exactly OpenCV's)."""
    v_floor: int = 25
    """With ``clahe``: pixels darker than this (raw V) are never dots."""
    morph_kernel_px: int = 3
    """Opening/closing element diameter."""
    min_dot_px: float = 3.5
    """Smallest dot diameter looked for, pixels."""
    min_distance_m: float = 0.12
    """Nearest a dot may be to the camera (bounds the largest blob)."""
    min_aspect: float = 0.25
    min_circularity: float = 0.55
    min_fill: float = 0.88
    min_convexity: float = 0.85
    max_ellipse_err: float = 0.05
    """Outline deviation from the blob's moment ellipse (plus 0.35 px / minor semi-axis)."""
    max_holes: float = 0.15
    seeds_per_blob: int = 2
    """Nearest neighbours of each blob tried as its pair (hypothesis seeds)."""
    ratio_tol: float = 1.5
    match_tol: float = 0.3
    min_dots: int = 4
    """Fewest dots of a brick (partial matches use any 4 or more)."""
    max_dot_residual_px: float = 0.9
    """A dot farther than this from where the pose puts it is dropped (or the brick is)."""
    max_rmse_px: float = 0.6
    """Largest RMS reprojection error of an accepted brick."""
    size_ratio: tuple[float, float] = (0.5, 1.7)
    """Accepted measured / predicted dot size."""
    max_view_angle_deg: float = 82.0
    """Dots seen more obliquely than this (from their normal) are not trusted."""
    ambiguity: AmbiguityRule = field(default_factory=AmbiguityRule)
    """The planar ambiguity's rule, the same as the ArUco detector's
    (:mod:`drovisio.pose.ambiguity`); χ² at ``centroid_sigma_px``."""
    centroid_sigma_px: float = 0.15
    """Prior standard deviation of a dot centre (the ambiguity rule's χ²)."""
    covariance_floor_px: float = 0.001
    """Least standard deviation of a dot centre for the pose covariance, which takes it from
    the brick's own reprojection residuals (the floor only keeps the matrix invertible).
    A prior of ``centroid_sigma_px`` (0.15 px) here made the covariance ~25× too large (in
    variance) on rendered scenes: Mahalanobis median 0.21 for χ²(6)'s 5.35; from the
    residuals it is 4.8 (``tests/pose/test_covariance_honesty.py``)."""
    covariance: bool = True
