"""What the calibration solve takes and gives: its options, the views, one solved model and
the whole result with its report fields."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drovisio.calibration.uncertainty import UncertaintyMap, param_names, param_values
from drovisio.camera import Camera

RMS_DEFINITION = ("root mean square over all kept corners of the distance between the detected "
                  "corner and the projection of its board point, pixels (OpenCV calibrateCamera)")


class CalibrationError(RuntimeError):
    """The views cannot be calibrated (too few, degenerate, or no model converged on them);
    the message says why and what to do, in one line."""


@dataclass
class SolveOptions:
    """Knobs of :func:`solve` (defaults are the documented rules)."""

    model: str = "plumb_bob"
    """Lens model: one of :data:`MODEL_CHOICES` (``auto``: chosen by held-out views; module
    doc)."""
    fix_k3: str | bool = "auto"
    """"auto" (the 2σ rule), True (always fix) or False (never); plumb_bob only."""
    reject_corners: bool = True
    """Drop single corners that disagree with the model (module doc)."""
    corner_factor: float = 5.0
    corner_margin_px: float = 0.5
    k3_significance: float = 2.0
    outlier_factor: float = 2.5
    outlier_margin_px: float = 0.15
    min_views: int = 4
    """Never reject views below this count."""
    cross_validate: bool = True
    min_views_cross_validation: int = 8
    grid_step_px: float = 16.0
    roi: tuple[float, float, float, float] | None = None
    """Image region (x0, y0, x1, y1) where the statistics are taken (None: whole image)."""
    board_flatness: bool = False
    """Also estimate how far the board bowed (:mod:`drovisio.calibration.flatness`)."""


@dataclass
class ViewInput:
    """What the solve needs from a view: its corners and their board points."""

    name: str
    corners: np.ndarray
    object_points: np.ndarray


@dataclass
class ViewFit:
    """A kept view after the solve."""

    name: str
    rms_px: float
    max_px: float
    n_corners: int
    rvec: np.ndarray
    tvec: np.ndarray

    def to_json(self) -> dict:
        return {"file": self.name, "rms_px": round(self.rms_px, 5),
                "max_px": round(self.max_px, 5), "corners": self.n_corners,
                "rvec": np.round(self.rvec, 6).tolist(), "tvec": np.round(self.tvec, 6).tolist()}


@dataclass
class Model:
    """One solve of a fixed set of views and a fixed parameter set."""

    camera: Camera
    rms_px: float
    fits: list[ViewFit]
    free: np.ndarray
    information: np.ndarray
    sigma2: float
    covariance: np.ndarray
    rms_history: list[float] = field(default_factory=list)
    """RMS after each accepted step of the last stage (never growing)."""
    start: str = ""
    """Where the solve started (e.g. "plumb_bob K" for the fisheye)."""
    retry_note: str | None = None
    """Set when the full model was refused and fewer coefficients were solved instead."""

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def values(self) -> np.ndarray:
        return param_values(self.camera)


@dataclass
class CalibrationResult:
    """Everything the solve found. ``to_json`` gives the report fields."""

    camera: Camera
    rms_px: float
    per_view: list[ViewFit]
    rejected: list[dict]
    model: Model
    fixed: dict[str, str]
    uncertainty: UncertaintyMap
    cross_validation: dict
    free_model: dict | None = None
    roi: tuple[float, float, float, float] | None = None
    views: list[ViewInput] = field(default_factory=list, repr=False)
    model_choice: dict | None = None
    """How the lens model was chosen (``auto``): per model its held-out RMS, and why."""
    rejected_corners: list[dict] = field(default_factory=list)
    board_flatness: dict | None = None
    """The board's bow (:func:`drovisio.calibration.flatness.board_flatness`), if asked."""

    @property
    def std(self) -> dict[str, float]:
        return {n: float(s) for n, s in zip(param_names(self.camera), self.model.std)}

    @property
    def covariance(self) -> np.ndarray:
        return self.model.covariance

    def uncertainty_stats(self) -> dict:
        return self.uncertainty.stats(self.roi)

    def to_json(self) -> dict:
        return {
            "camera": {"width": self.camera.width, "height": self.camera.height,
                       "fx": self.camera.fx, "fy": self.camera.fy, "cx": self.camera.cx,
                       "cy": self.camera.cy, "dist": self.camera.dist.tolist(),
                       "model": self.camera.model,
                       "camera_matrix": self.camera.K.tolist()},
            "model_choice": self.model_choice,
            "rejected_corners": list(self.rejected_corners),
            "rms_px": self.rms_px,
            "rms_definition": RMS_DEFINITION,
            "corner_noise_px": float(np.sqrt(self.model.sigma2)),
            "per_view": [v.to_json() for v in self.per_view],
            "rejected": list(self.rejected),
            "std": self.std,
            "fixed": dict(self.fixed),
            "free_model": self.free_model,
            "uncertainty_px": {**self.uncertainty_stats(),
                               "definition": "1-sigma projection uncertainty in the worst "
                                             "image direction, over a grid covering the "
                                             + ("region of interest" if self.roi else "image"),
                               "grid_step_px": float(self.uncertainty.xs[1]
                                                     - self.uncertainty.xs[0])},
            "cross_validation_px": self.cross_validation,
            "board_flatness": self.board_flatness,
        }
