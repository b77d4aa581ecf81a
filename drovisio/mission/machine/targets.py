"""Where the target is: vision sightings turned into site poses, the target's running
estimate, the total station checked against vision, and where the body must go.

Frames: sightings are in the drone's FRD body frame; everything returned is in the site frame
(x east, y north, z up, metres; yaw from east, counter-clockwise), see
:mod:`drovisio.mission.frames`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drovisio.mission.frames import nearest_mod_pi, site_from_body, wrap_half, yaw_of
from drovisio.mission.machine.context import StepContext, enter
from drovisio.mission.machine.signals import Sighting
from drovisio.mission.machine.states import PICK_STATES
from drovisio.mission.scenario import Pose4

__all__ = ["site_xy_from_body_xy", "body_xy_from_site_xy", "mean_pose", "site_pose_of",
           "target_sightings", "monitor_disagreement", "update_target", "body_goal", "errors"]

Sample = tuple[float, float, float, float]
"""One estimate of a target: (x, y, z, yaw) in the site frame, metres and radians."""


def site_xy_from_body_xy(v: Sequence[float] | np.ndarray, yaw: float) -> np.ndarray:
    """A horizontal FRD body vector (forward, right) as a site vector (east, north), (2,)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] + s * v[1], s * v[0] - c * v[1]])


def body_xy_from_site_xy(d: Sequence[float] | np.ndarray, yaw: float) -> np.ndarray:
    """A horizontal site vector (east, north) as an FRD body vector (forward, right), (2,)."""
    c, s = math.cos(yaw), math.sin(yaw)  # the FRD rotation is its own inverse
    return np.array([c * d[0] + s * d[1], s * d[0] - c * d[1]])


def mean_pose(samples: Sequence[Sample]) -> Pose4:
    """The mean of target estimates (yaws averaged modulo a half turn about the latest)."""
    a = np.asarray(samples, float)
    y0 = a[-1, 3]
    yaw = y0 + float(np.mean([wrap_half(y - y0) for y in a[:, 3]]))
    return Pose4(float(a[:, 0].mean()), float(a[:, 1].mean()), float(a[:, 2].mean()), yaw)


def site_pose_of(s: Sighting, position: np.ndarray, yaw: float) -> Pose4:
    """The site pose of a sighting seen from the body at ``position`` (3,) with ``yaw``."""
    site_from_brick = site_from_body(position, yaw) @ np.asarray(s.body_from_brick, float)
    return Pose4(float(site_from_brick[0, 3]), float(site_from_brick[1, 3]),
                 float(site_from_brick[2, 3]), yaw_of(site_from_brick))


def target_sightings(c: StepContext, brick: str, expected_xy: Sequence[float] | np.ndarray
                     ) -> list[Pose4]:
    """Site poses of ``brick`` in this frame (by id, or the one nearest where expected)."""
    if not c.readings.vision:
        return []
    scn = c.scn
    b = scn.brick_by_id[brick]
    poses = []
    name = scn.layout_of(brick).name   # sightings carry the layout's name, not the entry
    for s in c.readings.vision:
        if s.layout != name:
            continue
        if scn.has_ids(brick):
            if s.instance == b.instance:
                poses.append(site_pose_of(s, c.position, c.yaw))
        else:
            pose = site_pose_of(s, c.position, c.yaw)
            if math.dist((pose.x, pose.y), expected_xy) <= c.th.match_radius_m:
                poses.append(pose)
    if not scn.has_ids(brick) and len(poses) > 1:
        poses.sort(key=lambda q: math.dist((q.x, q.y), expected_xy))
        poses = poses[:1]
    return poses


def _known_positions(c: StepContext) -> dict[tuple[str, int | None], Pose4]:
    """Bricks with codes whose site position the machine knows: the as-built wall, and the
    bricks still lying at their (surveyed) pick poses."""
    scn = c.scn
    built = dict(c.mem.as_built)
    cur = c.brick
    out: dict[tuple[str, int | None], Pose4] = {}
    for b in scn.bricks:
        if not scn.has_ids(b.id):
            continue
        key = (scn.layout_of(b.id).name, b.instance)   # as a sighting names it
        if b.id in built:
            out[key] = built[b.id]
        elif b.id not in c.mem.placed and (b.id != cur or c.mem.state in PICK_STATES):
            out[key] = scn.pick_pose(b.id)
    return out


