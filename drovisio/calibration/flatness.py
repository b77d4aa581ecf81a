"""How flat the calibration board was: mrcal's board warp, solved with the intrinsics.

A printed board glued to cardboard bows by a millimetre or two; a calibration that takes it
for flat explains the bow with the lens (the focal length and the radial terms absorb it).
mrcal solves a board "warp" with the intrinsics; so does this, on the kept views: the board
points are moved off their plane by a parabolic bow along each side,

    z(x, y) = w_x·(1 − u²) + w_y·(1 − v²),   u, v ∈ [−1, 1] across the board's points,

so ``w_x`` is how far the middle of the board stands off the line through its left and right
edges (metres; positive toward +z of the board's frame, away from a camera that sees its
front), and the intrinsics, every view's pose and (w_x, w_y) are fitted together by
Levenberg–Marquardt from the flat solve (the projection's derivatives are OpenCV's). The bow's
standard errors come from the fit's covariance. OpenCV's own free-board solve
(``calibrateCameraRO``) would ask the same more generally, but OpenCV 5's calibration refuses
it, and its hundreds of free points need many more views.

Reported, never applied: the written camera is the flat board's solve; a significant bow is a
reason to flatten the board and calibrate again. Not for the fisheye model (its projection's
derivatives come in another form) or views with fewer than 6 board points.
"""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.calibration.uncertainty import param_names
from drovisio.camera import Camera

__all__ = ["board_flatness"]

#: a bow this many standard errors from zero is reported as real
SIGNIFICANCE = 3.0


def _not_computed(reason: str) -> dict:
    return {"computed": False, "reason": reason}


def _bow_basis(obj: np.ndarray, extent: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(N, 2) the bow's shape along x and y at board points (N, 3)."""
    lo, hi = extent
    u = 2.0 * (obj[:, 0] - lo[0]) / max(hi[0] - lo[0], 1e-12) - 1.0
    v = 2.0 * (obj[:, 1] - lo[1]) / max(hi[1] - lo[1], 1e-12) - 1.0
    return np.stack([1.0 - u * u, 1.0 - v * v], axis=1)


def _residuals(views, intr: np.ndarray, poses: np.ndarray, w: np.ndarray, extent,
               n_dist: int):
    """Stacked residuals (projected − detected) per view, their sum of squares, and the
    Jacobian's blocks per view: intrinsics, poses, bow."""
    K = np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1.0]])
    d = intr[4:4 + n_dist]
    res, JI, JP, JW = [], [], [], []
    for i, v in enumerate(views):
        obj = np.asarray(v.object_points, np.float64).reshape(-1, 3)
        B = _bow_basis(obj, extent)
        pts = obj.copy()
        pts[:, 2] += B @ w
        r, t = poses[i, :3].reshape(3, 1), poses[i, 3:].reshape(3, 1)
        px, J = cv2.projectPoints(pts.reshape(-1, 1, 3), r, t, K, d)
        res.append((px.reshape(-1, 2) - np.asarray(v.corners, np.float64).reshape(-1, 2))
                   .ravel())
        J = np.asarray(J, np.float64)
        JP.append(J[:, 0:6])
        JI.append(J[:, 6:10 + n_dist])
        # d px / d w = d px / d X_cam · R · d P / d w, and d px / d X_cam = d px / d t
        R = cv2.Rodrigues(r)[0]
        dXdw = R[:, 2:3] * B[:, None, :]          # (N, 3, 2): only z moves
        JW.append(np.einsum("nij,njk->nik", J[:, 3:6].reshape(-1, 2, 3), dXdw)
                  .reshape(-1, 2))
    return res, float(sum((x * x).sum() for x in res)), JI, JP, JW


