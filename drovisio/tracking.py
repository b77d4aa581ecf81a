"""Per-brick tracking: smooth jitter, bridge a missed frame, never output a stale pose.

One :class:`Track` per brick. Identity: ``(layout, instance)`` for bricks with codes; bricks
without ids (colour dots: ``instance`` is None) are associated frame to frame by position
(gated nearest neighbour on the predicted position) and get a track number.

The filter (why this one): the brick is static in the world but the drone moves, so in the
camera frame a brick's pose changes smoothly with the drone's motion. A **constant-velocity
Kalman filter on SE(3)** — error state ``(δθ, ω, δp, v)`` with a right perturbation of the
rotation ``R = R̂·exp([δθ]×)`` — uses each measurement's own 6×6 covariance (from the PnP
Jacobian; a code seen head-on at 2 m is far less certain in tilt than in x/y, and the filter
weighs that), smooths jitter where the measurements are noisy, follows quickly where they
are precise, and predicts over a missed frame. The process noise (white acceleration,
``q_trans`` m²/s³, ``q_rot`` rad²/s³) bounds how much the pose may change between frames;
an innovation beyond the χ² gate twice in a row restarts the track (a jump: the image
alone is then believed).

Never a stale pose: every output is the filter's state **at the capture time of the current
frame**, with ``t_measured`` (capture time of the last measurement) and ``age`` (seconds
since it). A track not measured for more than ``max_age`` (default 0.5 s) is dropped, and
:meth:`BrickTracker.prune` drops them even when no frame arrives (source lost).

Ambiguous (two-fold) and symmetric (half-turn) measurements: the candidate nearest to the
prediction is used; a symmetric brick's yaw therefore stays in one half-turn over time.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from drovisio.detect.result import BrickPose, _r, covariance_json
from drovisio.fusion import (
    default_covariance,
    pose_candidates,
    rvec_cov_to_tangent,
    so3_exp,
    so3_log,
    tangent_cov_to_rvec,
)
from drovisio.geometry import from_rvec_tvec
from drovisio.mount import Mount

__all__ = ["BrickTracker", "Track", "TrackedBrick", "TrackerConfig"]


@dataclass
class TrackerConfig:
    max_age: float = 0.5
    """Seconds without a measurement after which a brick is dropped."""
    q_trans: float = 0.5
    """White-acceleration spectral density of the translation (m²/s³)."""
    q_rot: float = 0.5
    """White angular-acceleration spectral density (rad²/s³)."""
    floor_rot: float = math.radians(0.3)
    """Added to every measurement's rotation σ (rad): no pose is known better than this."""
    floor_trans: float = 0.002
    """Added to every measurement's translation σ (m)."""
    gate_chi2: float = 40.0
    """Innovation χ² (6 dof) beyond which a measurement is an outlier for the track."""
    restart_after: int = 2
    """Consecutive outliers after which the track restarts from the measurement."""
    assoc_distance: float = 0.12
    """Largest distance (m) between a prediction and a measurement of a brick without id."""
    trail_length: int = 30
    """Positions kept per track for drawing trails."""
    v0_sigma: float = 1.0
    w0_sigma: float = 1.0


