"""The bricks where they truly are: lying in the pick area, held, or set down on the wall;
what the drone rests on; the picker's grab and release."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drovisio.mission.frames import site_from_body, site_from_brick, wrap_half, yaw_of
from drovisio.mission.scenario import Scenario
from drovisio.mission.sim.fault_state import FaultState
from drovisio.mission.sim.params import SimParams
from drovisio.mission.vision import WorldBrick

__all__ = ["BrickWorld"]


class BrickWorld:
    """The truth about the bricks (site frame, metres).

    Attributes:
        bricks: brick id → (4, 4) ``site_from_brick`` (a held brick keeps the pose it had when
            grabbed; :meth:`poses` gives where it is).
        held: the held brick's id, or None.
        held_T: (4, 4) ``body_from_brick`` of the held brick.
    """

    def __init__(self, scn: Scenario, bricks: dict[str, np.ndarray]):
        self.scn = scn
        self.bricks = bricks
        self._inv: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.held: str | None = None
        self.held_T: np.ndarray | None = None

    @classmethod
    def laid_by_hand(cls, scn: Scenario, p: SimParams, rng: np.random.Generator) -> BrickWorld:
        """Each brick within ``pick_sigma_m`` / ``pick_yaw_sigma_deg`` (clipped at two sigmas)
        of its scenario pick pose."""
        bricks: dict[str, np.ndarray] = {}
        for b in scn.bricks:
            pp = scn.pick_pose(b.id)
            dxy = np.clip(rng.normal(0.0, p.pick_sigma_m, 2), -2 * p.pick_sigma_m,
                          2 * p.pick_sigma_m)
            dyaw = math.radians(float(np.clip(rng.normal(0.0, p.pick_yaw_sigma_deg),
                                              -2 * p.pick_yaw_sigma_deg,
                                              2 * p.pick_yaw_sigma_deg)))
            bricks[b.id] = site_from_brick((pp.x + dxy[0], pp.y + dxy[1], pp.z), pp.yaw + dyaw)
        return cls(scn, bricks)

    # ------------------------------------------------------------------ geometry
    def dims(self, bid: str) -> np.ndarray:
        return np.asarray(self.scn.layout_of(bid).dimensions_m, float)

    def world_bricks(self) -> list[WorldBrick]:
        """The bricks vision can see (the held one is not drawn)."""
        return [WorldBrick(bid, self.scn.layout_of(bid), self.scn.brick_by_id[bid].instance, T)
                for bid, T in self.bricks.items() if bid != self.held]

    def _inverse(self, bid: str) -> np.ndarray:
        T = self.bricks[bid]
        cached = self._inv.get(bid)
        if cached is None or cached[0] is not T:
            cached = (T, np.linalg.inv(T))
            self._inv[bid] = cached
        return cached[1]

    def under(self, xy: Sequence[float] | np.ndarray, exclude: str | None = None) -> list[str]:
        """The bricks whose footprint holds the site point ``xy``."""
        out = []
        for bid in self.bricks:
            if bid in (exclude, self.held):
                continue
            d = self.dims(bid)
            inv = self._inverse(bid)
            q = inv[:2, :2] @ np.asarray(xy) + inv[:2, 3]
            if abs(q[0]) <= d[0] / 2 and abs(q[1]) <= d[1] / 2:
                out.append(bid)
        return out

    def _held_pose(self, pos: np.ndarray, yaw: float) -> np.ndarray:
        assert self.held_T is not None
        return site_from_body(pos, yaw) @ self.held_T

    def floor(self, pos: np.ndarray, yaw: float) -> float:
        """Lowest body height at the body position ``pos`` (3,): landing gear on the ground,
        picker on a brick, or the held brick resting on what is below it."""
        scn = self.scn
        depth = scn.drone.picker_depth_m
        if self.held is None:
            z = scn.drone.gear_height_m
            for bid in self.under(pos[:2]):
                z = max(z, self.bricks[bid][2, 3] + depth - 0.005)
            return z
        T = self._held_pose(pos, yaw)
        h = scn.wall.course_height_m
        z = depth + h  # held brick on the ground
        top_off = pos[2] - T[2, 3]
        support = self.support_top(T)
        if support is not None:
            z = max(z, support + h + top_off)
        return max(z, depth + self.dims(self.held)[2] - 0.02)

    def support_top(self, T: np.ndarray) -> float | None:
        """The highest top under the two pyramids of a brick at ``T`` (site_from_brick)."""
        tops = []
        for sx in (-0.075, 0.075):
            pt = T[:2, :2] @ np.array([sx, 0.0]) + T[:2, 3]
            for bid in self.under(pt, exclude=self.held):
                tops.append(self.bricks[bid][2, 3])
        return max(tops) if tops else None

    # ------------------------------------------------------------------ picker
    def grab(self, pos: np.ndarray, yaw: float, p: SimParams) -> None:
        """Take the brick under a closing picker: within ``capture_radius_m``,
        ``contact_tol_m`` and ``capture_yaw_deg`` of it, and nothing lying on it."""
        depth = self.scn.drone.picker_depth_m
        for bid, T in self.bricks.items():
            d = math.dist(T[:2, 3], pos[:2])
            dz = abs(pos[2] - (T[2, 3] + depth))
            dyaw = abs(wrap_half(yaw_of(T) - yaw))
            covered = any(self.bricks[o][2, 3] > T[2, 3] + 0.01
                          for o in self.under(T[:2, 3], exclude=bid))
            if (d <= p.capture_radius_m and dz <= p.contact_tol_m
                    and dyaw <= math.radians(p.capture_yaw_deg) and not covered):
                self.held = bid
                self.held_T = np.linalg.inv(site_from_body(pos, yaw)) @ T
                return

    def release(self, pos: np.ndarray, yaw: float) -> None:
        """Set the held brick down level on what is below it (the ground or the bricks under
        its pyramids)."""
        assert self.held is not None
        T = self._held_pose(pos, yaw)
        support = self.support_top(T)
        h = self.scn.wall.course_height_m
        z = (support + h) if support is not None else h
        self.bricks[self.held] = site_from_brick((T[0, 3], T[1, 3], z), yaw_of(T))
        self.held, self.held_T = None, None

    def picker(self, cmd: str, brick: str | None, pos: np.ndarray, yaw: float, p: SimParams,
               faults: FaultState) -> None:
        """The picker commanded ``cmd`` (``open`` / ``closed``) while it was the other."""
        if cmd == "closed" and self.held is None:
            if faults.take(faults.grab_fail, brick):
                return
            self.grab(pos, yaw, p)
        elif cmd == "open" and self.held is not None:
            if faults.take(faults.release_fail, brick):
                return  # jammed: the brick stays in the picker, the sensor reads "holding"
            self.release(pos, yaw)

    # ------------------------------------------------------------------ truth out
    def poses(self, pos: np.ndarray, yaw: float) -> dict[str, tuple[float, float, float, float]]:
        """Brick id → (x, y, z, yaw) of its top-face centre, the held one where it is."""
        out = {}
        for bid, T in self.bricks.items():
            if bid == self.held:
                T = self._held_pose(pos, yaw)
            out[bid] = (float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), yaw_of(T))
        return out

    def placements(self, placed: set[str]) -> dict[str, dict[str, float | bool]]:
        """Brick id → errors against the plan of each brick placed (or moved off its pick
        pose): ``error_m``, ``error_z_m``, ``error_along_m``, ``yaw_error_deg``,
        ``verified``."""
        out: dict[str, dict[str, float | bool]] = {}
        for bid in self.scn.order:
            if bid == self.held:
                continue
            T = self.bricks[bid]
            plan = self.scn.slot_pose(bid)
            moved = math.dist(T[:2, 3], self.scn.pick_pose(bid).xy) > 0.5
            if bid not in placed and not moved:
                continue
            exy = math.dist(T[:2, 3], (plan.x, plan.y))
            ez = float(T[2, 3] - plan.z)
            out[bid] = {"error_m": round(exy, 5), "error_z_m": round(ez, 5),
                        "error_along_m": round(float(np.dot(T[:2, 3] - plan.xy,
                                                            [math.cos(plan.yaw),
                                                             math.sin(plan.yaw)])), 5),
                        "yaw_error_deg": round(math.degrees(abs(wrap_half(yaw_of(T) - plan.yaw))),
                                               4),
                        "verified": bid in placed}
        return out
