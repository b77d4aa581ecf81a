"""A pose hypothesis of one brick and the chosen pose with its quality and alternatives."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["PoseCandidate", "PoseResult"]


@dataclass
class PoseCandidate:
    """One pose hypothesis: ``camera_from_object`` as (rvec, tvec), and its fit."""

    rvec: np.ndarray
    tvec: np.ndarray
    rmse_px: float
    """RMS reprojection error, pixels (distance per point)."""
    chi2: float
    """Σ of squared residuals weighted by the image points' noise."""

    @property
    def R(self) -> np.ndarray:
        """Rotation matrix (computed once)."""
        R = self.__dict__.get("_R")
        if R is None:
            R = cv2.Rodrigues(np.asarray(self.rvec, np.float64).reshape(3, 1))[0]
            self.__dict__["_R"] = R
        return R


@dataclass
class PoseResult:
    """The chosen pose, its quality and the alternative(s) when undecided."""

    rvec: np.ndarray
    tvec: np.ndarray
    rmse_px: float
    covariance: np.ndarray
    """6×6 covariance of (rvec, tvec) (rad², m²)."""
    ambiguous: bool = False
    alternatives: list[PoseCandidate] = field(default_factory=list)
    decided_by: str = "unique"
    """``unique`` (one candidate), ``gravity``, ``reference``, ``previous``, ``reprojection``,
    ``close`` (candidates nearly equal) or ``none`` (ambiguous)."""
    candidates: list[PoseCandidate] = field(default_factory=list)
    """All candidates after refinement, the chosen one first."""

    def camera_from_object(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(np.asarray(self.rvec, np.float64).reshape(3, 1))[0]
        T[:3, 3] = np.ravel(self.tvec)
        return T
