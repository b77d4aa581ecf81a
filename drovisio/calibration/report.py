"""The calibration report (JSON), a text summary and the uncertainty map as an image.

Report fields (``drovisio calibrate --report``; DESIGN.md's contract, extended):

``schema``, ``board``, ``image_size``, ``camera`` (K, distortion), ``rms_px`` and
``rms_definition``, ``corner_noise_px``, ``per_view`` (file, rms_px, max_px, corners, pose),
``rejected`` (file + reason: unreadable, no board, blurred, outlier, wrong size...), ``std``
(1-σ of fx fy cx cy k1 k2 p1 p2 k3; 0 for a fixed one), ``fixed`` (coefficient → why),
``free_model`` (the free solve, when a coefficient was fixed), ``uncertainty_px`` {p50, p95,
max, definition}, ``uncertainty_map`` (grid xs, ys, σ), ``cross_validation_px`` {p50, p95, max},
``coverage``, ``verdict`` {ok, reasons, advice}, ``suggestion`` (next board placement),
``model_choice`` (``--model auto``: chosen, reason, held_out_rms_px and failed_views per
model, refused {model: why}, corner_noise_px measured without a lens model).
When nothing could be solved, the solve fields are null and ``verdict.reasons`` says why.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from drovisio.calibration.uncertainty import model_key, param_names

__all__ = ["build_report", "format_summary", "uncertainty_image", "SCHEMA"]

SCHEMA = "drovisio/calibration-report@1"


def _clean(x):
    """JSON-safe: NaN/inf → None, numpy → Python."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def build_report(session, include_map: bool = True) -> dict:
    """The report of a :class:`~drovisio.calibration.session.CalibrationSession` as it is now
    (its last solve, current coverage, verdict and suggestion)."""
    res = session.result
    cov = session.coverage()
    verdict = session.verdict()
    try:
        sug = session.suggestion().to_json()
    except ValueError as e:
        sug = {"sentence": str(e)}
    rejected = list(session.rejected) + (list(res.rejected) if res is not None else [])
    rep = {
        "schema": SCHEMA,
        "board": session.board.to_json(),
        "image_size": None if session.image_size is None else list(session.image_size),
        "views_kept": len(res.per_view) if res is not None else len(session.views),
        "camera": None, "rms_px": None, "rms_definition": None, "corner_noise_px": None,
        "per_view": [], "std": None, "fixed": {}, "free_model": None,
        "uncertainty_px": {"p50": None, "p95": None, "max": None},
        "cross_validation_px": {"p50": None, "p95": None, "max": None},
    }
    if res is not None:
        rep.update(res.to_json())
        if include_map:
            rep["uncertainty_map"] = res.uncertainty.to_json()
    if session.last_error and res is None:
        rep["error"] = session.last_error
    rep["rejected"] = rejected
    rep["coverage"] = cov.to_json()
    rep["verdict"] = verdict.to_json()
    rep["suggestion"] = sug
    return _clean(rep)


def _distortion_line(cam: dict) -> str:
    """The lens's coefficients named as its model names them (a fisheye's k1..k4 are not
    Brown's k1 k2 p1 p2)."""
    d = [float(x) for x in cam["dist"]]
    names = param_names(model_key(cam.get("model") or "plumb_bob", len(d)))[4:4 + len(d)]
    return (f"distortion ({cam.get('model') or 'plumb_bob'}) {' '.join(names)}: "
            + " ".join(f"{x:.5g}" for x in d))


def format_summary(report: dict) -> str:
    """A few human lines summarising a report (for stderr)."""
    lines = []
    cam = report.get("camera")
    if cam:
        std = report.get("std") or {}
        lines.append(f"fx {cam['fx']:.2f} ± {std.get('fx', 0):.2f}  fy {cam['fy']:.2f} ± "
                     f"{std.get('fy', 0):.2f}  cx {cam['cx']:.2f} ± {std.get('cx', 0):.2f}  "
                     f"cy {cam['cy']:.2f} ± {std.get('cy', 0):.2f} px")
        lines.append(_distortion_line(cam))
        lines.append(f"RMS reprojection error {report['rms_px']:.3f} px over "
                     f"{report['views_kept']} views")
        u = report["uncertainty_px"]
        lines.append(f"projection uncertainty (1σ): p50 {u['p50']:.3f}  p95 {u['p95']:.3f}  "
                     f"max {u['max']:.3f} px")
        cv = report.get("cross_validation_px") or {}
        if cv.get("p95") is not None:
            rc = cv.get("rotation_compensated") or {}
            lines.append(f"cross-validation (two halves): p50 {cv['p50']:.3f}  p95 "
                         f"{cv['p95']:.3f}  max {cv['max']:.3f} px"
                         + (f" (after aligning rotations: p95 {rc['p95']:.3f} px)"
                            if rc.get("p95") is not None else ""))
        elif cv.get("skipped"):
            lines.append(f"cross-validation skipped: {cv['skipped']}")
    for r in report.get("rejected", []):
        lines.append(f"rejected {r['file']}: {r['reason']}")
    v = report.get("verdict") or {}
    lines.append("verdict: " + ("OK" if v.get("ok") else "NOT OK"))
    for r in v.get("reasons", []):
        lines.append(f"  - {r}")
    for a in v.get("advice", []):
        lines.append(f"  (note) {a}")
    s = report.get("suggestion") or {}
    if s.get("sentence") and not v.get("ok"):
        lines.append(f"next: {s['sentence']}")
    return "\n".join(lines)


def uncertainty_image(result, width: int | None = None, max_px: float = 2.0,
                      threshold_px: float = 0.5) -> np.ndarray:
    """The uncertainty map as a BGR image (image size, or ``width`` wide): σ from 0 (dark blue)
    to ``max_px`` and above (yellow) on the viridis scale, with the ``threshold_px`` contour
    drawn in white."""
    um = result.uncertainty
    w, h = result.camera.width, result.camera.height
    if width is not None:
        h = int(round(h * width / w))
        w = int(width)
    sig = cv2.resize(um.sigma.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    u8 = np.clip(sig / max_px * 255.0, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(u8, cv2.COLORMAP_VIRIDIS)
    mask = (sig > threshold_px).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(img, contours, -1, (255, 255, 255), 1)
    return img
