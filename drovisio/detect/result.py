"""The result of detecting bricks in one frame, and its JSON form (DESIGN.md contract).

A pose is ``camera_from_brick``: ``X_cam = R(rvec) · X_brick + tvec`` (metres, radians,
OpenCV camera frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio.geometry import from_rvec_tvec
from drovisio.pose.covariance import parent_covariance

__all__ = ["BrickPose", "FrameRecord", "covariance_json"]


def _r(x: float, nd: int = 6) -> float:
    """``x`` rounded to ``nd`` decimals, as a plain float (the JSON output's precision)."""
    return float(round(float(x), nd))


def covariance_json(rvec: np.ndarray, cov_rvec_tvec: np.ndarray) -> list[list[float]] | None:
    """The JSON ``covariance`` of a pose: 6×6 rows, (x, y, z, rotation about x, y, z) of the
    camera frame, m and rad (:mod:`drovisio.pose.covariance`); None when not finite.

    Args:
        rvec: (3,) rotation vector of ``camera_from_brick``.
        cov_rvec_tvec: (6, 6) covariance of (rvec, tvec), rad and m.
    """
    C = parent_covariance(rvec, cov_rvec_tvec)
    if not np.all(np.isfinite(C)):
        return None
    return [[float(f"{v:.6g}") for v in row] for row in C]


@dataclass
class BrickPose:
    """One brick found in one frame.

    Args:
        layout: Layout name.
        instance: Instance number k, or None where the layout has no ids (dots).
        method: ``"aruco"`` or ``"dots"`` (``"fused"`` downstream).
        rvec: Rotation vector of ``camera_from_brick`` (3,).
        tvec: Translation of ``camera_from_brick`` in metres (3,).
        reprojection_rmse_px: RMS distance between measured and reprojected image points.
        markers: Code ids used (aruco) or indices of the layout's dots used (dots).
        ambiguous: The image alone cannot decide between this pose and ``alternatives``.
        alternatives: Other candidate poses as (rvec, tvec) when ambiguous.
        symmetric: The layout is symmetric; the yaw is reported in one canonical half-turn.
        covariance: 6×6 covariance of (rvec, tvec), from the Jacobian and the corner noise.
        image_points: (N, 2) measured image points the pose was fitted to (for drawing).
        duplicate: See the attribute.
    """

    layout: str
    instance: int | None
    method: str
    rvec: np.ndarray
    tvec: np.ndarray
    reprojection_rmse_px: float
    markers: list[int] = field(default_factory=list)
    ambiguous: bool = False
    alternatives: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    symmetric: bool = False
    covariance: np.ndarray | None = None
    image_points: np.ndarray | None = None
    duplicate: bool = False
    """Its code's id was read more than once in the frame: each copy is posed on its own
    and flagged, never merged with the others into one brick."""

    def camera_from_brick(self) -> np.ndarray:
        """The pose as a 4×4 matrix."""
        return from_rvec_tvec(self.rvec, self.tvec)

    def to_json(self, with_covariance: bool = True) -> dict:
        """The DESIGN.md JSON object of one brick (flags only when they are true; the
        covariance, when known, in the convention of :mod:`drovisio.pose.covariance`)."""
        out: dict = {
            "layout": self.layout,
            "instance": self.instance,
            "method": self.method,
            "rvec": [_r(v, 7) for v in np.ravel(self.rvec)],
            "tvec": [_r(v, 7) for v in np.ravel(self.tvec)],
            "reprojection_rmse_px": _r(self.reprojection_rmse_px, 4),
            "markers": [int(m) for m in self.markers],
        }
        if self.ambiguous:
            out["ambiguous"] = True
            out["alternatives"] = [{"rvec": [_r(v, 7) for v in np.ravel(r)],
                                    "tvec": [_r(v, 7) for v in np.ravel(t)]}
                                   for r, t in self.alternatives]
        if self.symmetric:
            out["symmetric"] = True
        if self.duplicate:
            out["duplicate"] = True
        if with_covariance and self.covariance is not None:
            cov = covariance_json(self.rvec, self.covariance)
            if cov is not None:
                out["covariance"] = cov
        return out


@dataclass
class FrameRecord:
    """All bricks of one frame (one JSON Lines record of ``drovisio detect``)."""

    file: str
    frame: int
    bricks: list[BrickPose] = field(default_factory=list)
    error: str | None = None

    def to_json(self, with_covariance: bool = True) -> dict:
        """The DESIGN.md JSON Lines record: file, frame, the error if any, the bricks."""
        out: dict = {"file": self.file, "frame": self.frame}
        if self.error is not None:
            out["error"] = self.error
        out["bricks"] = [b.to_json(with_covariance) for b in self.bricks]
        return out
