"""Pose of one rigid object from 2D–3D point correspondences (the ArUco codes of a brick),
through the full lens model, with its planar ambiguity decided by the one rule of
:mod:`drovisio.pose.ambiguity` (which the dot detector's batched poses use too).

:func:`solve_brick_pose`:

1. **Candidates.** Planar point sets (every code of a drick's top, a dot pattern) have, seen
   from afar or nearly head-on, two poses that reproject almost equally well (the "flip"
   ambiguity). IPPE (``cv2.SOLVEPNP_IPPE``) returns both; it is fed exactly undistorted,
   normalised coordinates (our own undistortion, not OpenCV's 5-step one) and points
   expressed in their own plane (OpenCV's IPPE is wrong for a plane z = const ≠ 0, e.g. the
   drick's pyramid tops at z = 0.02). Non-planar sets use SQPnP (one global solution).
2. **Choice**, by :func:`drovisio.pose.ambiguity.decide_flips` (gravity, a reference "up",
   a previous pose, then the reprojection at the measured corner noise): the evidence is
   weighed before refinement (flips differ by tens of degrees), the χ² after refining both
   candidates. When nothing decides, the result says so (``ambiguous``) and carries the
   alternative.
3. **Refinement.** Gauss–Newton (Levenberg-damped) in *pixels* through the full lens model,
   weighted by the image points' covariance; with gravity known, an optional soft "lies
   flat" prior.
4. **Quality.** RMS reprojection error (px) and the 6×6 covariance of (rvec, tvec) from the
   Jacobian of the projection and the image points' covariance (Gauss–Newton:
   ``(Jᵀ Σ⁻¹ J)⁻¹``), inflated when the residuals say the noise is larger than assumed.

Conventions: ``camera_from_object``: ``X_cam = R(rvec) · X_obj + tvec``; metres, radians;
pixels are distorted image pixels, (0, 0) the centre of the top-left pixel; gravity is a unit
vector in the camera frame pointing down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.pose.ambiguity import (
    MIN_DOF_FOR_SCALE,
    AmbiguityRule,
    PoseEvidence,
    decide_flips,
    noise_scale,
)
from drovisio.pose.measures import is_planar, tilt_deg

__all__ = ["PoseCandidate", "PoseResult", "solve_brick_pose"]

#: Gauss–Newton iterations of the final refinement. One: from IPPE's start the later steps
#: changed nothing measurable, through the 60° lens nor through a 150° fisheye's periphery
#: (``drovisio bench lens --spread 4``: the same p95 with 6), and each costs a projection
REFINE_ITERATIONS = 1
#: Huber's threshold (standard deviations of a point's own covariance) of the final
#: refinement, and the fewest points it is used with (two codes: redundancy to tell a bad
#: corner from the pose)
ROBUST_K = 3.0
ROBUST_MIN_POINTS = 8



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


# ----------------------------------------------------------------------------- solving
_PLANE_CACHE: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
_EYE3 = np.eye(3)
_EYE3.flags.writeable = False


def _plane_frame(obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, c): columns of R are two in-plane axes and the normal of the points' plane, c a
    point of it; ``(obj - c) @ R`` has z = 0. Points already on a plane z = const keep
    their x, y axes. Cached (a brick's point sets repeat from frame to frame)."""
    key = obj.tobytes()
    hit = _PLANE_CACHE.get(key)
    if hit is None:
        hit = _plane_frame_uncached(obj)
        if len(_PLANE_CACHE) > 256:
            _PLANE_CACHE.clear()
        _PLANE_CACHE[key] = hit
    return hit


