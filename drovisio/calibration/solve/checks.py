"""Whether a solve can be written: the corners' own noise, a lens mapping that folds back
inside the field the board covered, residuals far above that noise, and intrinsics the views
do not determine."""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.calibration.solve.results import Model, ViewFit, ViewInput
from drovisio.calibration.uncertainty import lens_key, param_names, projection_uncertainty
from drovisio.camera import Camera

#: A solve whose 1-σ focal length or principal point is this fraction of the focal length
#: (of the image side) is not determined by its views: it is refused, never written.
MAX_RELATIVE_SIGMA = 0.1
#: Nor is one whose projection over the image is uncertain by this fraction of the focal
#: length at the median point (1-σ; 0.6° of viewing angle, 2 cm on a brick 2 m away): each
#: intrinsic may be known while the model as a whole is not (a tilted sensor's 14
#: coefficients from a few views trade with each other), and what a user gets is its
#: projection.
MAX_PROJECTION_SIGMA = 0.01
#: A solve whose RMS exceeds both this many times the corner noise and the noise + 2 px has
#: not found the lens (the corners disagree with the model far beyond their own noise).
MAX_RMS_OVER_NOISE = 10.0


def corner_noise_px(views: list[ViewInput]) -> float | None:
    """The corners' own noise, measured without any lens model, pixels (1-σ per axis).

    Every corner with its 8 grid neighbours (a 3 × 3 patch of the board) is fitted by a
    quadratic map from board to image (6 coefficients per axis: perspective and distortion
    are smooth over two squares); the residual variance of a patch is SSR / 6 (9 points, 6
    coefficients, 2 axes), and the noise is the median over all patches corrected for the
    median of χ²₆/6 (0.891). Board bow, print errors and any lens are smooth at this scale
    and are not counted: this is a lower bound of what a perfect model could reach.

    Returns:
        None when no view has a complete 3 × 3 patch.
    """
    vals: list[float] = []
    for v in views:
        o = np.asarray(v.object_points, float).reshape(-1, 3)[:, :2]
        c = np.asarray(v.corners, float).reshape(-1, 2)
        if len(o) < 9:
            continue
        dist = np.hypot(o[:, None, 0] - o[None, :, 0], o[:, None, 1] - o[None, :, 1])
        pos = dist[dist > 1e-12]
        if pos.size == 0:
            continue
        sq = float(pos.min())
        for i in range(len(o)):
            nb = np.flatnonzero(dist[i] < 1.5 * sq)
            if nb.size != 9:
                continue
            u = (o[nb] - o[i]) / sq
            M = np.stack([np.ones(9), u[:, 0], u[:, 1], u[:, 0] ** 2, u[:, 0] * u[:, 1],
                          u[:, 1] ** 2], axis=1)
            res = c[nb] - M @ np.linalg.lstsq(M, c[nb], rcond=None)[0]
            vals.append(float((res ** 2).sum()) / 6.0)
    if not vals:
        return None
    return float(np.sqrt(np.median(vals) / 0.8914))


def _field_radius(cam: Camera, O, fits: list[ViewFit]) -> float:
    """The largest angle from the optical axis (radians) at which the views saw a corner."""
    worst = 0.0
    for o, f in zip(O, fits):
        R = cv2.Rodrigues(np.asarray(f.rvec, float))[0]
        X = np.asarray(o, float).reshape(-1, 3) @ R.T + np.asarray(f.tvec, float)
        worst = max(worst, float(np.max(np.arctan2(np.hypot(X[:, 0], X[:, 1]), X[:, 2]))))
    return worst


def fold_angle(cam: Camera, theta_max: float) -> float | None:
    """The first angle from the axis (radians, up to ``theta_max``) where the lens model's
    radial mapping stops growing (a folded model: two rays on one pixel), None if it grows
    all the way."""
    th = np.linspace(0.0, min(theta_max, np.pi / 2 - 1e-3), 400)[1:]
    if cam.is_fisheye:
        k1, k2, k3, k4 = cam.dist
        t2 = th * th
        r = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    else:
        d = np.zeros(8)
        d[: min(8, cam.dist.size)] = cam.dist[:8]
        x = np.tan(th)
        x2 = x * x
        num = 1 + x2 * (d[0] + x2 * (d[1] + x2 * d[4]))
        den = 1 + x2 * (d[5] + x2 * (d[6] + x2 * d[7]))
        if np.any(den <= 0):
            return float(th[int(np.argmax(den <= 0))])
        r = x * num / den
    bad = np.flatnonzero(np.diff(r) <= 0)
    return None if bad.size == 0 else float(th[bad[0]])


def diagnose(m: Model, O, noise: float | None) -> tuple[str, str] | None:
    """Why a solve cannot be written ((cause, fix)), or None: it did not converge (folded
    lens mapping inside the field the board covered, residuals far above the corner noise)
    or its views do not determine it (focal length or principal point uncertain by
    :data:`MAX_RELATIVE_SIGMA`, its projection by :data:`MAX_PROJECTION_SIGMA`, of the focal
    length)."""
    cam = m.camera
    key = lens_key(cam)
    other = ("or try --model plumb_bob" if key == "fisheye" else
             "or try --model fisheye for a wide lens")
    field_max = _field_radius(cam, O, m.fits)
    fold = fold_angle(cam, field_max)
    coeffs = ", ".join(f"{n} = {v:.4g}" for n, v in zip(param_names(cam)[4:], cam.dist)
                       if abs(v) > 0)
    if fold is not None:
        return (f"did not converge: its lens mapping folds back {np.degrees(fold):.0f}° from "
                f"the axis, inside the {np.degrees(field_max):.0f}° the board covered "
                f"({coeffs})", "add views with the board near the image corners and edges, "
                + other)
    if noise is not None and m.rms_px > max(MAX_RMS_OVER_NOISE * noise, noise + 2.0):
        return (f"did not converge: RMS {m.rms_px:.2f} px, far above the corners' own noise "
                f"({noise:.2f} px, measured without a lens model)", "check --board and "
                "--square and that the board is flat, remove views of a moving board, "
                + other)
    fix = ("add views with the board tilted toward each side and at other distances, "
           "or use a model with fewer coefficients")
    sd = m.std
    rel = np.array([sd[0] / cam.fx, sd[1] / cam.fy, sd[2] / cam.fx, sd[3] / cam.fy])
    if not np.all(np.isfinite(rel)) or rel.max() > MAX_RELATIVE_SIGMA:
        worst = int(np.nanargmax(np.where(np.isfinite(rel), rel, np.inf)))
        name = ("fx", "fy", "cx", "cy")[worst]
        return (f"is not determined by these views: 1-sigma of {name} is "
                f"{rel[worst] * 100:.0f} % of the focal length" if np.isfinite(rel[worst])
                else f"is not determined by these views: {name} has no finite uncertainty",
                fix)
    p50 = projection_uncertainty(cam, m.covariance).stats()["p50"]
    f = min(cam.fx, cam.fy)
    if p50 is None or p50 > MAX_PROJECTION_SIGMA * f:
        return ("is not determined by these views: its projection is uncertain by "
                + ("an unknown amount everywhere" if p50 is None else
                   f"{p50:.1f} px (1-sigma) at the median point of the image, more than "
                   f"{MAX_PROJECTION_SIGMA * 100:g} % of the focal length"), fix)
    return None