def board_flatness(views, camera: Camera, model: str, rms_px: float, fits,
                   fx_std_px: float, min_views: int = 6, iterations: int = 20) -> dict:
    """The board's bow, fitted with the intrinsics and poses from the flat solve.

    Args:
        views: The kept views (:class:`drovisio.calibration.solve.ViewInput`), board points
            in metres, the board in its z = 0 plane.
        camera: The flat board's solved camera (the start).
        model: The calibration's model name (:func:`drovisio.calibration.uncertainty.
            lens_key`).
        rms_px: The flat board's solve's RMS (reported beside the bowed board's).
        fits: The flat solve's per-view fits (their poses start the fit).
        fx_std_px: The flat solve's standard deviation of fx: a bow matters when it moves fx
            by more than twice that.
        min_views: Fewer views than this: not computed.
        iterations: Levenberg–Marquardt iterations at most.

    Returns:
        ``{"computed": True, "warp_x_mm", "warp_y_mm", "warp_std_mm": [x, y],
        "fx_shift_pct", "rms_px_flat", "rms_px_bowed", "significant", "matters",
        "summary"}``, or
        ``{"computed": False, "reason"}``.

    Raises:
        ValueError: ``iterations`` below 1 (the covariance comes from the last iteration's
            normal equations).
    """
    if iterations < 1:
        raise ValueError(f"board_flatness: iterations {iterations}, at least 1")
    if model == "fisheye":
        return _not_computed("not for the fisheye model")
    if len(views) < min_views:
        return _not_computed(f"{len(views)} views; the bow needs {min_views}")
    allp = np.concatenate([np.asarray(v.object_points, np.float64).reshape(-1, 3)
                           for v in views])
    if np.ptp(allp[:, 2]) > 0:
        return _not_computed("the board points are not in one plane")
    extent = (allp.min(axis=0), allp.max(axis=0))
    if np.any(extent[1][:2] - extent[0][:2] <= 0):
        return _not_computed("the board points are not a flat grid")
    n_dist = len(param_names(model)) - 4
    intr = np.zeros(4 + n_dist)
    intr[:4] = camera.fx, camera.fy, camera.cx, camera.cy
    intr[4:4 + min(n_dist, camera.dist.size)] = camera.dist[:n_dist]
    poses = np.array([np.concatenate([f.rvec, f.tvec]) for f in fits], np.float64)
    w = np.zeros(2)
    nV, nI = len(views), intr.size
    lam = 1e-3
    try:
        cur = _residuals(views, intr, poses, w, extent, n_dist)
        for _ in range(iterations):
            res, cost, JI, JP, JW = cur
            A, g = _normal_equations(res, JI, JP, JW, nI)
            D = np.diag(np.diag(A)) + 1e-12 * np.eye(len(A))
            try:
                step = -np.linalg.solve(A + lam * D, g)
            except np.linalg.LinAlgError:
                break
            intr_n, w_n = intr + step[:nI], w + step[nI:nI + 2]
            poses_n = poses + step[nI + 2:].reshape(nV, 6)
            trial = _residuals(views, intr_n, poses_n, w_n, extent, n_dist)
            if np.isfinite(trial[1]) and trial[1] <= cost:
                done = cost - trial[1] < 1e-10 * max(cost, 1e-30)
                intr, poses, w, cur = intr_n, poses_n, w_n, trial
                lam = max(lam / 5.0, 1e-9)
                if done:
                    break
            else:
                lam *= 10.0
    except cv2.error as e:  # a pose or a coefficient OpenCV cannot project with
        return _not_computed(f"the fit failed ({str(e).strip().splitlines()[-1][:80]})")
    res, cost = cur[0], cur[1]
    n_obs = sum(r.size for r in res)
    dof = max(n_obs - (nI + 2 + 6 * nV), 1)
    sigma2 = cost / dof
    try:
        cov = np.linalg.inv(A + 1e-12 * np.eye(len(A))) * sigma2
        std = np.sqrt(np.clip(np.diag(cov)[nI:nI + 2], 0.0, None))
    except np.linalg.LinAlgError:
        return _not_computed("the bow cannot be told apart from the lens on these views")
    wx, wy = float(w[0]), float(w[1])
    if not np.all(np.isfinite([wx, wy, *std])):
        return _not_computed("the fit diverged")
    significant = bool(abs(wx) > SIGNIFICANCE * std[0] or abs(wy) > SIGNIFICANCE * std[1])
    shift = (camera.fx - float(intr[0])) / float(intr[0])
    matters = significant and abs(camera.fx - float(intr[0])) > 2.0 * fx_std_px

    summary = _summary(wx, wy, std, shift, fx_std_px / camera.fx, significant, matters)
    return {"computed": True, "warp_x_mm": wx * 1000, "warp_y_mm": wy * 1000,
            "warp_std_mm": [float(std[0]) * 1000, float(std[1]) * 1000],
            "fx_shift_pct": shift * 100, "rms_px_flat": float(rms_px),
            "rms_px_bowed": float(np.sqrt(cost / (n_obs / 2))),
            "significant": significant, "matters": bool(matters), "summary": summary}


def _normal_equations(res: list[np.ndarray], JI: list[np.ndarray], JP: list[np.ndarray],
                      JW: list[np.ndarray], nI: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Newton's normal equations (A, g) over (intrinsics (nI), bow (2), poses (6 per
    view)); dense: a few hundred unknowns."""
    nV = len(res)
    P = nI + 2 + 6 * nV
    A = np.zeros((P, P))
    g = np.zeros(P)
    for i in range(nV):
        Jg = np.concatenate([JI[i], JW[i]], axis=1)
        sl = slice(nI + 2 + 6 * i, nI + 8 + 6 * i)
        A[:nI + 2, :nI + 2] += Jg.T @ Jg
        A[:nI + 2, sl] += Jg.T @ JP[i]
        A[sl, sl] += JP[i].T @ JP[i]
        g[:nI + 2] += Jg.T @ res[i]
        g[sl] += JP[i].T @ res[i]
    A[nI + 2:, :nI + 2] = A[:nI + 2, nI + 2:].T
    return A, g


def _summary(wx: float, wy: float, std: np.ndarray, shift: float, fx_rel_std: float,
             significant: bool, matters: bool) -> str:
    """The bow in one sentence: its size (metres in, millimetres said) and whether it moves
    the focal length (``shift``, relative) beyond its uncertainty (``fx_rel_std``)."""
    def mm(m: float) -> str:
        return f"{m * 1000:.2f} mm"

    bow = (f"{mm(wx)} along its width and {mm(wy)} along its height (± {mm(std[0])}, "
           f"{mm(std[1])})")
    if matters:
        return (f"the board bows by {bow}; taking it for flat moves the focal length by "
                f"{shift * 100:+.2f} %, more than its uncertainty ({fx_rel_std * 100:.2f} %"
                "): glue the print to something flat and calibrate again")
    if significant:
        return (f"the board bows by {bow}: measurable, but it moves the focal length by "
                f"{shift * 100:+.2f} % only, within its uncertainty "
                f"({fx_rel_std * 100:.2f} %)")
    return f"the board is flat within the measurement (bow {bow})"