def _plane_frame_uncached(obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = obj[:, 2]
    if np.ptp(z) <= 1e-9 * max(1.0, float(np.abs(obj).max())):
        return _EYE3, np.array([0.0, 0.0, float(z.mean())])
    c = obj.mean(axis=0)
    _, _, Vt = np.linalg.svd(obj - c)
    R = Vt.T.copy()
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    return R, c


def _sigma_inv(points_cov: np.ndarray | None, n: int, default_sigma: float) -> np.ndarray:
    """Inverse covariance (2n, 2n) of the image points."""
    if points_cov is None:
        return np.eye(2 * n) / default_sigma ** 2
    C = np.asarray(points_cov, np.float64)
    if C.ndim == 0 or C.size == 1:
        return np.eye(2 * n) / float(C) ** 2  # a scalar sigma
    if C.ndim == 1:  # per-point sigma
        return np.diag(np.repeat(1.0 / C ** 2, 2))
    try:
        return np.linalg.inv(C)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(C)


def _candidate(obj, img, rvec, tvec, camera, Winv) -> PoseCandidate:
    px, _ = camera.project_points(obj, rvec, tvec)
    r = (px - img).ravel()
    return PoseCandidate(np.asarray(rvec, np.float64).ravel().copy(),
                         np.asarray(tvec, np.float64).ravel().copy(),
                         float(np.sqrt(np.mean(np.sum((px - img) ** 2, axis=1)))),
                         float(r @ Winv @ r))


def _up_residual(rvec: np.ndarray, up_axis: np.ndarray, g: np.ndarray, sigma: float):
    """Residual (3,) of the flat-lying prior, (R·up + g)/sigma, and its Jacobian (3, 3)."""
    R, dR = cv2.Rodrigues(rvec.reshape(3, 1))  # dR: (3, 9), dR[k, 3 i + j] = d R_ij / d r_k
    r0 = (R @ up_axis + g) / sigma
    J = (dR.reshape(3, 3, 3) @ up_axis).T / sigma  # J[i, k] = sum_j dR_ij/dr_k up_j
    return r0, J


def _gauss_newton(obj, img, cand: PoseCandidate, camera: Camera, Winv, iterations: int = 2,
                  prior: tuple[np.ndarray, np.ndarray, float] | None = None
                  ) -> tuple[PoseCandidate, np.ndarray]:
    """Weighted Gauss–Newton in pixels (Levenberg-damped), optionally with the flat-lying
    prior ``(up_axis, gravity, sigma_rad)``. Returns the refined candidate (χ² of the image
    part) and the information matrix (6×6, prior included) at it."""
    rvec, tvec = cand.rvec.copy(), cand.tvec.copy()
    best_rt = (rvec, tvec)
    best_cost = np.inf
    best_chi2 = np.inf
    best_sq = np.inf
    best_d = None
    info = None
    lam = 1e-6
    obj3 = obj.reshape(-1, 1, 3)
    for it in range(iterations + 1):
        last = it == iterations
        if last and it > 0:  # the final check needs no Jacobian (the information matrix
            # is taken at the previous point: one small step away)
            px, _ = camera.project_points(obj3, rvec, tvec)
            J = None
        else:
            px, J = camera.project_points(obj3, rvec, tvec)
        d = img - px.reshape(-1, 2)
        r = d.ravel()
        chi2 = float(r @ Winv @ r)
        cost = chi2
        if J is not None:
            JW = J.T @ Winv
            A = JW @ J
            b = JW @ r
        if prior is not None:
            rp, Jp = _up_residual(rvec, *prior)
            cost += float(rp @ rp)
            if J is not None:
                A[:3, :3] += Jp.T @ Jp
                b[:3] -= Jp.T @ rp
        if cost <= best_cost:
            best_cost, best_chi2, best_rt = cost, chi2, (rvec, tvec)
            if J is not None:
                info = A
            best_sq = float((d * d).sum())
            best_d = d
            lam = max(lam * 0.1, 1e-9)
        else:  # worse: back to the best, damp more
            rvec, tvec = best_rt
            lam *= 100.0
            continue
        if it == iterations:
            break
        A_d = A.copy()
        A_d.flat[::7] *= 1.0 + lam
        ok, step = cv2.solve(A_d, b.reshape(6, 1), flags=cv2.DECOMP_CHOLESKY)
        if not ok:
            ok, step = cv2.solve(A_d, b.reshape(6, 1), flags=cv2.DECOMP_SVD)
            if not ok:
                break
        step = step.ravel()
        if (float(np.abs(step[:3]).max()) < 1e-9
                and float(np.abs(step[3:]).max()) < 1e-9 * (1.0 + float(np.abs(tvec).max()))):
            break  # converged: the next point would be this one
        rvec = rvec + step[:3]
        tvec = tvec + step[3:]
    n = len(obj)
    out = PoseCandidate(best_rt[0].copy(), best_rt[1].copy(), math.sqrt(best_sq / n), best_chi2)
    if best_d is not None:
        out.__dict__["_residual"] = best_d  # (N, 2) image - projection, px (for the weights)
    return out, np.zeros((6, 6)) if info is None else info   # None: no finite cost at all


def _robust_weights(obj, img, cand: PoseCandidate, camera: Camera, Winv: np.ndarray,
                    k: float) -> np.ndarray:
    """Huber weights (N,) of the points at a pose: 1 for a point whose reprojection residual
    is within ``k`` standard deviations of its own covariance (the 2×2 block of the inverse
    of ``Winv``), ``k / d`` for one ``d > k`` away."""
    r = cand.__dict__.get("_residual")
    if r is None:
        px, _ = camera.project_points(obj.reshape(-1, 1, 3), cand.rvec, cand.tvec)
        r = img - px.reshape(-1, 2)
    rr = r.ravel()
    if not float(rr @ Winv @ rr) > k * k:
        # a point's own Mahalanobis distance is at most the whole residual's (a marginal
        # of a Gaussian): nothing to weigh down, no inversion
        return np.ones(len(obj))
    ok, C = cv2.invert(Winv, flags=cv2.DECOMP_CHOLESKY)
    if not ok:
        return np.ones(len(obj))
    n = len(obj)
    blocks = C.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n), :]  # (n, 2, 2)
    a, b, d = blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 1, 1]
    det = a * d - b * b
    x, y = r[:, 0], r[:, 1]
    m = np.where(det > 0, (d * x * x - 2 * b * x * y + a * y * y) / np.where(det > 0, det, 1),
                 0.0)
    dist = np.sqrt(np.maximum(m, 0.0))
    return np.where(dist > k, k / np.maximum(dist, 1e-12), 1.0)