def monitor_disagreement(c: StepContext) -> bool:
    """Compare the total station with vision on every frame (thesis 8.4.3); True when the
    disagreement sent the machine to the safe zone.

    A brick of known site position seen by vision gives the drone's position; beyond
    ``disagreement_m`` for ``disagreement_frames`` frames in a row, go to the safe zone.
    Bricks without ids are matched by position and cannot reveal an offset larger than
    ``match_radius_m``.
    """
    if not c.ts_ok or c.readings.vision is None:
        return False
    known = _known_positions(c)
    worst = None
    for s in c.readings.vision:
        k = known.get((s.layout, s.instance))
        if k is None:
            continue
        seen = site_pose_of(s, c.position, c.yaw)
        d = float(np.hypot(k.x - seen.x, k.y - seen.y))
        worst = d if worst is None else max(worst, d)
    if worst is None:
        return False
    n = c.mem.disagree + 1 if worst > c.th.disagreement_m else 0
    c.update(disagree=n)
    if n >= c.th.disagreement_frames:
        c.event("disagreement", distance_m=round(worst, 3), threshold_m=c.th.disagreement_m)
        enter(c, "disagreement", reason=f"total station and vision disagree by {worst:.2f} m")
        return True
    return False


def _pick_sample(c: StepContext, brick: str) -> Sample | None:
    """This frame's estimate of the brick to pick, or None if the frame does not show it."""
    nominal = c.scn.pick_pose(brick)
    expected = mean_pose(c.mem.samples).xy if c.mem.samples else nominal.xy
    poses = target_sightings(c, brick, expected)
    if not poses:
        return None
    pose = poses[0]
    return (pose.x, pose.y, nominal.z, pose.yaw)


def _slot_sample(c: StepContext, brick: str, refs: list[str]) -> Sample | None:
    """This frame's estimate of the slot from the placed bricks ``refs`` around it, or None
    if the frame shows none of them."""
    scn = c.scn
    slot = scn.slot_pose(brick)
    built = dict(c.mem.as_built)
    xs, ys, yaws = [], [], []
    for ref in refs:
        known = built.get(ref, scn.slot_pose(ref))
        poses = target_sightings(c, ref, known.xy)
        if not poses:
            continue
        seen = poses[0]
        rel = scn.ref_from_slot(ref, brick)
        ref_yaw = nearest_mod_pi(seen.yaw, known.yaw)
        dxy = np.array([[math.cos(ref_yaw), -math.sin(ref_yaw)],
                        [math.sin(ref_yaw), math.cos(ref_yaw)]]) @ np.array([rel.x, rel.y])
        xs.append(seen.x + dxy[0])
        ys.append(seen.y + dxy[1])
        yaws.append(ref_yaw + rel.yaw)
    if not xs:
        return None
    if scn.plan_by_id[brick].course == 1:
        # course 1: the plan through the total station and the heading. The neighbour is
        # only checked (seen, consistent): chaining the yaw to it was measured worse (its
        # estimate noise adds up brick after brick along the course)
        return (slot.x, slot.y, slot.z, slot.yaw)
    y0 = yaws[0]
    yaw = y0 + float(np.mean([wrap_half(y - y0) for y in yaws]))
    return (float(np.mean(xs)), float(np.mean(ys)), slot.z, nearest_mod_pi(yaw, slot.yaw))


def update_target(c: StepContext, brick: str, drop: bool) -> bool | None:
    """Fold this frame's sightings into the target estimate.

    Returns True if the target was seen in this frame, False if a frame came without it,
    None if no frame arrived.
    """
    refs = c.scn.references(brick) if drop else []
    if drop and not refs:
        # course 1 with no placed neighbour: the total station and the plan only
        slot = c.scn.slot_pose(brick)
        c.update(samples=((slot.x, slot.y, slot.z, slot.yaw),), last_seen_t=c.now,
                 seen_frames=c.mem.seen_frames + 1)
        return True
    if c.readings.vision is None:
        return None
    cand = _slot_sample(c, brick, refs) if drop else _pick_sample(c, brick)
    if cand is None:
        return False
    samples = (c.mem.samples + (cand,))[-c.th.filter_frames:]
    c.update(samples=samples, last_seen_t=c.now, seen_frames=c.mem.seen_frames + 1)
    return True


def body_goal(c: StepContext, target: Pose4, drop: bool) -> tuple[np.ndarray, float]:
    """Where the body must be (xy, (2,)) and its heading so the picker / held brick meets
    ``target``."""
    if drop and c.mem.held is not None:
        hx, hy, hyaw = c.mem.held
    else:
        hx, hy, hyaw = 0.0, 0.0, 0.0
    body_yaw = nearest_mod_pi(target.yaw - hyaw, c.yaw)
    xy = target.xy - site_xy_from_body_xy((hx, hy), body_yaw)
    return xy, body_yaw


def errors(c: StepContext, xy: Sequence[float] | np.ndarray, body_yaw: float
           ) -> tuple[float, float]:
    """The body's horizontal distance to ``xy`` (m) and heading error to ``body_yaw`` (rad)."""
    return float(np.hypot(*(np.asarray(xy) - c.position[:2]))), wrap_half(body_yaw - c.yaw)