@dataclass
class TrackedBrick:
    """The output for one brick in one frame (pose at the frame's capture time)."""

    layout: str
    instance: int | None
    track: int
    method: str
    rvec: np.ndarray
    tvec: np.ndarray
    covariance: np.ndarray
    """6×6 covariance of (rvec, tvec) of the filtered pose."""
    t: float
    """Capture time (UNIX seconds) of the frame this pose is for."""
    t_measured: float
    """Capture time (UNIX seconds) of the last measurement."""
    age: float
    """t − t_measured, seconds (0 when measured in this frame)."""
    measured: bool
    measurement: BrickPose | None = None
    """This frame's detection (raw, before filtering), if any."""
    symmetric: bool = False
    ambiguous: bool = False
    body_from_brick: np.ndarray | None = None
    """4×4, when a camera mount is known."""
    last_measured: np.ndarray | None = None
    """4×4 ``camera_from_brick`` of the last measurement (taken at ``t_measured``)."""

    def camera_from_brick(self) -> np.ndarray:
        return from_rvec_tvec(self.rvec, self.tvec)

    def measured_camera_from_brick(self) -> np.ndarray | None:
        """This frame's measurement as a 4×4 ``camera_from_brick`` — what the camera saw, not
        the filter's estimate — or None when the brick was not measured in this frame. Of an
        ambiguous or symmetric measurement's candidates, the one the track agrees with."""
        return self.last_measured if self.measured else None

    @property
    def key(self) -> tuple[str, int | None, int]:
        return (self.layout, self.instance, self.track)

    @property
    def distance(self) -> float:
        """Distance to the body origin (with a mount) or to the camera, metres."""
        if self.body_from_brick is not None:
            return float(np.linalg.norm(self.body_from_brick[:3, 3]))
        return float(np.linalg.norm(self.tvec))

    def to_json(self, with_covariance: bool = True) -> dict:
        m = self.measurement
        out: dict = {
            "layout": self.layout,
            "instance": self.instance,
            "method": self.method,
            "rvec": [_r(v, 7) for v in np.ravel(self.rvec)],
            "tvec": [_r(v, 7) for v in np.ravel(self.tvec)],
            "reprojection_rmse_px": _r(m.reprojection_rmse_px, 4) if m is not None else None,
            "markers": [int(x) for x in m.markers] if m is not None else [],
            "track": self.track,
            "t": _r(self.t, 6),
            "t_measured": _r(self.t_measured, 6),
            "age": _r(self.age, 4),
            "measured": self.measured,
            "distance": _r(self.distance, 4),
        }
        if self.ambiguous:
            out["ambiguous"] = True
        if self.symmetric:
            out["symmetric"] = True
        if self.body_from_brick is not None:
            out["body_from_brick"] = {
                "rvec": [_r(v, 7) for v in so3_log(self.body_from_brick[:3, :3])],
                "tvec": [_r(v, 7) for v in self.body_from_brick[:3, 3]]}
        if with_covariance and self.covariance is not None:
            cov = covariance_json(self.rvec, self.covariance)
            if cov is not None:
                out["covariance"] = cov
        return out


def _cv_q(dt: float, q: float) -> np.ndarray:
    """Process noise of a constant-velocity model, 1 axis: state (x, v)."""
    return q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])


_ID = itertools.count(1)


@dataclass
class Track:
    """State of one brick: error-state Kalman filter, x = (δθ, ω, δp, v) (12)."""

    layout: str
    instance: int | None
    track: int
    R: np.ndarray
    p: np.ndarray
    w: np.ndarray
    v: np.ndarray
    P: np.ndarray
    t_mono: float
    """Time (monotonic) of the state."""
    t_measured_mono: float
    t_measured_wall: float
    method: str
    symmetric: bool = False
    outliers: int = 0
    hits: int = 1
    trail: deque = field(default_factory=lambda: deque(maxlen=30))
    last_measured: np.ndarray | None = None
    """4×4 ``camera_from_brick`` of the last measurement."""

    # ------------------------------------------------------------------ model
    def predict(self, t_mono: float, cfg: TrackerConfig) -> None:
        dt = t_mono - self.t_mono
        if dt <= 0:
            return
        self.R = self.R @ so3_exp(self.w * dt)
        self.p = self.p + self.v * dt
        F = np.eye(12)
        F[0:3, 3:6] = np.eye(3) * dt
        F[6:9, 9:12] = np.eye(3) * dt
        Q = np.zeros((12, 12))
        qr, qt = _cv_q(dt, cfg.q_rot), _cv_q(dt, cfg.q_trans)
        for i in range(3):
            Q[np.ix_([i, 3 + i], [i, 3 + i])] = qr
            Q[np.ix_([6 + i, 9 + i], [6 + i, 9 + i])] = qt
        self.P = F @ self.P @ F.T + Q
        self.t_mono = t_mono

    def innovation(self, R_m: np.ndarray, t_m: np.ndarray, C_m: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, float]:
        z = np.r_[so3_log(self.R.T @ R_m), t_m - self.p]
        S = self.P[np.ix_(_H_IDX, _H_IDX)] + C_m
        d2 = float(z @ np.linalg.solve(S, z))
        return z, S, d2

    def update(self, z: np.ndarray, S: np.ndarray, C_m: np.ndarray) -> None:
        PHt = self.P[:, _H_IDX]
        K = np.linalg.solve(S, PHt.T).T
        dx = K @ z
        self.R = self.R @ so3_exp(dx[0:3])
        self.w = self.w + dx[3:6]
        self.p = self.p + dx[6:9]
        self.v = self.v + dx[9:12]
        H = np.zeros((6, 12))
        H[np.arange(6), _H_IDX] = 1.0
        IKH = np.eye(12) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ C_m @ K.T  # Joseph form
        self.P = 0.5 * (self.P + self.P.T)

    def pose_cov(self) -> np.ndarray:
        """6×6 covariance of (rvec, tvec) of the current state."""
        C = self.P[np.ix_(_H_IDX, _H_IDX)]
        return tangent_cov_to_rvec(so3_log(self.R), C)


