"""The dot benchmark's scores: a reported brick against the true ones of its frame (pose
errors, flips, false bricks, dot-centre bias), summed over a set of frames."""

from __future__ import annotations

import cv2
import numpy as np

from drovisio.bench.dots.frames import DotTruth, Frame
from drovisio.pose.truth_errors import pose_errors


def _rot(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]


def truth_pose_errors(truth: DotTruth, R_est: np.ndarray, t_est: np.ndarray, symmetric: bool
                      ) -> dict:
    """:func:`drovisio.pose.truth_errors.pose_errors` of a pose against a brick's truth."""
    return pose_errors(truth.camera_from_brick, R_est, t_est, symmetric)


def _eligible(b: DotTruth) -> bool:
    vis = np.asarray(b.visible, bool)
    if vis.sum() < 4:
        return False
    return float(np.median(np.asarray(b.size_px)[vis])) >= 6.0


class Tally:
    """Accumulates the scores of one set of frames and one detector setting."""

    def __init__(self):
        self.eligible = 0
        self.found = 0
        self.eligible_full = 0
        self.found_full = 0
        self.errors: list[dict] = []
        self.flips = 0
        self.unflagged_flips = 0
        self.ambiguous = 0
        self.reported = 0
        self.false = 0
        self.bias: list[np.ndarray] = []
        self.frames = 0
        self.missed: list[str] = []

    def add(self, frame: Frame, poses, symmetric_of, tag: str = "", perm_of=None) -> None:
        """Score one frame's reported bricks against its true ones (``symmetric_of(layout
        name)``: whether the layout is symmetric; ``perm_of(layout name)``: its dots' labels
        after a half-turn, or None)."""
        self.frames += 1
        matched: set[int] = set()
        for bi, b in enumerate(frame.bricks):
            best = _nearest(b, poses, matched)
            elig = _eligible(b)
            full = elig and all(b.visible)
            self.eligible += elig
            self.eligible_full += full
            if best is None:
                if elig:
                    self.missed.append(f"{tag} brick {bi}")
                continue
            matched.add(best)
            p = poses[best]
            self.found += elig
            self.found_full += full
            e = truth_pose_errors(b, _rot(p.rvec), np.asarray(p.tvec, float),
                                  symmetric_of(p.layout))
            e["eligible"] = elig
            e["ambiguous"] = bool(p.ambiguous)
            e["n_dots"] = len(p.markers)
            self.errors.append(e)
            flip = e["rot_deg"] > 20.0
            self.flips += flip
            self.unflagged_flips += flip and not p.ambiguous
            if p.image_points is not None and len(p.markers):
                self.bias.append(_center_errors(b, p, perm_of(p.layout) if perm_of else None))
        for p in poses:
            self.reported += 1
            self.ambiguous += bool(p.ambiguous)
        self.false += len(poses) - len(matched)

    def summary(self, max_dist: float = 2.0) -> dict:
        errs = [e for e in self.errors if e["dist_m"] <= max_dist and e["rot_deg"] <= 20.0]

        def p95(key, scale=1.0):
            v = [e[key] * scale for e in errs]
            return float(np.percentile(v, 95)) if v else float("nan")

        b = np.concatenate(self.bias) if self.bias else np.zeros((0, 2))
        return {
            "frames": self.frames,
            "eligible": self.eligible, "found": self.found,
            "recall": self.found / self.eligible if self.eligible else float("nan"),
            "eligible_all_dots": self.eligible_full, "found_all_dots": self.found_full,
            "recall_all_dots": (self.found_full / self.eligible_full if self.eligible_full
                                else float("nan")),
            "poses_scored": len(errs),
            "lateral_p95_cm": p95("lateral_m", 100), "depth_p95_pct": p95("depth_rel", 100),
            "yaw_p95_deg": p95("yaw_deg"), "rot_p95_deg": p95("rot_deg"),
            "flips": self.flips, "unflagged_flips": self.unflagged_flips,
            "ambiguous_share": self.ambiguous / self.reported if self.reported else 0.0,
            "false_bricks": self.false,
            "center_bias_px": b.mean(axis=0).tolist() if len(b) else [float("nan")] * 2,
            "center_rms_px": float(np.sqrt((b ** 2).sum(axis=1).mean())) if len(b) else
            float("nan"),
            "centers": len(b),
        }


def _nearest(b: DotTruth, poses, matched: set[int]) -> int | None:
    """The reported brick of the same layout nearest to a true one (within 8 cm) that no
    other true brick took, or None."""
    T = np.asarray(b.camera_from_brick)
    best, bd = None, 0.08
    for k, p in enumerate(poses):
        if k in matched or p.layout != b.layout:
            continue
        d = float(np.linalg.norm(np.asarray(p.tvec) - T[:3, 3]))
        if d < bd:
            best, bd = k, d
    return best


def _center_errors(b: DotTruth, p, perm) -> np.ndarray:
    """(n, 2) reported minus true dot centres, pixels; with ``perm`` (a half-turned report
    labels the dots the other way) the labelling that fits better."""
    mk = np.asarray(p.markers)
    err = np.asarray(p.image_points) - np.asarray(b.centers_px)[mk]
    if perm is not None:
        err2 = np.asarray(p.image_points) - np.asarray(b.centers_px)[perm[mk]]
        if np.abs(err2).sum() < np.abs(err).sum():
            err = err2
    return err
