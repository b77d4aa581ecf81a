"""Parameter covariance of a calibration and the projection-uncertainty map over the image.

Model and covariance
--------------------
The solve minimises the squared reprojection error over the intrinsics θ of the lens model
(:func:`param_names`: fx, fy, cx, cy and 5 Brown, 8 rational, 12 thin-prism, 14 tilted or 4
fisheye coefficients) and
six extrinsics e_i = (rvec_i, tvec_i) per view.
With J_i = [A_i | B_i] the Jacobian of view i's residuals with respect to (θ, e_i), the
information about θ *after the extrinsics have been solved for* is the Schur complement

    S = Σ_i A_iᵀA_i − A_iᵀB_i (B_iᵀB_i)⁻¹ B_iᵀA_i,

and Σ_θ = σ² S⁻¹ with σ² = SSR / (2·N_corners − n_free − 6·n_views), the corner noise variance
estimated from the residuals. This is the joint (P × P, correlations included) covariance of the
intrinsics, marginalised over all board poses — its diagonal is what OpenCV's
``calibrateCameraExtended`` reports as standard deviations. Parameters held fixed (e.g. k3 = 0)
have zero variance: the map is then *conditioned* on that choice, which is honest only when
fixing was justified (see ``solve.py`` for the rule).

Projection uncertainty
----------------------
mrcal's question: how far may the projection of a fixed point in space move if the calibration
were repeated with new noise? For a pixel q we take the viewing ray of the solved model through
q, p = (x, y, 1) in the camera frame (a point at any distance on that ray: with the camera frame
held fixed, the projection depends only on the direction, so the distance drops out), and
propagate linearly:

    Σ_q = J_q Σ_θ J_qᵀ,   J_q = ∂π(p; θ)/∂θ   (2 × P),

reporting σ(q) = √λ_max(Σ_q), the 1-σ uncertainty in the worst image direction, pixels.

This holds the camera frame fixed. It does *not* let the frame rotate to absorb a principal-point
error (mrcal aligns the frames through the boards); it is therefore an upper bound on what a pose
estimator, which solves its own rotation, suffers, and it is exactly the quantity that can be
checked against a known true model: π_est(p) − π_true(p) for p on true rays. Validated on 20
rendered views (tests/calibration/test_uncertainty.py): the true model's projection lies within
2σ(q) of the estimate over ≥ 95 % of the image.

Everything here is linear (first order): valid while σ(q) is small against the distortion's
curvature, i.e. exactly in the regime where a verdict of "ok" is given.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from drovisio.camera import Camera, LensModel

__all__ = ["PARAM_NAMES", "camera_model", "lens_key", "model_key", "param_names", "param_values", "view_jacobian", "schur_information", "covariance_from_information",
           "UncertaintyMap", "image_grid", "grid_jacobians", "sigma_max",
           "projection_uncertainty", "model_difference_px"]

_DIST_NAMES = {
    "plumb_bob": ("k1", "k2", "p1", "p2", "k3"),
    "rational_polynomial": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "thin_prism": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"),
    "tilted": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx",
               "ty"),
    "fisheye": ("k1", "k2", "k3", "k4"),
}


def lens_key(camera: Camera) -> str:
    """The calibration's name of a camera's lens model: its file model, and for OpenCV's
    model with 12 or 14 coefficients ``thin_prism`` or ``tilted`` (the file says
    ``rational_polynomial`` for all three, as OpenCV writes them)."""
    return model_key(camera.model, camera.dist.size)


def model_key(model: str, n_coefficients: int) -> str:
    """:func:`lens_key` of a camera file's model name and its number of coefficients."""
    if model == "fisheye":
        return "fisheye"
    n = n_coefficients
    return ("tilted" if n >= 14 else "thin_prism" if n >= 12 else
            "rational_polynomial" if n >= 8 else "plumb_bob")


def camera_model(key: str) -> LensModel:
    """The camera file's model name of a calibration model (thin_prism and tilted are OpenCV's
    model with 12 and 14 coefficients: ``rational_polynomial``); :func:`lens_key`'s inverse."""
    if key == "fisheye":
        return "fisheye"
    if key == "plumb_bob":
        return "plumb_bob"
    return "rational_polynomial"


def param_names(model: str | Camera = "plumb_bob") -> tuple[str, ...]:
    """The intrinsics a calibration of ``model`` (a :func:`lens_key` name, or a camera)
    estimates, in the order of its vectors."""
    key = lens_key(model) if isinstance(model, Camera) else model
    return ("fx", "fy", "cx", "cy") + _DIST_NAMES.get(key, _DIST_NAMES["plumb_bob"])


PARAM_NAMES = param_names("plumb_bob")


