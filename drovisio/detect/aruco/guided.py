"""Guided codes: a brick's codes that were not read, fitted where its pose puts them.

A brick posed from fewer codes than its layout carries (a drick seen from one 65 mm code)
has a baseline of one code: its range, lateral position and yaw are only as good as four
corners a few pixels apart. Its other codes are often in view but not read (small, oblique,
blurred at a fisheye's rim). Their place is known: the layout's code corners projected with
the brick's pose through the lens model, to within the pose's uncertainty. Each such
prediction that faces the camera, lies inside the image, is not covered by a code that was
read, and is big enough to fit, is fitted by the same photometric corner fit as every read
code (:func:`drovisio.detect.corners.refine_codes`), from the predicted corners, with the
bits its id must carry: nothing is decoded. It is accepted only if

* the fit is ``ok`` with every inner cell reading as the expected bit (no misread or
  undecided cell tolerated: there is no independent decode behind it), and
* its corners lie where the pose said they would, within the pose's own uncertainty: the
  squared Mahalanobis distance between fitted and predicted corners, under the sum of the
  predicted corners' covariance (``J C Jᵀ``, ``C`` the pose's covariance, ``J`` the lens
  model's Jacobian) and the fit's own covariance, both with the corners' unmodelled error
  (a share of the fitted blur: :func:`_blur_covariance`), is χ²(8) at a chance of at least
  :attr:`~drovisio.detect.aruco.params.ArucoParams.guided_chance`.

The fit converges on a code only from a start within about half a cell of it, and a pose
from one small code predicts the other to a pixel or two: more than half a 2.5-px cell. A
code whose fit from the predicted corners fails these checks is fitted again from the
predicted quad shifted in half-cell steps over the uncertainty of the code's centre, as far
as the prediction's covariance reaches (:func:`start_shifts`); of those fits that pass the
checks, the one nearest the prediction (least Mahalanobis distance) is taken.

An ambiguous brick is predicted with each of its planar candidates; the first whose
prediction fits is taken. Accepted codes carry ``guided=True``; the brick is then solved
again from all its codes by the same solver (weights, ambiguity, covariance).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.detect.aruco.codes import BrickKey, CodeDetection
from drovisio.detect.aruco.corner_fit import corner_covariance
from drovisio.detect.aruco.families import CodeFamily
from drovisio.detect.aruco.params import ArucoParams
from drovisio.detect.corners import RefinedCode, refine_codes
from drovisio.layout import MarkerLayout, aruco_code_bits
from drovisio.pose import PoseResult

__all__ = ["GuidedPrediction", "chi2_8_chance", "guided_codes", "predict_missing",
           "start_shifts"]

Solved = tuple[PoseResult, list[CodeDetection]]


@dataclass
class GuidedPrediction:
    """Where a brick's unread code should be.

    Args:
        key: The brick.
        marker_id: The code's id.
        slot: Its slot in the layout.
        layout: The brick's layout.
        instance: The brick's instance.
        corners_px: (4, 2) predicted corners TL, TR, BR, BL, distorted px.
        cov_px: (8, 8) covariance of ``corners_px.ravel()`` from the pose's covariance, px².
    """

    key: BrickKey
    marker_id: int
    slot: int
    layout: MarkerLayout
    instance: int
    corners_px: np.ndarray
    cov_px: np.ndarray


def chi2_8_chance(x: float) -> float:
    """Chance that a χ² variable with 8 degrees of freedom exceeds ``x`` (closed form for
    an even number of degrees of freedom: ``exp(−x/2) Σₖ₌₀³ (x/2)ᵏ / k!``)."""
    h = 0.5 * max(float(x), 0.0)
    return float(np.exp(-h) * (1.0 + h + h * h / 2.0 + h ** 3 / 6.0))


def _facing(R: np.ndarray, t: np.ndarray, corners_m: np.ndarray, normal: np.ndarray) -> bool:
    """Whether a code (corners (4, 3) and outward normal (3,) in the brick frame) lies in
    front of the camera with its printed side toward it."""
    X = corners_m @ R.T + t
    return bool(np.all(X[:, 2] > 0) and float((R @ normal) @ X.mean(axis=0)) < 0.0)


def _inside(px: np.ndarray, shape: tuple[int, int], margin: float) -> bool:
    H, W = shape
    return bool(np.all(np.isfinite(px)) and np.all(px >= margin)
                and np.all(px <= [W - 1 - margin, H - 1 - margin]))


def _min_side(px: np.ndarray) -> float:
    return float(np.sqrt(((px - np.roll(px, -1, axis=0)) ** 2).sum(axis=1)).min())


def _covered(px: np.ndarray, read: list[np.ndarray]) -> bool:
    """Whether a predicted quad overlaps a code that was read (it cannot be both)."""
    a = px.astype(np.float32)
    for q in read:
        area, _ = cv2.intersectConvexConvex(a, q.astype(np.float32))
        if area > 0:
            return True
    return False


def _candidates(res: PoseResult) -> list[tuple[np.ndarray, np.ndarray]]:
    """The poses to predict from: the chosen one, and its planar mirror(s) when the image
    could not decide."""
    poses = [(res.rvec, res.tvec)]
    if res.ambiguous:
        poses += [(c.rvec, c.tvec) for c in res.alternatives]
    return poses


def _blur_covariance(group: list[CodeDetection], corners_m: Mapping[int, np.ndarray],
                     rvec: np.ndarray, tvec: np.ndarray, camera: Camera, share: float
                     ) -> np.ndarray:
    """(6, 6) covariance of (rvec, tvec) from the read corners' unmodelled error: each
    corner off by ``share`` × its code's fitted blur (px, per axis), independently.

    The fit's covariance holds the pixel noise only; the real blur is not the model's
    separable Gaussian (motion, a defocus disc, a fisheye rim's stretched spot), and that
    shifts fitted corners by a part of the blur's width, however many pixels are fitted.
    """
    obj = np.concatenate([corners_m[c.slot] for c in group])
    var = np.repeat([(share * c.refined.blur_px) ** 2 if c.refined is not None else 0.0
                     for c in group], 8)
    _, J = camera.project_points(obj, rvec, tvec)
    try:
        return np.linalg.inv(J.T @ (J / np.maximum(var, 1e-6)[:, None]))
    except np.linalg.LinAlgError:
        return np.zeros((6, 6))


def predict_missing(key: BrickKey, res: PoseResult, group: list[CodeDetection],
                    camera: Camera, params: ArucoParams, read: list[np.ndarray],
                    corners_m: Mapping[int, np.ndarray],
                    normals: Mapping[int, np.ndarray]) -> list[list[GuidedPrediction]]:
    """Predictions of a brick's unread codes, per code the candidates' predictions.

    Args:
        key: The brick.
        res: Its pose (``camera_from_brick``) from the codes read.
        group: The codes it was solved from.
        camera: The camera.
        params: The detector's tuning (the guided group).
        read: (4, 2) corners, px, of every code read in the frame.
        corners_m: Code slot -> (4, 3) corners in the brick frame, m.
        normals: Code slot -> (3,) outward unit normal in the brick frame.

    Returns:
        Per missing code that passes the checks for at least one candidate pose, the
        predictions of the candidates that pass them (chosen pose first).
    """
    lay, inst = group[0].layout, group[0].instance
    have = {c.slot for c in group}
    shape = (camera.height, camera.width)
    out: list[list[GuidedPrediction]] = []
    for slot, obj in corners_m.items():
        if slot in have:
            continue
        preds = []
        for rvec, tvec in _candidates(res):
            R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
            if not _facing(R, np.ravel(tvec), obj, normals[slot]):
                continue
            px, J = camera.project_points(obj, rvec, tvec)
            px = px.reshape(4, 2)
            if (not _inside(px, shape, params.guided_margin_px)
                    or _min_side(px) < params.guided_min_side_px or _covered(px, read)):
                continue
            cov = res.covariance + _blur_covariance(group, corners_m, rvec, tvec, camera,
                                                    params.guided_blur_share)
            preds.append(GuidedPrediction(key, lay.marker_id(inst, slot), slot, lay, inst, px,
                                          J @ cov @ J.T))
        if preds:
            out.append(preds)
    return out


def _mahalanobis2(r: RefinedCode, pred: GuidedPrediction, params: ArucoParams) -> float:
    """Squared Mahalanobis distance of the fitted corners from the predicted ones, under both
    covariances (the prediction's, the fit's with its unmodelled share of the blur); inf
    when the fit is not ``ok`` or a cell reads wrong."""
    if not r.ok or r.cell_margin <= 0.0:
        return float("inf")
    d = (r.corners_px - pred.corners_px).ravel()
    S = (pred.cov_px + corner_covariance(r.cov_px, params)
         + np.eye(8) * (params.guided_blur_share * r.blur_px) ** 2)
    try:
        return float(d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return float("inf")


def start_shifts(pred: GuidedPrediction, cells: int, params: ArucoParams) -> np.ndarray:
    """Shifts (px) of a predicted quad that the fit starts from.

    The fit's basin is about half a cell (a start farther off aligns the model's cells with
    the wrong ones). The code's centre is uncertain by the mean of the predicted corners'
    covariance; along each principal axis of that 2×2 covariance the shifts step by half a
    cell out to ``guided_search_sigmas`` standard deviations, so that some start lies within
    the basin wherever the code is with that confidence. A prediction within the basin gets
    the single shift (0, 0).

    Args:
        pred: The prediction (its corners, px, and their (8, 8) covariance, px²).
        cells: Cells per side of the code, border included.
        params: The detector's tuning (``guided_search_sigmas``, ``guided_search_max``).

    Returns:
        (K, 2) shifts, px, the likeliest first ((0, 0)).
    """
    q = pred.corners_px
    step = 0.5 * float(np.sqrt(((q - np.roll(q, -1, axis=0)) ** 2).sum(axis=1)).mean()) / cells
    avg = np.kron(np.full((1, 4), 0.25), np.eye(2))            # (2, 8): the corners' mean
    w, V = np.linalg.eigh(avg @ pred.cov_px @ avg.T)
    k = np.floor(params.guided_search_sigmas * np.sqrt(np.maximum(w, 0.0)) / step)
    while (2 * k[0] + 1) * (2 * k[1] + 1) > params.guided_search_max:
        k[np.argmax(k)] -= 1                                   # the budget: fewer steps
    i, j = np.meshgrid(np.arange(-k[0], k[0] + 1), np.arange(-k[1], k[1] + 1), indexing="ij")
    grid = np.stack([i.ravel(), j.ravel()], axis=1) * step
    # the likeliest first: by Mahalanobis distance under the centre's covariance
    order = np.argsort(((grid ** 2) / np.maximum(w, 1e-12)).sum(axis=1), kind="stable")
    return grid[order] @ V.T


def _fit(gray: np.ndarray, camera: Camera, starts: np.ndarray, marker_ids: list[int],
         params: ArucoParams, family_of: Mapping[int, CodeFamily]) -> list[RefinedCode]:
    """The photometric corner fit from every start ((K, 4, 2) px), in one batch, with no
    tolerated cell."""
    p = params
    bits = [aruco_code_bits(family_of[m].dvalue, m).astype(np.float64) for m in marker_ids]
    return refine_codes(gray, camera, starts, bits,
                        iterations=p.refine_iterations + p.guided_coarse_iterations,
                        coarse_iterations=p.guided_coarse_iterations,
                        lm_lambda=p.refine_lambda, max_samples=p.max_samples,
                        band_px=p.band_px, outer_edge=p.outer_edge, tolerable_cells=0)


def _nearest_fits(gray: np.ndarray, camera: Camera, flat: list[GuidedPrediction],
                  shifts: list[np.ndarray], params: ArucoParams,
                  family_of: Mapping[int, CodeFamily]) -> list[RefinedCode | None]:
    """Per prediction, the fits from its quad moved by each of its ``shifts`` ((K, 2) px),
    all in one batch; of those that pass the checks, the one nearest the prediction (least
    Mahalanobis distance: the likeliest place under the pose), or None."""
    owner = np.repeat(np.arange(len(flat)), [len(d) for d in shifts])
    if not len(owner):
        return [None] * len(flat)
    starts = np.concatenate([g.corners_px[None] + d[:, None] for g, d in zip(flat, shifts)])
    fits = _fit(gray, camera, starts, [flat[n].marker_id for n in owner], params, family_of)
    best: list[RefinedCode | None] = [None] * len(flat)
    best_m2 = [float("inf")] * len(flat)
    for n, r in zip(owner, fits):
        m2 = _mahalanobis2(r, flat[n], params)
        if m2 < best_m2[n] and chi2_8_chance(m2) >= params.guided_chance:
            best[n], best_m2[n] = r, m2
    return best


def _guided_fits(gray: np.ndarray, camera: Camera, per_code: list[list[GuidedPrediction]],
                 params: ArucoParams, family_of: Mapping[int, CodeFamily]
                 ) -> list[list[RefinedCode | None]]:
    """Per code, per candidate prediction, its accepted fit or None: first from the
    predicted corners; the codes none of whose candidates fit there are fitted again from
    the shifted starts of :func:`start_shifts`."""
    flat = [g for preds in per_code for g in preds]
    zero = [np.zeros((1, 2))] * len(flat)
    first = iter(_nearest_fits(gray, camera, flat, zero, params, family_of))
    out = [[next(first) for _ in preds] for preds in per_code]
    failed = [all(f is None for f in fits) for fits in out]
    again = [g for preds, f in zip(per_code, failed) if f for g in preds]
    if again:
        shifts = [start_shifts(g, len(aruco_code_bits(family_of[g.marker_id].dvalue,
                                                      g.marker_id)), params)[1:]
                  for g in again]
        second = iter(_nearest_fits(gray, camera, again, shifts, params, family_of))
        out = [[next(second) for _ in fits] if f else fits for fits, f in zip(out, failed)]
    return out


def _predictions(results: Mapping[BrickKey, Solved], codes: list[CodeDetection],
                 camera: Camera, params: ArucoParams, family_of: Mapping[int, CodeFamily],
                 corners_m: Mapping[int, Mapping[int, np.ndarray]]
                 ) -> list[list[GuidedPrediction]]:
    """Per unread code of the posed bricks, its candidates' predictions (ids read anywhere
    in the frame are not looked for: a read code cannot also be a guided one)."""
    read_ids = {c.marker_id for c in codes}
    read = [c.refined.corners_px if c.refined is not None and c.refined.ok else c.raw_corners
            for c in codes]
    out: list[list[GuidedPrediction]] = []
    for key, (res, group) in results.items():
        lay = group[0].layout
        if key[2] != 0 or len(group) >= len(corners_m[id(lay)]):
            continue  # complete, or a copy of a duplicated id (no identity to guide)
        out += [preds for preds in predict_missing(key, res, group, camera, params, read,
                                                   corners_m[id(lay)], lay.code_normals())
                if preds[0].marker_id not in read_ids and preds[0].marker_id in family_of]
    return out


def guided_codes(gray: np.ndarray, results: Mapping[BrickKey, Solved],
                 codes: list[CodeDetection], camera: Camera, params: ArucoParams,
                 family_of: Mapping[int, CodeFamily],
                 corners_m: Mapping[int, Mapping[int, np.ndarray]]) -> list[CodeDetection]:
    """The unread codes of the frame's posed bricks, fitted where the poses put them.

    Args:
        gray: (H, W) uint8 frame.
        results: The bricks posed from the codes read (key -> (pose, codes)).
        codes: Every code read in the frame (their ids are not looked for again).
        camera: The camera.
        params: The detector's tuning (the guided group, the corner fit's).
        family_of: Code id -> its family.
        corners_m: ``id(layout)`` -> code slot -> (4, 3) corners in the brick frame, m.

    Returns:
        The accepted codes (``guided=True``, refined, with their information matrix).
    """
    per_code = _predictions(results, codes, camera, params, family_of, corners_m)
    if not per_code:
        return []
    out: list[CodeDetection] = []
    for preds, fits in zip(per_code, _guided_fits(gray, camera, per_code, params, family_of)):
        good = [(g, r) for g, r in zip(preds, fits) if r is not None]
        if not good:
            continue
        g, r = good[0]
        cov = corner_covariance(r.cov_px, params)
        out.append(CodeDetection(g.marker_id, g.layout, g.instance, g.slot, g.corners_px,
                                 refined=r, info=np.linalg.inv(cov), guided=True))
    return out
