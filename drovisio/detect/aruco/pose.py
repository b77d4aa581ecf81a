"""Stage 6, the pose: one joint PnP per brick over all its codes, flips resolved.

Each brick is solved by :func:`drovisio.pose.solve_brick_pose` over every visible code, with
the corners' covariance from the fit (block-diagonal: codes are fitted independently); a code
with a corner far beyond the noise the brick's own residuals show is left out of the final
refinement there. A joint fit worse than ``max_rmse_px`` that nothing explains
(:meth:`BrickSolver.fit_explained`) falls back to the best single code.

Flips are chosen with gravity when known, then with the "up" of the other, decided bricks
of the frame (bricks on one ground are parallel; :func:`drovisio.detect.base.decided_up`),
then with the previous pose of the same brick in a stream, then with the reprojection.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from drovisio.camera import Camera
from drovisio.detect.aruco.codes import BrickKey, CodeDetection
from drovisio.detect.aruco.params import ArucoParams
from drovisio.detect.base import decided_up
from drovisio.layout import MarkerLayout
from drovisio.pose import PoseEvidence, PoseResult, solve_brick_pose
from drovisio.pose.ambiguity import noise_scale

__all__ = ["BrickSolver", "Solved"]

Solved = tuple[PoseResult, list[CodeDetection]]
"""A brick's pose and the codes it was solved from (one of them after a fallback)."""

PreviousPose = Callable[[BrickKey], "tuple[np.ndarray, np.ndarray] | None"]