def _point_distances(obj, img, cand: PoseCandidate, camera: Camera, Winv: np.ndarray
                     ) -> np.ndarray | None:
    """Squared Mahalanobis distance (N,) of each point's reprojection residual at a pose, by
    its own 2×2 covariance (the diagonal block of the inverse of ``Winv``); None when
    ``Winv`` is not invertible."""
    n = len(obj)
    px, _ = camera.project_points(obj.reshape(-1, 1, 3), cand.rvec, cand.tvec)
    r = img - px.reshape(-1, 2)
    ok, C = cv2.invert(Winv, flags=cv2.DECOMP_CHOLESKY)
    if not ok:
        return None
    blocks = C.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n), :]  # (n, 2, 2)
    a, b, d = blocks[:, 0, 0], blocks[:, 0, 1], blocks[:, 1, 1]
    det = a * d - b * b
    x, y = r[:, 0], r[:, 1]
    return np.where(det > 0, (d * x * x - 2 * b * x * y + a * y * y)
                    / np.where(det > 0, det, 1.0), 0.0)


def _group_outliers(m: np.ndarray, groups: np.ndarray, dof: int) -> np.ndarray:
    """Which groups of points (codes) to leave out of a pose: those with a point beyond
    what the brick's own residuals allow. Returns a weight per point (N,), 0 or 1.

    Huber weights (:func:`_robust_weights`) bound a wrong corner's pull but keep it at
    ``ROBUST_K`` standard deviations: a code fitted to the wrong edges (its corners 1-4 px
    off on a 19-px code) still moved a two-code brick's pose by a centimetre through a
    fisheye's rim. Its other corners share its wrong homography, so the whole code goes.
    The noise scale is measured robustly from the brick itself (the median squared distance
    against χ²(2)'s, 1.386, corrected for the fitted parameters; never below the assumed
    noise); the limit is the χ²(2) quantile a right point exceeds with chance 0.1 % over the
    brick's points, ``2 ln(N / 0.001)``. At least one group always stays.

    Args:
        m: (N,) squared Mahalanobis distances of the points (:func:`_point_distances`).
        groups: (N,) group label of each point (the code it belongs to).
        dof: Degrees of freedom of the fit (2N − 6).
    """
    n = len(m)
    s2 = max(1.0, float(np.median(m)) / 1.386 * (2.0 * n / max(dof, 1)))
    bad_pts = m / s2 > 2.0 * math.log(n / 0.001)
    if not bad_pts.any():
        return np.ones(n)
    labels, inv = np.unique(groups, return_inverse=True)
    bad = np.zeros(len(labels), bool)
    np.logical_or.at(bad, inv, bad_pts)
    if bad.all():   # nothing to tell the pose from: keep everything
        return np.ones(n)
    return np.where(bad[inv], 0.0, 1.0)


