"""The compiled lens model (numba): OpenCV's rational + thin-prism distortion (12 coefficients,
no tilt), undistortion with its local Jacobian and projection.

:class:`drovisio.camera.Camera` chooses these inside its own fast functions
(:meth:`~drovisio.camera.Camera.normalize_fast`, :meth:`~drovisio.camera.Camera.project_fast`);
its numpy / OpenCV methods are the reference (tests compare the two).

Pixel (0, 0) is the centre of the top-left pixel; normalised image coordinates are x/z, y/z of
the OpenCV camera frame.
"""

from __future__ import annotations

import numpy as np

from drovisio._numba import jit as _jit


def lens_coefficients(dist: np.ndarray) -> np.ndarray | None:
    """A pinhole lens's distortion (OpenCV's 4 to 14 coefficients) as the 12 of the compiled
    model, or None for a tilted sensor (coefficients 13 and 14), which it does not know."""
    d = np.zeros(14)
    d[:dist.size] = dist
    return d[:12].copy() if not d[12:].any() else None


@_jit
def undistort(px, fx, fy, cx, cy, d):
    """Normalised coordinates of distorted pixels and the local Jacobian d(normalised)/d(pixel)
    (OpenCV's rational + thin-prism model, 12 coefficients ``d``; no tilt), by Newton's method
    on the distortion with its analytic Jacobian.

    Returns:
        (q (n, 2), J (n, 2, 2)).
    """
    n = px.shape[0]
    q = np.empty((n, 2))
    Jout = np.empty((n, 2, 2))
    k1, k2, p1, p2, k3, k4, k5, k6 = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
    s1, s2, s3, s4 = d[8], d[9], d[10], d[11]
    for i in range(n):
        ux = (px[i, 0] - cx) / fx
        uy = (px[i, 1] - cy) / fy
        x = ux
        y = uy
        a00 = 1.0
        a01 = 0.0
        a10 = 0.0
        a11 = 1.0
        for _ in range(12):
            r2 = x * x + y * y
            Nn = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            Dd = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
            rad = Nn / Dd
            dN = k1 + r2 * (2 * k2 + 3 * k3 * r2)
            dD = k4 + r2 * (2 * k5 + 3 * k6 * r2)
            drad = (dN * Dd - Nn * dD) / (Dd * Dd)
            ex = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
            ey = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
            sx = s1 + 2 * s2 * r2
            sy = s3 + 2 * s4 * r2
            a00 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * sx * x
            a01 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * sx * y
            a10 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * sy * x
            a11 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * sy * y
            rx = ux - ex
            ry = uy - ey
            det = a00 * a11 - a01 * a10
            if det == 0.0:
                break
            dx = (a11 * rx - a01 * ry) / det
            dy = (a00 * ry - a10 * rx) / det
            x += dx
            y += dy
            if abs(dx) + abs(dy) < 1e-15:
                break
        q[i, 0] = x
        q[i, 1] = y
        det = a00 * a11 - a01 * a10
        if det == 0.0:
            det = 1e-300
        # d(normalised)/d(pixel) = A⁻¹ · diag(1/fx, 1/fy)
        Jout[i, 0, 0] = a11 / det / fx
        Jout[i, 0, 1] = -a01 / det / fy
        Jout[i, 1, 0] = -a10 / det / fx
        Jout[i, 1, 1] = a00 / det / fy
    return q, Jout


@_jit
def project(Y, fx, fy, cx, cy, d):
    """Distorted pixels (n, 2) of camera-frame points (n, 3) (the model of :func:`undistort`;
    as ``cv2.projectPoints`` with zero pose)."""
    n = Y.shape[0]
    out = np.empty((n, 2))
    k1, k2, p1, p2, k3, k4, k5, k6 = d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]
    s1, s2, s3, s4 = d[8], d[9], d[10], d[11]
    for i in range(n):
        z = Y[i, 2]
        iz = 1.0 / z if z != 0 else 1.0
        x = Y[i, 0] * iz
        y = Y[i, 1] * iz
        r2 = x * x + y * y
        rad = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
        out[i, 0] = fx * xd + cx
        out[i, 1] = fy * yd + cy
    return out