def param_values(camera: Camera) -> np.ndarray:
    """The camera's intrinsics in :func:`param_names` order (missing coefficients 0)."""
    n = len(param_names(camera)) - 4
    d = np.zeros(n)
    d[: min(n, camera.dist.size)] = camera.dist[:n]
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *d])


def view_jacobian(object_points: np.ndarray, rvec, tvec, camera: Camera
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual Jacobians of one view through ``camera``'s lens model.

    Returns:
        (A (2N, P) w.r.t. the intrinsics in :func:`param_names` order, B (2N, 6) w.r.t.
        (rvec, tvec), projections (N, 2)).
    """
    obj = np.asarray(object_points, np.float64).reshape(-1, 1, 3)
    r = np.ascontiguousarray(np.asarray(rvec, float).reshape(3, 1))
    t = np.ascontiguousarray(np.asarray(tvec, float).reshape(3, 1))
    if camera.is_fisheye:
        # columns: fx fy cx cy k1..k4 | rvec | tvec | alpha (skew, held at 0)
        px, jac = cv2.fisheye.projectPoints(obj, r, t, camera.K, camera.dist)
        jac = np.asarray(jac, float)
        return jac[:, 0:8], jac[:, 8:14], np.asarray(px, float).reshape(-1, 2)
    d = param_values(camera)[4:]
    px, jac = cv2.projectPoints(obj, r, t, camera.K, d)
    jac = np.asarray(jac, float)
    return jac[:, 6:10 + d.size], jac[:, 0:6], np.asarray(px, float).reshape(-1, 2)


def schur_information(jacobians: list[tuple[np.ndarray, np.ndarray]], free: np.ndarray
                      ) -> np.ndarray:
    """Information S (n_free × n_free) about the free intrinsics, extrinsics eliminated.

    Args:
        jacobians: Per view (A, B) as from :func:`view_jacobian`.
        free: Boolean mask (9,) of the intrinsics that were estimated.
    """
    n = int(np.count_nonzero(free))
    S = np.zeros((n, n))
    for A, B in jacobians:
        Af = A[:, free]
        BtB = B.T @ B
        BtA = B.T @ Af
        S += Af.T @ Af - BtA.T @ np.linalg.solve(BtB, BtA)
    return S


def covariance_from_information(S: np.ndarray, sigma2: float, free: np.ndarray) -> np.ndarray:
    """Σ_θ (P × P) = σ² S⁻¹ on the free parameters, zeros on the fixed ones."""
    cov = np.zeros((free.size, free.size))
    idx = np.flatnonzero(free)
    # scale to unit diagonal before inverting: fx (~500) and k3 (~0.1) differ by 10⁴
    d = np.sqrt(np.clip(np.diag(S), 1e-300, None))
    Sn = S / np.outer(d, d)
    inv = np.linalg.pinv(Sn, rcond=1e-12) / np.outer(d, d)
    cov[np.ix_(idx, idx)] = sigma2 * inv
    return cov


@dataclass
class UncertaintyMap:
    """σ(q) (worst-direction 1-σ, pixels) on a grid of image points.

    ``xs`` (gw,) and ``ys`` (gh,) are pixel coordinates (edges included: 0 and width−1);
    ``sigma`` is (gh, gw).
    """

    xs: np.ndarray
    ys: np.ndarray
    sigma: np.ndarray

    def mask(self, roi: tuple[float, float, float, float] | None) -> np.ndarray:
        """Grid points inside ``roi`` = (x0, y0, x1, y1) pixels (None: everything)."""
        gx, gy = np.meshgrid(self.xs, self.ys)
        if roi is None:
            return np.ones(gx.shape, bool)
        x0, y0, x1, y1 = roi
        return (gx >= x0) & (gx <= x1) & (gy >= y0) & (gy <= y1)

    def stats(self, roi=None) -> dict:
        """{p50, p95, max} of σ over the grid points in ``roi``, pixels."""
        v = self.sigma[self.mask(roi)]
        v = v[np.isfinite(v)]
        if v.size == 0:
            return {"p50": None, "p95": None, "max": None}
        return {"p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)),
                "max": float(v.max())}

    def at(self, px: np.ndarray) -> np.ndarray:
        """σ interpolated (bilinear) at pixels (N, 2)."""
        px = np.asarray(px, float).reshape(-1, 2)
        fx = np.interp(px[:, 0], self.xs, np.arange(self.xs.size))
        fy = np.interp(px[:, 1], self.ys, np.arange(self.ys.size))
        m = cv2.remap(self.sigma.astype(np.float32), fx.astype(np.float32).reshape(-1, 1),
                      fy.astype(np.float32).reshape(-1, 1), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)
        return np.asarray(m, float).ravel()

    def to_json(self, decimals: int = 4) -> dict:
        return {"xs": np.round(self.xs, 2).tolist(), "ys": np.round(self.ys, 2).tolist(),
                "sigma_px": np.round(self.sigma, decimals).tolist()}


def image_grid(width: int, height: int, step: float = 16.0) -> tuple[np.ndarray, np.ndarray]:
    """Grid coordinates covering the image edge to edge, about ``step`` pixels apart."""
    nx = max(2, int(round((width - 1) / step)) + 1)
    ny = max(2, int(round((height - 1) / step)) + 1)
    return np.linspace(0, width - 1, nx), np.linspace(0, height - 1, ny)


def grid_jacobians(camera: Camera, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """∂π/∂θ (G, 2, P) for the viewing rays of ``camera`` through the grid points
    (row-major); NaN where the lens sees no ray."""
    gx, gy = np.meshgrid(xs, ys)
    px = np.stack([gx.ravel(), gy.ravel()], axis=1)
    xy = camera.normalize(px)
    P = len(param_names(camera))
    out = np.full((len(px), 2, P), np.nan)
    ok = np.all(np.isfinite(xy), axis=1)
    if ok.any():
        p = np.concatenate([xy[ok], np.ones((int(ok.sum()), 1))], axis=1)
        A, _, _ = view_jacobian(p, np.zeros(3), np.zeros(3), camera)
        out[ok] = A.reshape(-1, 2, P)
    return out


def sigma_max(J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """√λ_max of J Σ Jᵀ for a stack of (G, 2, P) Jacobians → (G,) (NaN rows give NaN)."""
    M = J @ cov  # (G, 2, n)
    a = np.sum(M[:, 0, :] * J[:, 0, :], axis=1)
    b = np.sum(M[:, 0, :] * J[:, 1, :], axis=1)
    c = np.sum(M[:, 1, :] * J[:, 1, :], axis=1)
    lam = 0.5 * (a + c) + np.sqrt(np.maximum(0.25 * (a - c) ** 2 + b * b, 0.0))
    return np.sqrt(np.maximum(lam, 0.0))


def projection_uncertainty(camera: Camera, cov: np.ndarray, step: float = 16.0
                           ) -> UncertaintyMap:
    """The projection-uncertainty map of ``camera`` given the intrinsics' covariance."""
    xs, ys = image_grid(camera.width, camera.height, step)
    J = grid_jacobians(camera, xs, ys)
    return UncertaintyMap(xs, ys, sigma_max(J, cov).reshape(ys.size, xs.size))


def model_difference_px(a: Camera, b: Camera, xs: np.ndarray, ys: np.ndarray,
                        compensate_rotation: bool = False) -> np.ndarray:
    """|π_b(ray_a(q)) − q| on the grid (gh, gw): how far model b moves the points that model a
    sees at q. Used for cross-validation and truth checks.

    With ``compensate_rotation`` the camera frame of b may first rotate by the small rotation
    that best aligns the two models over the grid (least squares, Gauss-Newton): what remains is
    the difference a pose estimator would feel, since it solves its own rotation anyway.

    Grid points that model a sees through no ray (a distortion polynomial that folds back
    near the image corners, as a weakly determined half-set's can) are NaN in the result and
    take no part in the alignment.
    """
    gx, gy = np.meshgrid(xs, ys)
    q = np.stack([gx.ravel(), gy.ravel()], axis=1)
    xy = a.normalize(q)
    ok = np.all(np.isfinite(xy), axis=1)
    d = np.full(len(q), np.nan)
    if not ok.any():
        return d.reshape(ys.size, xs.size)
    p = np.concatenate([xy[ok], np.ones((int(ok.sum()), 1))], axis=1)
    qv = q[ok]
    if not compensate_rotation:
        d[ok] = np.hypot(*(b.project(p) - qv).T)
        return d.reshape(ys.size, xs.size)
    w = np.zeros(3)
    for _ in range(5):
        px = b.cv_project(p, w, np.zeros(3))
        r = px - qv
        good = np.all(np.isfinite(r), axis=1)
        if good.sum() < 3:
            break
        # Jacobian of the projection with respect to the rotation, by central differences
        # (valid for every lens model)
        Jw = np.empty((int(good.sum()) * 2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-7
            Jw[:, k] = ((b.cv_project(p[good], w + e, np.zeros(3))
                         - b.cv_project(p[good], w - e, np.zeros(3))) / 2e-7).ravel()
        step = np.linalg.lstsq(Jw, -r[good].ravel(), rcond=None)[0]
        w = w + step
        if np.linalg.norm(step) < 1e-12:
            break
    d[ok] = np.hypot(*(b.cv_project(p, w, np.zeros(3)) - qv).T)
    return d.reshape(ys.size, xs.size)