def _covariance(info: np.ndarray, chi2: float, dof: int) -> np.ndarray:
    """(Jᵀ Σ⁻¹ J)⁻¹, inflated by χ²/dof when the residuals show more noise than assumed."""
    ok, cov = cv2.invert(info, flags=cv2.DECOMP_CHOLESKY)
    if not ok:  # not positive definite (a degenerate view): the pseudo-inverse
        cov = np.linalg.pinv(info)
    if dof > 0 and chi2 / dof > 1.0:
        cov = cov * (chi2 / dof)
    return 0.5 * (cov + cov.T)


def _measured_scale(obj, img, cand: PoseCandidate, camera: Camera, Winv: np.ndarray,
                    dof: int) -> float:
    """The point noise the best candidate's residuals show, as a factor on the assumed
    variance (:func:`drovisio.pose.ambiguity.noise_scale`)."""
    if dof < MIN_DOF_FOR_SCALE:
        return 1.0
    px, _ = camera.project_points(obj.reshape(-1, 1, 3), cand.rvec, cand.tvec)
    r = (px.reshape(-1, 2) - img).ravel()
    try:  # whitened: e = Lᵀ r with L Lᵀ = Winv, so |e|² = χ²
        e = np.linalg.cholesky(Winv).T @ r
    except np.linalg.LinAlgError:
        return 1.0
    return noise_scale(e, dof)


