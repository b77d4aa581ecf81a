"""The planar ambiguity: which of a flat marker's two poses, and when to say it is undecided.

A planar point set (a code, a drick's top, a dot pattern) seen from afar or nearly head-on has
two poses that reproject almost equally well. Both detectors decide between them with **one
rule** (:func:`decide_flips`), batched over bricks:

1. evidence, in this order — gravity (a brick lies roughly flat: its up axis within
   ``gravity_tol_deg`` of −gravity; of two such, the flatter), a reference "up" from other
   bricks of the frame, a previous pose of the same brick in a stream — decides when exactly
   one candidate agrees with it (or both do and one is clearly closer); a candidate whose fit
   is far worse than the other's never wins by evidence;
2. the image decides (``reprojection``) when the other candidate's χ² exceeds the best one's
   by ``chi2_margin`` at the measured point noise and the best fit is consistent with that
   noise (χ² ≤ 3·dof + 4); the noise is the points' assumed covariance (from their fit),
   raised where the brick's own residuals robustly show more (:func:`noise_scale`: real JPEG
   corners of a 13-code board);
3. two candidates closer than ``min_angle_deg`` are one pose (``close``: the better fit);
4. with gravity, a choice tilted more than ``gravity_tol_deg`` from flat is no choice
   (gravity contradicts it: typically a pose from too few points);
5. otherwise the pose is **ambiguous**: the better-fitting candidate is reported, flagged,
   with the other as the alternative.

So ``"ambiguous": true`` in the output means one thing whatever the detector: *the image
cannot tell the two poses apart at the measured noise (Δχ² < 25, a 5σ difference) and nothing
else known (gravity, other bricks, the previous frame) decided — or gravity contradicts the
pose the image prefers.*

A half-turn-symmetric layout's pose (``rot180_z``) is reported in one canonical half-turn
(:func:`canonical_half_turn`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from drovisio.pose.measures import rotation_angles_deg

__all__ = [
    "AmbiguityRule",
    "PoseEvidence",
    "PoseHistory",
    "alternative_plausible",
    "canonical_half_turn",
    "decide_flips",
    "noise_scale",
    "reference_up",
]


@dataclass(frozen=True)
class AmbiguityRule:
    """The one rule's numbers (module doc).

    Args:
        chi2_margin: Δχ² at which the image alone decides (25: a 5σ difference).
        min_angle_deg: Candidates closer than this are one pose.
        gravity_tol_deg: How far from flat a brick may lie for gravity to speak for it.
        reference_tol_deg: Likewise for another brick's up direction.
        previous_tol_deg: Rotation within which a previous pose supports a candidate.
        min_separation_deg: When both candidates agree with a reference or a previous pose,
            the closer one wins only if closer by this much (those are uncertain too).
    """

    chi2_margin: float = 25.0
    min_angle_deg: float = 5.0
    gravity_tol_deg: float = 25.0
    reference_tol_deg: float = 20.0
    previous_tol_deg: float = 15.0
    min_separation_deg: float = 6.0


@dataclass
class PoseEvidence:
    """What is known besides the image points, to decide between flip candidates.

    Args:
        gravity: Unit vector of gravity in the camera frame (pointing down), or None.
        reference_up: Unit "up" direction in the camera frame from other objects of the same
            frame (e.g. the median z axis of unambiguous bricks on the same ground), or None.
        previous: A recent pose of the same object (rvec, tvec), e.g. from
            :class:`PoseHistory`, or None.
    """

    gravity: np.ndarray | None = None
    reference_up: np.ndarray | None = None
    previous: tuple[np.ndarray, np.ndarray] | None = None


class PoseHistory:
    """Recent confident poses per object, for temporal consistency in a stream.

    Keep one per stream; :meth:`previous` gives the evidence for a key (e.g.
    ``(layout, instance)``), :meth:`update` records a decided pose. Entries older than
    ``max_age`` frames are forgotten (memory stays bounded by the number of objects seen
    within that window).
    """

    def __init__(self, max_age: int = 15):
        self.max_age = int(max_age)
        self.frame = 0
        self._poses: dict[object, tuple[int, np.ndarray, np.ndarray]] = {}

    def next_frame(self) -> None:
        """Call once per frame, before the poses of that frame."""
        self.frame += 1
        if len(self._poses) > 64:
            self._poses = {k: v for k, v in self._poses.items()
                           if self.frame - v[0] <= self.max_age}

    def previous(self, key) -> tuple[np.ndarray, np.ndarray] | None:
        v = self._poses.get(key)
        if v is None or self.frame - v[0] > self.max_age:
            return None
        return v[1], v[2]

    def update(self, key, rvec: np.ndarray, tvec: np.ndarray) -> None:
        self._poses[key] = (self.frame, np.asarray(rvec, np.float64).copy(),
                            np.asarray(tvec, np.float64).copy())


def _tilt_deg(R: np.ndarray, down: np.ndarray, up_axis: np.ndarray) -> np.ndarray:
    """Angles (B, 2) between each candidate's up axis and −``down`` (one (3,) vector or one
    per brick (B, 3)), degrees."""
    d = np.asarray(down, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    up = R[..., :, 2] if _is_z(up_axis) else R @ (up_axis / np.linalg.norm(up_axis))
    c = -(up @ d) if d.ndim == 1 else -np.einsum("bkj,bj->bk", up, d)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _is_z(axis: np.ndarray) -> bool:
    return bool(axis[0] == 0.0 and axis[1] == 0.0 and axis[2] > 0.0)


#: Fewest degrees of freedom from which a brick's own residuals measure its noise: below,
#: the relative standard error of a variance estimate, sqrt(2 / dof), exceeds one half.
MIN_DOF_FOR_SCALE = 8


def _chi2_quantile(p: float, dof: float) -> float:
    """The p-quantile of χ²(dof) (Wilson–Hilferty; within 1 % from 3 dof up)."""
    z = NormalDist().inv_cdf(p)
    h = 2.0 / (9.0 * dof)
    return float(dof * (1.0 - h + z * np.sqrt(h)) ** 3)


def noise_scale(whitened: np.ndarray, dof: int, confidence: float = 0.99) -> float:
    """How much noisier a brick's image points are than assumed, measured robustly from its
    own residuals: the factor (≥ 1) on the χ² scale, i.e. on the points' variance.

    The residuals of the best fit, whitened by the assumed point covariance (``whitened``,
    (2N,): unit variance each when the assumption holds), give the variance robustly from
    their median square (a wrong point or two does not raise it: the χ²(1) median is
    0.4549), corrected for the parameters the fit absorbed (2N / dof). The factor is the
    lower ``confidence`` bound of that estimate (the noise is raised only as far as the
    residuals prove it), and 1 below :data:`MIN_DOF_FOR_SCALE` degrees of freedom (a single
    code's 2 cannot measure it). Real JPEG corners are noisier than their fit's covariance
    says; this keeps the rule's "measured point noise" true for them, while a fit whose
    residuals are large only at some points (one wrong code) stays inconsistent.

    Args:
        whitened: (2N,) residuals of the best candidate, whitened by the assumed noise.
        dof: Degrees of freedom of the fit (2N − 6).
        confidence: Confidence of the lower bound.

    Returns:
        The variance factor s² (1 when the residuals do not show more noise).
    """
    e = np.asarray(whitened, np.float64).ravel()
    if dof < MIN_DOF_FOR_SCALE or e.size == 0 or not np.all(np.isfinite(e)):
        return 1.0
    s2 = float(np.median(e * e)) / 0.4549 * (e.size / dof)
    return max(1.0, s2 * dof / _chi2_quantile(confidence, dof))


def alternative_plausible(chi2: np.ndarray, dof: np.ndarray | float,
                          rule: AmbiguityRule = AmbiguityRule(),
                          scale: np.ndarray | float = 1.0) -> np.ndarray:
    """Per brick (B,): the image alone cannot rule out the second candidate of ``chi2``
    (B, 2) — its χ² is within the margin of the first's, or the first's fit is itself
    inconsistent with the noise. ``scale`` (B,) or one number: the measured noise as a factor
    on the assumed variance (:func:`noise_scale`); the χ² are divided by it."""
    chi2 = np.asarray(chi2, np.float64) / np.reshape(np.asarray(scale, np.float64), (-1, 1))
    dof = np.asarray(dof, np.float64)     # (B,) or one number: broadcasts
    best = np.minimum(chi2[:, 0], chi2[:, 1])
    other = np.maximum(chi2[:, 0], chi2[:, 1])
    return np.isfinite(other) & ((other - best < rule.chi2_margin) | (best > 3.0 * dof + 4.0))


def _best_fit(chi2: np.ndarray, rmse_px: np.ndarray | None, rule: AmbiguityRule
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reprojection's part of the rule, for B bricks with two candidates each.

    Returns:
        (finite (B,): both χ² known; best (B,): the better-fitting candidate, by χ², else by
        ``rmse_px``; fit_ok (B, 2): the candidates whose fit is not far worse than the best
        one's: a candidate that is out stays out, whatever else is said).
    """
    B = chi2.shape[0]
    finite = np.isfinite(chi2).all(axis=1)
    ar = np.arange(B)
    if finite.all():
        best = (chi2[:, 1] < chi2[:, 0]).astype(np.int64)
    else:
        best = np.where(finite, np.argmin(np.where(np.isfinite(chi2), chi2, np.inf), axis=1),
                        np.argmin(rmse_px, axis=1) if rmse_px is not None else 0)
    if rmse_px is not None and not finite.all():
        rb = rmse_px[ar, best]
        fit_ok = rmse_px <= 3.0 * rb[:, None] + 1.0
    else:
        cb = chi2[ar, best]
        fit_ok = chi2 - cb[:, None] <= np.maximum(9.0 * rule.chi2_margin, 3.0 * cb)[:, None]
    return finite, best, fit_ok


def decide_flips(R: np.ndarray, chi2: np.ndarray, dof: np.ndarray | float, *,
                 gravity: np.ndarray | None = None, reference_up: np.ndarray | None = None,
                 previous: Sequence[np.ndarray | None] | None = None,
                 up_axis: Sequence[float] | np.ndarray = (0.0, 0.0, 1.0),
                 rule: AmbiguityRule = AmbiguityRule(), rmse_px: np.ndarray | None = None,
                 use_evidence: bool = True, use_fit: bool = True,
                 scale: np.ndarray | float = 1.0
                 ) -> tuple[np.ndarray, list[str]]:
    """The one rule (module doc), for B bricks with two candidates each.

    Args:
        R: (B, 2, 3, 3) the candidates' rotations ``camera_from_brick``.
        chi2: (B, 2) their χ² at the measured point noise (NaN: not refined yet; then
            ``rmse_px`` judges a hopeless fit).
        dof: Degrees of freedom of each fit (2·points − 6), (B,) or one number.
        gravity: Down in the camera frame (3,) or (B, 3), or None.
        reference_up: Up in the camera frame from other bricks (3,) or (B, 3), or None.
        previous: Per brick, the rotation (3, 3) of its previous pose, or None.
        up_axis: The brick axis that points up when it lies flat.
        rule: The numbers of the rule.
        rmse_px: (B, 2) RMS reprojection errors, for the hopeless-fit test before χ² exist.
        use_evidence: Let gravity, the reference and the previous pose speak.
        use_fit: Let the reprojection (and the "close" rule) speak.
        scale: The point noise measured from each brick's residuals, as a factor on the
            assumed variance (:func:`noise_scale`), (B,) or one number; 1: as assumed.

    Returns:
        (choice (B,) of 0 or 1, or −1 when undecided; what decided, per brick: ``close``,
        ``gravity``, ``reference``, ``previous``, ``reprojection``, or ``""`` when nothing
        did).
    """
    R = np.asarray(R, np.float64)
    B = R.shape[0]
    # χ² at the measured noise (the assumed one, raised by the residuals' own scale)
    chi2 = np.asarray(chi2, np.float64) / np.reshape(np.asarray(scale, np.float64), (-1, 1))
    dof_a = np.asarray(dof, np.float64)
    up = np.asarray(up_axis, np.float64)
    choice = np.full(B, -1, np.int64)
    why = [""] * B
    ar = np.arange(B)
    finite, best, fit_ok = _best_fit(chi2, rmse_px, rule)

    def settle(mask: np.ndarray, pick: np.ndarray, reason: str) -> None:
        m = mask & (choice < 0)
        if m.any():
            choice[m] = pick[m]
            for b in m.nonzero()[0].tolist():
                why[b] = reason

    def agree(angle: np.ndarray, tol: float, reason: str, separation: bool) -> None:
        """Candidates within ``tol`` of the evidence (angles (B, 2)) and fitting: exactly one
        wins; of two, the nearer (when ``separation``: only if nearer by the margin)."""
        ok = (angle <= tol) & fit_ok
        settle(ok[:, 0] != ok[:, 1], np.where(ok[:, 0], 0, 1), reason)
        both = ok[:, 0] & ok[:, 1]
        if separation:
            both &= np.abs(angle[:, 0] - angle[:, 1]) >= rule.min_separation_deg
        settle(both, np.where(angle[:, 0] <= angle[:, 1], 0, 1), reason)

    tilt = None if gravity is None else _tilt_deg(R, gravity, up)
    if use_evidence:
        if tilt is not None:       # both roughly flat: the flatter one
            agree(tilt, rule.gravity_tol_deg, "gravity", separation=False)
        if reference_up is not None:
            ref = _tilt_deg(R, -np.asarray(reference_up, np.float64), up)
            agree(ref, rule.reference_tol_deg, "reference", separation=True)
        if previous is not None:
            ang = np.full((B, 2), np.inf)
            for b, Rp in enumerate(previous):
                if Rp is not None:
                    ang[b] = rotation_angles_deg(Rp, R[b])
            agree(ang, rule.previous_tol_deg, "previous", separation=True)
    if use_fit:
        settle(finite & ~alternative_plausible(chi2, dof_a, rule), best, "reprojection")
        # closer than the pose's own uncertainty: one pose
        settle(rotation_angles_deg(R[:, 0], R[:, 1]) < rule.min_angle_deg, best, "close")
    if tilt is not None:
        # bricks lie roughly flat: a choice gravity contradicts is no decision (neither
        # candidate is then trustworthy: typically a pose from too few points)
        veto = (choice >= 0) & (tilt[ar, np.maximum(choice, 0)] > rule.gravity_tol_deg)
        if veto.any():
            choice[veto] = -1
            for b in veto.nonzero()[0].tolist():
                why[b] = ""
    return choice, why


FIRM_REASONS = frozenset({"gravity", "reprojection", "previous", "unique"})
"""Decisions firm enough for their brick's up to speak for the undecided bricks of a frame."""


def reference_up(R: np.ndarray, reasons: Sequence[str]) -> np.ndarray | None:
    """The "up" of a frame: the median z axis (unit, camera frame) of the chosen rotations
    (n, 3, 3) whose decision was firm (:data:`FIRM_REASONS`); None when none was, or when
    they disagree too much to have a direction."""
    firm = [k for k, why in enumerate(reasons) if why in FIRM_REASONS]
    if not firm:
        return None
    up = np.median(np.asarray(R, np.float64)[firm, :, 2], axis=0)
    n = float(np.linalg.norm(up))
    return up / n if n > 0.5 else None


def canonical_half_turn(R: np.ndarray) -> np.ndarray:
    """Whether to turn each pose (B, 3, 3) half a turn about the brick's z to put it in the
    canonical half-turn of a symmetric layout: the brick's x axis toward the camera's +x
    (image right); if perpendicular to it, toward +y."""
    x = np.asarray(R, np.float64)[..., :, 0]
    return np.where(np.abs(x[..., 0]) > 1e-9, x[..., 0] < 0, x[..., 1] < 0)


HALF_TURN = np.array([-1.0, -1.0, 1.0])
"""Multiplies a rotation's columns: ``R * HALF_TURN`` is R turned half a turn about its z."""

