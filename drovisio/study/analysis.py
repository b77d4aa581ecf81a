"""Errors of one pose against the truth, and the summaries the figures and the report show.

Errors are in the camera frame of the thesis's set-up (z through the camera, perpendicular to
the markers; x, y in their plane):

* ``x_cm``, ``y_cm``: signed translation errors; ``xy_cm``: their norm;
* ``z_pct``: |Δz| / z of the truth, percent;
* ``rot_x_deg``, ``rot_y_deg``, ``rot_z_deg``: the rotation error ``R_est · R_trueᵀ`` as a
  rotation vector in the camera frame, its components (signed, degrees);
* and the benchmarks' own measures, so both can be compared on the same frames:
  ``lateral_mm`` (norm of the x/y error), ``depth_pct`` and ``yaw_deg`` (about the brick's z
  axis) exactly as ``drovisio bench aruco`` (codes) or ``dots`` (dots) compute them.

A layout with a symmetry (the thesis's red-blue-red dots: a half turn) is scored against the
nearer of the truth and its half-turned twin.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from drovisio.pose import yaw_about_axis_deg
from drovisio.pose.truth_errors import pose_errors
from drovisio.study.protocol import FIGURES

__all__ = ["ERRORS", "frame_errors", "summarise"]

#: error name → (axis label, unit, budget: the 5 cm / 3° the wall allows, or None)
ERRORS = {
    "xy_cm": ("x/y error (cm)", 5.0),
    "z_pct": ("z error (% of the distance)", None),
    "rot_xy_deg": ("rotation error about the turned axis (°)", 3.0),
    "rot_z_deg": ("rotation error about z (°)", 3.0),
}


def _half_turn_z() -> np.ndarray:
    return np.diag([-1.0, -1.0, 1.0])


def frame_errors(T_est: np.ndarray, T_true: np.ndarray, symmetric: bool = False,
                 turned: str | None = None, kind: str = "codes") -> dict:
    """Errors of ``camera_from_brick`` ``T_est`` against ``T_true`` (4×4 each).

    Args:
        symmetric: The layout looks the same after a half turn about its z axis.
        turned: ``"x"`` or ``"y"`` for a step that turns the brick about that camera axis
            (``rot_xy_deg`` is then the error about it).
        kind: ``"codes"`` or ``"dots"``: whose benchmark's measures (``drovisio bench aruco``
            or ``dots``) ``lateral_mm``, ``depth_pct`` and ``yaw_deg`` are.
    """
    R_true = T_true[:3, :3]
    R_est = T_est[:3, :3]
    if symmetric:
        twin = R_est @ _half_turn_z()
        if np.trace(twin.T @ R_true) > np.trace(R_est.T @ R_true):
            R_est = twin
    dt = T_est[:3, 3] - T_true[:3, 3]
    rv = cv2.Rodrigues(R_est @ R_true.T)[0].ravel()
    rot = np.degrees(rv)
    if kind == "dots":
        yaw = pose_errors(T_true.tolist(), T_est[:3, :3], T_est[:3, 3], symmetric)["yaw_deg"]
    else:
        yaw = yaw_about_axis_deg(R_true, R_est)
    out = {"x_cm": 100 * float(dt[0]), "y_cm": 100 * float(dt[1]),
           "xy_cm": 100 * float(math.hypot(dt[0], dt[1])),
           "z_pct": 100 * abs(float(dt[2])) / float(T_true[2, 3]),
           "rot_x_deg": float(rot[0]), "rot_y_deg": float(rot[1]), "rot_z_deg": float(rot[2]),
           "lateral_mm": 1000 * float(math.hypot(dt[0], dt[1])),
           "depth_pct": 100 * abs(float(dt[2])) / float(T_true[2, 3]),
           "yaw_deg": abs(yaw)}
    out["rot_xy_deg"] = abs(out[f"rot_{turned}_deg"]) if turned in ("x", "y") else \
        float(math.hypot(rot[0], rot[1]))
    out["rot_z_deg"] = abs(out["rot_z_deg"])
    return out


def summarise(records: list[dict]) -> list[dict]:
    """Per (figure, layout, method, step): frames, found, flagged ambiguous, median / p95 /
    max of the figure's error, and the share of frames within the budget."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((r["figure"], r["layout"], r["method"], r["step"]), []).append(r)
    out = []
    for (fig, lay, method, step), rs in sorted(groups.items()):
        err = FIGURES[fig]["error"]
        vals = [r["errors"][err] for r in rs if r["found"]]
        budget = ERRORS[err][1]
        s = {"figure": fig, "layout": lay, "method": method, "step": step,
             "vary": rs[0]["vary"], "value": rs[0]["value"], "error": err,
             "frames": len(rs), "found": sum(r["found"] for r in rs),
             "ambiguous": sum(bool(r.get("ambiguous")) for r in rs)}
        if vals:
            s.update(median=float(np.median(vals)), p95=float(np.percentile(vals, 95)),
                     max=float(np.max(vals)))
            if budget is not None:
                s["within_budget"] = float(np.mean(np.asarray(vals) <= budget))
        out.append(s)
    return out