def solve_brick_pose(object_pts: np.ndarray, image_pts: np.ndarray, camera: Camera,
                     gravity: np.ndarray | None = None, planar: bool | None = None, *,
                     image_pts_norm: np.ndarray | None = None,
                     points_cov: np.ndarray | None = None, default_sigma_px: float = 0.2,
                     points_info: np.ndarray | None = None,
                     up_axis=(0.0, 0.0, 1.0), evidence: PoseEvidence | None = None,
                     rule: AmbiguityRule = AmbiguityRule(),
                     gravity_prior_deg: float | None = None,
                     refine: bool = True,
                     point_groups: np.ndarray | None = None) -> PoseResult | None:
    """Pose of an object from ≥ 4 point correspondences, flip ambiguity resolved with evidence.

    Args:
        object_pts: (N, 3) points in the object (brick) frame, metres.
        image_pts: (N, 2) their measured positions, distorted pixels.
        camera: The calibrated camera.
        gravity: Unit gravity vector in the camera frame (shortcut for
            ``evidence.gravity``).
        planar: Whether the points are coplanar (None: decide from the points).
        image_pts_norm: (N, 2) the same points undistorted and normalised, if already known
            (saves the undistortion).
        points_cov: Noise of the image points: a scalar sigma (px), (N,) sigmas, or a
            (2N, 2N) covariance in the order x0, y0, x1, y1, ... None: ``default_sigma_px``.
        default_sigma_px: Image point noise when ``points_cov`` is None.
        points_info: (2N, 2N) inverse covariance of the image points, instead of
            ``points_cov`` (saves an inversion when the caller has it).
        up_axis: The object axis that points up when it lies flat (for gravity).
        evidence: Gravity, reference up, previous pose (see :class:`PoseEvidence`).
        rule: The ambiguity rule's numbers (:class:`~drovisio.pose.ambiguity.AmbiguityRule`).
        gravity_prior_deg: With gravity known, also pull the chosen pose toward lying flat
            (its ``up_axis`` along −gravity) with this standard deviation (a soft prior:
            strong image evidence wins; None or 0: gravity only chooses between candidates).
            Applied only when the pose is within ``gravity_tol_deg`` of flat.
        refine: Refine in pixels (weighted Gauss–Newton through the full lens model).
        point_groups: (N,) which measurement each point comes from (e.g. the code index of
            each corner): with two groups or more, a group with a point far beyond the
            brick's measured noise is left out of the final refinement
            (:func:`_group_outliers`).

    Returns:
        The :class:`PoseResult`, or None when no pose in front of the camera fits.
    """
    obj = np.ascontiguousarray(np.asarray(object_pts, np.float64).reshape(-1, 3))
    img = np.ascontiguousarray(np.asarray(image_pts, np.float64).reshape(-1, 2))
    n = len(obj)
    if n < 4 or len(img) != n:
        raise ValueError(f"need at least 4 matching points, got {n} object and {len(img)} "
                         "image points")
    groups = None if point_groups is None else np.asarray(point_groups).ravel()
    if groups is not None and len(groups) != n:
        raise ValueError(f"point_groups has {len(groups)} labels for {n} points")
    ev = evidence if evidence is not None else PoseEvidence()
    if gravity is not None:
        ev = PoseEvidence(np.asarray(gravity, np.float64), ev.reference_up, ev.previous)
    if planar is None:
        planar = is_planar(obj)
    xn = (np.asarray(image_pts_norm, np.float64).reshape(-1, 2) if image_pts_norm is not None
          else camera.normalize(img))
    if not np.all(np.isfinite(xn)):
        return None
    Winv = (np.asarray(points_info, np.float64) if points_info is not None
            else _sigma_inv(points_cov, n, default_sigma_px))
    I3 = np.eye(3)
    rvecs: list = []
    tvecs: list = []
    Rs: list[np.ndarray] = []
    errs: list = []
    er = None
    try:
        if planar:
            # OpenCV's IPPE is only right for points on z = 0: solve in the points' plane
            Rp, c = _plane_frame(obj)
            plane_pts = (obj - c) @ Rp
            _, rv, tv, er = cv2.solvePnPGeneric(plane_pts.reshape(-1, 1, 3),
                                                xn.reshape(-1, 1, 2), I3, None,
                                                flags=cv2.SOLVEPNP_IPPE)
            identity = Rp is _EYE3
            for r, t_ in zip(rv, tv):
                R = cv2.Rodrigues(r)[0]
                if not identity:
                    R = R @ Rp.T
                    r = cv2.Rodrigues(R)[0]
                rvecs.append(r)
                Rs.append(R)
                tvecs.append(np.ravel(t_) - R @ c)
        else:
            _, rv, tv, er = cv2.solvePnPGeneric(obj.reshape(-1, 1, 3), xn.reshape(-1, 1, 2),
                                                I3, None, flags=cv2.SOLVEPNP_SQPNP)
            rvecs, tvecs = list(rv), list(tv)
        errs = list(np.ravel(er)) if er is not None else [np.nan] * len(rvecs)
    except cv2.error:
        rvecs, tvecs = [], []
    # IPPE's RMS error is in normalised units: ~pixels / focal length (enough to tell a
    # candidate that does not fit at all); χ² is computed only where the fit must decide
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    cands = []
    for i, (r, t, e) in enumerate(zip(rvecs, tvecs, errs)):
        if float(np.ravel(t)[2]) <= 0:
            continue
        cand = PoseCandidate(np.ravel(r).astype(np.float64), np.ravel(t).astype(np.float64),
                             float(e) * f if np.isfinite(e) else float("inf"), float("nan"))
        if i < len(Rs):
            cand.__dict__["_R"] = Rs[i]
        cands.append(cand)
    if not cands:
        try:
            ok, r, t = cv2.solvePnP(obj.reshape(-1, 1, 3), xn.reshape(-1, 1, 2), I3, None,
                                    flags=cv2.SOLVEPNP_ITERATIVE)
        except cv2.error:
            ok = False
        if not ok or float(np.ravel(t)[2]) <= 0:
            return None
        cands = [_candidate(obj, img, r, t, camera, Winv)]
    dof = 2 * n - 6
    cands.sort(key=lambda c: c.rmse_px)
    up = np.asarray(up_axis, np.float64)
    chosen: int | None
    if len(cands) == 1:
        chosen, decided_by = 0, "unique"
    else:
        cands = cands[:2]
        prev = None if ev.previous is None else cv2.Rodrigues(
            np.asarray(ev.previous[0], np.float64).reshape(3, 1))[0]

        def decide(use_evidence: bool, use_fit: bool, scale: float = 1.0
                   ) -> tuple[int | None, str]:
            R2 = np.stack([c.R for c in cands])[None]
            chi2 = np.array([[c.chi2 for c in cands]])
            rmse = np.array([[c.rmse_px for c in cands]])
            pick, why = decide_flips(R2, chi2, dof, gravity=ev.gravity,
                                     reference_up=ev.reference_up,
                                     previous=None if prev is None else [prev], up_axis=up,
                                     rule=rule, rmse_px=rmse, use_evidence=use_evidence,
                                     use_fit=use_fit, scale=scale)
            return (int(pick[0]), why[0]) if pick[0] >= 0 else (None, "")

        # evidence first (it needs no refinement: flips differ by tens of degrees), then the
        # reprojection on refined candidates
        chosen, decided_by = decide(True, False)
        if chosen is None:
            cands = sorted((_gauss_newton(obj, img, c, camera, Winv,
                                          iterations=1 if refine else 0)[0]
                            for c in cands), key=lambda c: c.chi2)
            chosen, decided_by = decide(False, True,
                                        _measured_scale(obj, img, cands[0], camera, Winv, dof))
    if chosen is None:  # undecided: report the better-fitting one, flag it
        chosen, amb, decided_by = 0, True, "none"
    else:
        amb = False
    best = cands[chosen]
    others = [c for i, c in enumerate(cands) if i != chosen]
    prior = None
    if (ev.gravity is not None and gravity_prior_deg and not amb
            and tilt_deg(best.R, ev.gravity, up) <= rule.gravity_tol_deg):
        prior = (up, np.asarray(ev.gravity, np.float64), math.radians(gravity_prior_deg))
    # IPPE's solution from exact normalised coordinates is already close to the pixel-space
    # optimum: one Gauss–Newton step gets it (the prior is nearly linear as well)
    start = best
    best, info = _gauss_newton(obj, img, start, camera, Winv,
                               iterations=REFINE_ITERATIONS if refine else 0, prior=prior)
    if prior is not None and not best.rmse_px <= 3.0 * start.rmse_px + 1.0:
        # the prior outweighed the image (poorly known corners of a small code seen
        # square-on): a flat pose that no longer fits is no answer; the image's own is
        prior = None
        best, info = _gauss_newton(obj, img, start, camera, Winv,
                                   iterations=REFINE_ITERATIONS if refine else 0)
    if refine and n >= ROBUST_MIN_POINTS:
        # a corner far outside its own covariance (a code's fit caught on its surroundings)
        # pulls a least-squares pose by all of its error: Huber weights in the image, from
        # each point's own covariance, re-weighted twice
        for _ in range(2):
            w = _robust_weights(obj, img, best, camera, Winv, ROBUST_K)
            if w.min() >= 1.0:
                break
            sw = np.repeat(np.sqrt(w), 2)
            best, info = _gauss_newton(obj, img, best, camera, Winv * sw[:, None] * sw[None, :],
                                       iterations=REFINE_ITERATIONS, prior=prior)
        m = (None if groups is None or len(np.unique(groups)) < 2
             else _point_distances(obj, img, best, camera, Winv))
        if groups is not None and m is not None:
            w = _group_outliers(m, groups, dof)
            if w.min() < 1.0:
                # the pose moves by the wrong code's whole pull: two steps, not one
                sw = np.repeat(w, 2)
                best, info = _gauss_newton(obj, img, best, camera,
                                           Winv * sw[:, None] * sw[None, :],
                                           iterations=2, prior=prior)
                dof = int(2 * w.sum()) - 6
    return PoseResult(best.rvec, best.tvec, best.rmse_px, _covariance(info, best.chi2, dof),
                      amb, others if amb else [], decided_by, [best] + others)


