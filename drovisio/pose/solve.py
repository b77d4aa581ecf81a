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

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.pose.ambiguity import AmbiguityRule, PoseEvidence, decide_flips
from drovisio.pose.candidate import PoseCandidate, PoseResult
from drovisio.pose.measures import is_planar, tilt_deg
from drovisio.pose.refine import (
    gauss_newton,
    group_outliers,
    measured_scale,
    point_distances,
    points_information,
    pose_covariance,
    robust_weights,
)

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


def _candidate(obj, img, rvec, tvec, camera, Winv) -> PoseCandidate:
    px, _ = camera.project_points(obj, rvec, tvec)
    r = (px - img).ravel()
    return PoseCandidate(np.asarray(rvec, np.float64).ravel().copy(),
                         np.asarray(tvec, np.float64).ravel().copy(),
                         float(np.sqrt(np.mean(np.sum((px - img) ** 2, axis=1)))),
                         float(r @ Winv @ r))


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
            (:func:`~drovisio.pose.refine.group_outliers`).

    Returns:
        The :class:`PoseResult`, or None when no pose in front of the camera fits.
    """
    obj, img, groups = _checked_points(object_pts, image_pts, point_groups)
    n = len(obj)
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
            else points_information(points_cov, n, default_sigma_px))
    cands = _initial_candidates(obj, img, xn, camera, Winv, planar)
    if not cands:
        return None
    dof = 2 * n - 6
    cands.sort(key=lambda c: c.rmse_px)
    up = np.asarray(up_axis, np.float64)
    cands, chosen, decided_by = _choose(obj, img, cands, camera, Winv, ev, up, rule, dof,
                                        refine)
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
    best, info, prior = _refine(obj, img, best, camera, Winv, prior, refine)
    if refine and n >= ROBUST_MIN_POINTS:
        best, info, dof = _refine_robust(obj, img, best, info, camera, Winv, groups, prior,
                                         dof)
    return PoseResult(best.rvec, best.tvec, best.rmse_px, pose_covariance(info, best.chi2, dof),
                      amb, others if amb else [], decided_by, [best] + others)


def _checked_points(object_pts: np.ndarray, image_pts: np.ndarray,
                    point_groups: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The points as contiguous (N, 3) and (N, 2) float64 arrays and the (N,) group labels.

    Raises:
        ValueError: fewer than 4 points, or counts that do not match.
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
    return obj, img, groups


def _initial_candidates(obj: np.ndarray, img: np.ndarray, xn: np.ndarray, camera: Camera,
                        Winv: np.ndarray, planar: bool) -> list[PoseCandidate]:
    """The candidates in front of the camera: IPPE's two (planar points) or SQPnP's one,
    from the normalised points ``xn`` (N, 2); OpenCV's iterative solve when neither gives
    one. Empty when no pose in front of the camera fits."""
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
    if cands:
        return cands
    try:
        ok, r, t = cv2.solvePnP(obj.reshape(-1, 1, 3), xn.reshape(-1, 1, 2), I3, None,
                                flags=cv2.SOLVEPNP_ITERATIVE)
    except cv2.error:
        ok = False
    if not ok or float(np.ravel(t)[2]) <= 0:
        return []
    return [_candidate(obj, img, r, t, camera, Winv)]


def _choose(obj: np.ndarray, img: np.ndarray, cands: list[PoseCandidate], camera: Camera,
            Winv: np.ndarray, ev: PoseEvidence, up: np.ndarray, rule: AmbiguityRule, dof: int,
            refine: bool) -> tuple[list[PoseCandidate], int | None, str]:
    """The candidate to keep, by :func:`~drovisio.pose.ambiguity.decide_flips`: the evidence
    first (it needs no refinement: flips differ by tens of degrees), then the reprojection
    on refined candidates.

    Returns:
        (the candidates, at most two, refined when the fit decided; the index of the chosen
        one or None when nothing decides; what decided).
    """
    if len(cands) == 1:
        return cands, 0, "unique"
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

    chosen, decided_by = decide(True, False)
    if chosen is None:
        cands = sorted((gauss_newton(obj, img, c, camera, Winv,
                                     iterations=1 if refine else 0)[0]
                        for c in cands), key=lambda c: c.chi2)
        chosen, decided_by = decide(False, True,
                                    measured_scale(obj, img, cands[0], camera, Winv, dof))
    return cands, chosen, decided_by


def _refine(obj: np.ndarray, img: np.ndarray, start: PoseCandidate, camera: Camera,
            Winv: np.ndarray, prior: tuple[np.ndarray, np.ndarray, float] | None,
            refine: bool) -> tuple[PoseCandidate, np.ndarray,
                                   tuple[np.ndarray, np.ndarray, float] | None]:
    """The chosen candidate refined in pixels, with the flat-lying ``prior`` unless it
    outweighed the image.

    Returns:
        (refined candidate, its 6×6 information matrix, the prior kept or None).
    """
    # IPPE's solution from exact normalised coordinates is already close to the pixel-space
    # optimum: one Gauss–Newton step gets it (the prior is nearly linear as well)
    best, info = gauss_newton(obj, img, start, camera, Winv,
                              iterations=REFINE_ITERATIONS if refine else 0, prior=prior)
    if prior is not None and not best.rmse_px <= 3.0 * start.rmse_px + 1.0:
        # the prior outweighed the image (poorly known corners of a small code seen
        # square-on): a flat pose that no longer fits is no answer; the image's own is
        prior = None
        best, info = gauss_newton(obj, img, start, camera, Winv,
                                  iterations=REFINE_ITERATIONS if refine else 0)
    return best, info, prior


def _refine_robust(obj: np.ndarray, img: np.ndarray, best: PoseCandidate, info: np.ndarray,
                   camera: Camera, Winv: np.ndarray, groups: np.ndarray | None,
                   prior: tuple[np.ndarray, np.ndarray, float] | None, dof: int
                   ) -> tuple[PoseCandidate, np.ndarray, int]:
    """Huber weights, then whole codes (``groups``) left out that disagree with the brick.

    Returns:
        (refined candidate, its information matrix, the degrees of freedom left).
    """
    # a corner far outside its own covariance (a code's fit caught on its surroundings)
    # pulls a least-squares pose by all of its error: Huber weights in the image, from
    # each point's own covariance, re-weighted twice
    for _ in range(2):
        w = robust_weights(obj, img, best, camera, Winv, ROBUST_K)
        if w.min() >= 1.0:
            break
        sw = np.repeat(np.sqrt(w), 2)
        best, info = gauss_newton(obj, img, best, camera, Winv * sw[:, None] * sw[None, :],
                                  iterations=REFINE_ITERATIONS, prior=prior)
    m = (None if groups is None or len(np.unique(groups)) < 2
         else point_distances(obj, img, best, camera, Winv))
    if groups is not None and m is not None:
        w = group_outliers(m, groups, dof)
        if w.min() < 1.0:
            # the pose moves by the wrong code's whole pull: two steps, not one
            sw = np.repeat(w, 2)
            best, info = gauss_newton(obj, img, best, camera,
                                      Winv * sw[:, None] * sw[None, :],
                                      iterations=2, prior=prior)
            dof = int(2 * w.sum()) - 6
    return best, info, dof