def _refined(c: CodeDetection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A grouped code's refined corners (px, normalised) and their information matrix."""
    assert c.refined is not None and c.info is not None  # only refined codes are grouped
    return c.refined.corners_px, c.refined.corners_norm, c.info


class BrickSolver:
    """Joint poses of bricks from their refined codes.

    Args:
        camera: The calibrated camera.
        params: The detector's tuning (the pose's group).
        layouts: The layouts whose code corners are prepared up front.
    """

    def __init__(self, camera: Camera, params: ArucoParams, layouts: list[MarkerLayout]):
        self.camera = camera
        self.params = params
        self._corners_m: dict[int, dict[int, np.ndarray]] = {
            id(lay): lay.code_corners_m() for lay in layouts}

    def corners_m_by_layout(self) -> dict[int, dict[int, np.ndarray]]:
        """``id(layout)`` -> code slot -> (4, 3) corners in the brick frame, m."""
        return self._corners_m

    def _code_corners_m(self, lay: MarkerLayout) -> dict[int, np.ndarray]:
        """Code slot -> (4, 3) corners in the brick frame, m (cached per layout)."""
        corners_m = self._corners_m.get(id(lay))
        if corners_m is None:
            corners_m = self._corners_m[id(lay)] = lay.code_corners_m()
        return corners_m

    def _points(self, group: list[CodeDetection]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(object points (4G, 3) m, image points (4G, 2) px, the same normalised, their
        (8G, 8G) information matrix) of a brick's G codes."""
        corners_m = self._code_corners_m(group[0].layout)
        if len(group) == 1:
            img, xn, info = _refined(group[0])
            return corners_m[group[0].slot], img, xn, info
        obj = np.concatenate([corners_m[c.slot] for c in group])
        parts = [_refined(c) for c in group]
        img = np.concatenate([r[0] for r in parts])
        xn = np.concatenate([r[1] for r in parts])
        # codes are fitted independently: block-diagonal
        info = np.zeros((8 * len(group), 8 * len(group)))
        for i, r in enumerate(parts):
            info[8 * i:8 * i + 8, 8 * i:8 * i + 8] = r[2]
        return obj, img, xn, info

    def solve(self, group: list[CodeDetection], evidence: PoseEvidence) -> Solved | None:
        """Joint pose of one brick from its codes; None when no fit is good enough."""
        obj, img, xn, info = self._points(group)
        res = solve_brick_pose(obj, img, self.camera, image_pts_norm=xn, points_info=info,
                               evidence=evidence, rule=self.params.ambiguity,
                               gravity_prior_deg=self.params.gravity_prior_deg, planar=None,
                               point_groups=np.repeat(np.arange(len(group)), 4))
        if res is None or not np.isfinite(res.rmse_px) or (
                res.rmse_px > self.params.max_rmse_px
                and not self.fit_explained(res, group, obj, img, info)):
            if len(group) > 1:  # one code may be wrong: keep the best single-code pose
                singles = [self.solve([c], evidence) for c in group]
                kept = [s for s in singles if s is not None]
                if kept:
                    return min(kept, key=lambda s: s[0].rmse_px)
            return None
        return res, group

    def solve_frame(self, groups: dict[BrickKey, list[CodeDetection]],
                    gravity: np.ndarray | None, previous: PreviousPose
                    ) -> dict[BrickKey, Solved]:
        """Every brick of a frame, then the undecided ones again with the "up" of the
        decided ones.

        Args:
            groups: The frame's bricks and their codes.
            gravity: (3,) unit gravity in the camera frame, or None.
            previous: The brick's previous pose ``(rvec, tvec)`` in the stream, or None.
        """
        results: dict[BrickKey, Solved] = {}
        for key, group in groups.items():
            solved = self.solve(group, PoseEvidence(gravity=gravity, previous=previous(key)))
            if solved is not None:
                results[key] = solved
        if not any(r[0].ambiguous for r in results.values()):
            return results
        chosen = [r[0] for r in results.values()]
        up = decided_up(np.array([cv2.Rodrigues(d.rvec.reshape(3, 1))[0] for d in chosen]),
                        [d.decided_by for d in chosen], np.array([d.ambiguous for d in chosen]))
        if up is None:
            return results
        for key, (res, group) in list(results.items()):
            if res.ambiguous:
                res2 = self.solve(group, PoseEvidence(
                    gravity=gravity, reference_up=up, previous=previous(key)))
                if res2 is not None:
                    results[key] = res2
        return results

    def fit_explained(self, res: PoseResult, group: list[CodeDetection], obj: np.ndarray,
                      img: np.ndarray, info: np.ndarray) -> bool:
        """Whether a joint fit worse than ``max_rmse_px`` is still right.

        Several codes: when their residuals are consistent with the corner noise measured
        robustly in them (χ² at that noise ≤ 3·dof + 4, the ambiguity rule's test,
        :func:`drovisio.pose.ambiguity.noise_scale`): noisy corners or a camera model that
        fits the whole board a little worse, not one code grouped wrongly (its residuals
        would stand out from the others'). One code (2 degrees of freedom cannot measure
        noise): when OpenCV's own corners of that code fit the camera no better (within
        1.5×, the spread of independent corner estimates): the residual is then the camera
        model's, not the corners' (both judged by the same unweighted planar PnP).
        """
        dof = 2 * len(img) - 6
        if len(group) > 1:
            px, _ = self.camera.project_points(obj.reshape(-1, 1, 3), res.rvec, res.tvec)
            r = (px.reshape(-1, 2) - img).ravel()
            try:
                e = np.linalg.cholesky(info).T @ r
            except np.linalg.LinAlgError:
                return False
            return float(e @ e) / noise_scale(e, dof) <= 3.0 * dof + 4.0
        ours = self.plain_rmse(obj, img)
        raw = self.plain_rmse(obj, group[0].raw_corners)
        return ours <= 1.5 * raw

    def plain_rmse(self, obj: np.ndarray, pts: np.ndarray) -> float:
        """RMS residual (px) of the unweighted planar PnP (IPPE) of one code's corners: how
        well the camera model explains those four points as the square they are."""
        xn = self.camera.normalize(pts)
        if not np.all(np.isfinite(xn)):
            return float("inf")
        try:
            ok, rv, tv = cv2.solvePnP(obj.reshape(-1, 1, 3), xn.reshape(-1, 1, 2), np.eye(3),
                                      None, flags=cv2.SOLVEPNP_IPPE)
        except cv2.error:
            return float("inf")
        if not ok:
            return float("inf")
        px, _ = self.camera.project_points(obj.reshape(-1, 1, 3), rv, tv)
        return float(np.sqrt(((px.reshape(-1, 2) - pts) ** 2).sum(axis=1).mean()))