_H_IDX = np.array([0, 1, 2, 6, 7, 8])


class BrickTracker:
    """Tracks of all bricks; feed it each frame's detections with :meth:`update`.

    Args:
        config: Filter settings (``max_age`` is the drop time).
        mount: Optional :class:`drovisio.mount.Mount` to fill ``body_from_brick``.
    """

    def __init__(self, config: TrackerConfig | None = None, mount: Mount | None = None):
        self.config = config or TrackerConfig()
        self.mount = mount
        self.tracks: list[Track] = []

    # ------------------------------------------------------------------ helpers
    def _meas_cov(self, p: BrickPose) -> np.ndarray:
        cfg = self.config
        if p.covariance is None or not np.all(np.isfinite(p.covariance)):
            C = default_covariance()
        else:
            C = rvec_cov_to_tangent(p.rvec, p.covariance)
            C = 0.5 * (C + C.T)
        C = C.copy()
        C[np.diag_indices(3)] += cfg.floor_rot ** 2
        C[3 + np.arange(3), 3 + np.arange(3)] += cfg.floor_trans ** 2
        return C

    def _new_track(self, p: BrickPose, R: np.ndarray, t: np.ndarray, C: np.ndarray,
                   t_mono: float, t_wall: float) -> Track:
        cfg = self.config
        P = np.zeros((12, 12))
        P[np.ix_(_H_IDX, _H_IDX)] = C
        P[3:6, 3:6] = np.eye(3) * cfg.w0_sigma ** 2
        P[9:12, 9:12] = np.eye(3) * cfg.v0_sigma ** 2
        tr = Track(layout=p.layout, instance=p.instance, track=next(_ID), R=R.copy(),
                   p=t.copy(), w=np.zeros(3), v=np.zeros(3), P=P, t_mono=t_mono,
                   t_measured_mono=t_mono, t_measured_wall=t_wall, method=p.method,
                   symmetric=bool(p.symmetric), trail=deque(maxlen=cfg.trail_length))
        return tr

    def _associate(self, poses: Sequence[BrickPose]) -> list[tuple[BrickPose, Track | None]]:
        """Each pose with its track (None: a new brick): by id when the brick has one, else
        by :meth:`_match_anonymous`."""
        by_key = {(t.layout, t.instance): t for t in self.tracks if t.instance is not None}
        out: list[tuple[BrickPose, Track | None]] = []
        anon = [p for p in poses if p.instance is None]
        for p in poses:
            if p.instance is not None:
                out.append((p, by_key.get((p.layout, p.instance))))
        match = self._match_anonymous(anon)
        for i, p in enumerate(anon):
            out.append((p, match.get(i)))
        return out

    def _match_anonymous(self, anon: Sequence[BrickPose]) -> dict[int, Track]:
        """Bricks without id: greedy nearest neighbour on the tracks' predicted positions,
        within :attr:`TrackerConfig.assoc_distance` (index into ``anon`` -> track)."""
        free = [t for t in self.tracks if t.instance is None]
        cands = []
        for i, p in enumerate(anon):
            tp = np.ravel(p.tvec)
            for j, t in enumerate(free):
                if t.layout != p.layout:
                    continue
                d = float(np.linalg.norm(t.p - tp))
                if d <= self.config.assoc_distance:
                    cands.append((d, i, j))
        cands.sort()
        used_i, used_j = set(), set()
        match: dict[int, Track] = {}
        for _d, i, j in cands:
            if i in used_i or j in used_j:
                continue
            used_i.add(i)
            used_j.add(j)
            match[i] = free[j]
        return match

    # ------------------------------------------------------------------ API
    def prune(self, t_mono: float) -> None:
        """Drop tracks not measured for more than ``max_age`` (call it also without frames)."""
        ma = self.config.max_age
        self.tracks = [t for t in self.tracks if t_mono - t.t_measured_mono <= ma]

    def reset(self) -> None:
        self.tracks = []

    def update(self, poses: Sequence[BrickPose], t_mono: float, t_wall: float
               ) -> list[TrackedBrick]:
        """One frame: detections ``poses`` captured at ``t_mono`` (monotonic) / ``t_wall``.

        Returns the bricks to output for this frame: measured ones and ones bridged by
        prediction (``measured=False``) that are younger than ``max_age``.
        """
        cfg = self.config
        self.prune(t_mono)
        for t in self.tracks:
            t.predict(t_mono, cfg)
        measured: dict[int, BrickPose] = {}
        for p, tr in self._associate(poses):
            C = self._meas_cov(p)
            cands = pose_candidates(p)
            if tr is None:
                R, tv = cands[0]
                tr = self._new_track(p, R, tv, C, t_mono, t_wall)
                self.tracks.append(tr)
                measured[id(tr)] = p
                continue
            z, S, d2, R_m, t_m = min(((*tr.innovation(R_m, t_m, C), R_m, t_m)
                                      for R_m, t_m in cands), key=lambda x: x[2])
            if d2 > cfg.gate_chi2:
                tr.outliers += 1
                if tr.outliers >= cfg.restart_after:
                    fresh = self._new_track(p, cands[0][0], cands[0][1], C, t_mono, t_wall)
                    fresh.track = tr.track
                    self.tracks[self.tracks.index(tr)] = fresh
                    measured[id(fresh)] = p
                continue
            tr.outliers = 0
            tr.update(z, S, C)
            tr.hits += 1
            tr.method = p.method
            tr.symmetric = bool(p.symmetric)
            tr.t_measured_mono = t_mono
            tr.t_measured_wall = t_wall
            measured[id(tr)] = p
        out = []
        for tr in self.tracks:
            m = measured.get(id(tr))
            tr.trail.append(tr.p.copy())
            if m is not None:
                R_m, t_m = max(pose_candidates(m), key=lambda c: float(np.trace(tr.R.T @ c[0])))
                tr.last_measured = np.eye(4)
                tr.last_measured[:3, :3], tr.last_measured[:3, 3] = R_m, t_m
            rvec = so3_log(tr.R)
            T = np.eye(4)
            T[:3, :3] = tr.R
            T[:3, 3] = tr.p
            age = max(0.0, t_mono - tr.t_measured_mono)
            out.append(TrackedBrick(
                layout=tr.layout, instance=tr.instance, track=tr.track,
                method=tr.method, rvec=rvec, tvec=tr.p.copy(), covariance=tr.pose_cov(),
                t=t_wall, t_measured=tr.t_measured_wall, age=age, measured=m is not None,
                measurement=m, symmetric=tr.symmetric,
                ambiguous=bool(m is not None and m.ambiguous and tr.hits <= 1),
                body_from_brick=None if self.mount is None else self.mount.body_from(T),
                last_measured=tr.last_measured))
        out.sort(key=lambda b: (b.layout, -1 if b.instance is None else b.instance, b.track))
        return out

    def trails(self) -> dict[int, np.ndarray]:
        """Recent filtered positions (camera frame) per track number."""
        return {t.track: np.array(t.trail) for t in self.tracks if len(t.trail)}
