"""``drovisio bench dots``: accuracy, robustness, speed and memory of the colour-dot detector.

Measured on the renderer's scenes (:mod:`drovisio.scenes`), with exact truth. Parts:

* ``accuracy``  random scenes (0.4–2 m, tilt ≤ 40°, gravel/grass/clutter, blur, noise, JPEG,
  lighting gain 0.8–1.2, gamma 0.9–1.1, a few red/blue props): recall, pose errors with and
  without gravity, flips, false bricks, and the bias of the reported dot centres.
* ``hidden``    the same with one or two dots of every brick unpainted, plus bricks partly
  covered by a plain brick laid across them.
* ``clutter``   scenes without any brick, photo clutter on the ground and red cups, blue
  tarpaulins and boxes: every brick reported is a false brick.
* ``lighting``  a gain × gamma grid (0.6–1.3 × 0.8–1.25) with the default palette.
* ``timing``    per-frame time against a minimal pass (cvtColor to HSV + one cv2.inRange per
  colour) on the same frames, with 1, 5 and 20 bricks in view; medians.
* ``memory``    resident memory over many frames (a loop over cached frames).
* ``kernels``   each compiled kernel against what it replaces (the numpy reference, or
  OpenCV: IPPE, undistortion, projection) on the inputs of the 20-brick timing frames.

Definitions (printed with the table):

* a brick is *eligible* when at least 4 of its dots are fully visible (inside the image,
  painted, not hidden by its own pyramids, another brick or a prop) and their median size is
  ≥ 6 px across (equivalent diameter of the projected dot, 2·√(area/π));
* *lateral error*: √(Δx² + Δy²) of ``tvec`` in the camera frame (the brick origin, centre of
  its top face); *depth error*: |Δz| / z; *yaw error*: the rotation about the brick's z axis
  of R_trueᵀ·R_est, modulo 180° for a ``rot180_z`` layout; all at ≤ 2 m from the camera;
* a *flip*: the reported orientation is more than 20° from the truth (modulo the layout's
  symmetry); *unflagged* when the pose is not marked ``ambiguous``;
* a *false brick*: a reported brick with no true brick of that layout within 8 cm.

Rendered frames are cached (PNG + truth JSON) in ``--cache`` (default
``~/.cache/drovisio/bench-dots``), so a second run only measures.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from drovisio.bounds import ArgumentParser, whole

EXAMPLE = """example:
  drovisio bench dots                      # all parts, default frame counts (~15 min first run)
  drovisio bench dots --quick              # small counts, a couple of minutes
  drovisio bench dots --parts timing,memory --memory-frames 20000
  drovisio bench dots --json report.json   # also write the figures as JSON
"""

PARTS = ("accuracy", "hidden", "clutter", "lighting", "timing", "memory", "kernels")


def _parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="drovisio bench dots",
        description="Benchmark of the colour-dot detector on rendered scenes: "
                    "recall, pose errors, flips, false bricks, lighting, speed, memory.",
        epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default=",".join(PARTS),
                   help=f"comma-separated parts to run (default: all of {','.join(PARTS)})")
    p.add_argument("--quick", action="store_true", help="small frame counts (a smoke run)")
    p.add_argument("--frames", type=whole(1, 1_000_000), default=None,
                   help="frames of the accuracy part (default 300; quick 40)")
    p.add_argument("--hidden-frames", type=whole(1, 1_000_000), default=None, help="default 200; quick 30")
    p.add_argument("--clutter-frames", type=whole(1, 1_000_000), default=None, help="default 220; quick 30")
    p.add_argument("--lighting-frames", type=whole(1, 1_000_000), default=None,
                   help="frames per gain × gamma cell (default 12; quick 2)")
    p.add_argument("--timing-frames", type=whole(1, 1_000_000), default=None,
                   help="frames per brick count (default 6; quick 3)")
    p.add_argument("--timing-repeats", type=whole(1, 1_000_000), default=None,
                   help="timed runs per frame (default 40; quick 10)")
    p.add_argument("--memory-frames", type=whole(1, 1_000_000), default=None,
                   help="frames of the memory loop (default 20000; quick 2000)")
    p.add_argument("--memory-trace", action="store_true",
                   help="also trace Python's allocations in the memory part (slower)")
    p.add_argument("--seed", type=whole(0, 2**32 - 1), default=0, help="first scene seed")
    p.add_argument("--layout", default=None,
                   help="layout file (default: the shipped drick-dots-2x3.json)")
    p.add_argument("--cache", default=None,
                   help="folder for rendered frames (default ~/.cache/drovisio/bench-dots)")
    p.add_argument("--no-cache", action="store_true", help="render every frame afresh")
    p.add_argument("--threads", type=whole(1, 256), default=None,
                   help="cv2.setNumThreads for the timing part (default: OpenCV's own)")
    p.add_argument("--json", metavar="FILE", help="write all figures as JSON")
    return p


# =============================================================================== frames
@dataclass
class DotTruth:
    layout: str
    camera_from_brick: list
    centers_px: list
    visible: list
    size_px: list


@dataclass
class Frame:
    image: np.ndarray
    gravity: np.ndarray
    bricks: list[DotTruth] = field(default_factory=list)


_MODELS: dict = {}


def _visibility(scene, result, camera) -> list[DotTruth]:
    """Per brick and dot: fully visible? projected size (equivalent diameter, px)."""
    import trimesh

    from drovisio.detect.dots.match import DotModel, occluded_dots
    from drovisio.synth import brick_mesh_for

    cfw = result.camera_from_world
    world_from_camera = np.linalg.inv(cfw)
    cam_w = world_from_camera[:3, 3]
    meshes = []
    for prop in scene.props:
        m = prop.mesh.copy()
        m.apply_transform(prop.world_from_object)
        meshes.append(m)
    brick_meshes = []
    for b in scene.bricks:
        m = brick_mesh_for(b.layout).copy()
        m.apply_transform(b.world_from_brick)
        brick_meshes.append(m)
    out = []
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    for k, (b, truth) in enumerate(zip(scene.bricks, result.bricks)):
        lay = b.layout
        cfb = truth.camera_from_brick
        X = lay.dot_centers_m()
        nrm = lay.dot_normals()
        rad = lay.dot_diameters_m() / 2
        dot_marker_index = [i for i, m in enumerate(lay.markers) if m.kind == "dot"]
        model = _MODELS.get(id(lay))
        if model is None:
            colors = {c: i for i, c in enumerate(dict.fromkeys(lay.dot_colors()))}
            model = _MODELS[id(lay)] = DotModel.from_layout(lay, colors)
        own = occluded_dots(model, cfb[None, :3, :3], cfb[None, :3, 3])[0]
        others = [m for j, m in enumerate(brick_meshes) if j != k] + meshes
        other = trimesh.util.concatenate(others) if others else None
        vis, size = [], []
        for d in range(len(X)):
            u = np.cross(nrm[d], [1.0, 0, 0] if abs(nrm[d][0]) < 0.9 else [0, 1.0, 0])
            u /= np.linalg.norm(u)
            v = np.cross(nrm[d], u)
            rim = X[d] + rad[d] * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
            px = camera.project_from(rim, cfb)
            x, y = px[:, 0], px[:, 1]
            x1, y1 = np.roll(x, -1), np.roll(y, -1)
            area = abs(float((x * y1 - x1 * y).sum()) / 2)
            size.append(2 * math.sqrt(area / math.pi))
            ok = (dot_marker_index[d] not in b.hidden_markers) and not own[d]
            ok = ok and bool(np.all((x >= 1) & (x <= camera.width - 2) & (y >= 1)
                                    & (y <= camera.height - 2)))
            Yc = rim @ cfb[:3, :3].T + cfb[:3, 3]
            ok = ok and bool(np.all(Yc[:, 2] > 0)) and float(
                -(cfb[:3, :3] @ nrm[d]) @ (cfb[:3, :3] @ X[d] + cfb[:3, 3])) > 0
            if ok and other is not None:
                rim_w = (world_from_camera[:3, :3] @ Yc.T).T + world_from_camera[:3, 3]
                dirs = rim_w - cam_w
                dist = np.linalg.norm(dirs, axis=1)
                dirs /= dist[:, None]
                locs, idx_ray, _ = other.ray.intersects_location(
                    np.repeat(cam_w[None], len(dirs), 0), dirs, multiple_hits=False)
                if len(idx_ray):
                    hit_d = np.linalg.norm(locs - cam_w, axis=1)
                    ok = not bool(np.any(hit_d < dist[idx_ray] - 1e-4))
            vis.append(bool(ok))
        out.append(DotTruth(layout=truth.layout, camera_from_brick=cfb.tolist(),
                            centers_px=np.asarray(truth.dot_centers_px).tolist(), visible=vis,
                            size_px=size))
    return out


class FrameSource:
    """Renders (or loads from the cache) frames named by (part, seed, spec)."""

    def __init__(self, layout, cache: Path | None):
        from drovisio.camera import Camera

        self.layout = layout
        self.camera = Camera.drone_webcam()
        self.cache = cache
        if cache is not None:
            cache.mkdir(parents=True, exist_ok=True)

    def get(self, key: str, seed: int, spec, hide: tuple[int, int] | None = None) -> Frame:
        from drovisio.scenes import random_scene

        tag = hashlib.sha1(repr((key, seed, _spec_repr(spec), hide, self.layout.name,
                                 "v2")).encode()).hexdigest()[:16]
        hit, png, js = self._cached(key, seed, tag)
        if hit is not None:
            return hit
        scene, fx = random_scene(seed, spec, self.camera)
        return self._render(scene, fx, png, js, seed, hide)

    def _cached(self, key: str, seed: int, tag: str):
        """(frame from the cache or None, png path, json path); paths are None without a
        cache."""
        import cv2

        if self.cache is None:
            return None, None, None
        stem = f"{key}-{seed}-{tag}"
        png, js = self.cache / f"{stem}.png", self.cache / f"{stem}.json"
        if png.is_file() and js.is_file():
            try:
                img = cv2.imread(str(png), cv2.IMREAD_COLOR)
                meta = json.loads(js.read_text())
                if img is not None:
                    return (Frame(image=img, gravity=np.array(meta["gravity"]),
                                  bricks=[DotTruth(**b) for b in meta["bricks"]]), png, js)
            except (OSError, ValueError, KeyError, TypeError):
                pass  # a broken or stale cache entry: render it again
        return None, png, js

    def get_scene(self, key: str, seed: int, build) -> Frame:
        """A frame of a scene made by ``build() -> (Scene, Effects)`` (cached by key, seed)."""
        tag = hashlib.sha1(repr((key, seed, self.layout.name, "v2")).encode()).hexdigest()[:16]
        hit, png, js = self._cached(key, seed, tag)
        if hit is not None:
            return hit
        scene, fx = build()
        return self._render(scene, fx, png, js, seed, None)

    def _render(self, scene, fx, png, js, seed, hide) -> Frame:

        from drovisio.scenes import gravity_in_camera
        from drovisio.synth import render

        if hide is not None:
            rng = np.random.default_rng(seed + 99991)
            dots = [i for i, m in enumerate(self.layout.markers) if m.kind == "dot"]
            for b in scene.bricks:
                k = int(rng.integers(hide[0], hide[1] + 1))
                b.hidden_markers = frozenset(int(i) for i in rng.choice(dots, k, replace=False))
        res = render(scene, fx, ss=3)
        frame = Frame(image=res.image, gravity=gravity_in_camera(res.camera_from_world),
                      bricks=_visibility(scene, res, self.camera))
        if png is not None:
            from drovisio.fileio import atomic_write_text, write_image

            # each file written beside and renamed; the picture last, as the entry's mark of
            # completeness (an entry is read only when both are there)
            atomic_write_text(js, json.dumps({"gravity": frame.gravity.tolist(),
                                              "bricks": [asdict(b) for b in frame.bricks]}),
                              make_parents=True)
            write_image(png, frame.image)
        return frame


def _spec_repr(spec) -> str:
    d = dict(vars(spec))
    d["layouts"] = [x.name for x in spec.layouts]
    return repr(sorted(d.items()))


# ================================================================================ scoring
def _rot(rvec) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]


def _angle(R: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))


def _pose_errors(truth: DotTruth, R_est: np.ndarray, t_est: np.ndarray, symmetric: bool
                 ) -> dict:
    T = np.asarray(truth.camera_from_brick)
    Rt, tt = T[:3, :3], T[:3, 3]
    E = Rt.T @ R_est
    yaw = math.degrees(math.atan2(E[1, 0] - E[0, 1], E[0, 0] + E[1, 1]))
    period = 180.0 if symmetric else 360.0
    yaw = (yaw + period / 2) % period - period / 2
    rot = _angle(E)
    if symmetric:
        rot = min(rot, _angle(E @ np.diag([-1.0, -1.0, 1.0])))
    return {"lateral_m": float(np.hypot(*(t_est - tt)[:2])),
            "depth_rel": float(abs(t_est[2] - tt[2]) / tt[2]),
            "yaw_deg": abs(yaw), "rot_deg": rot, "dist_m": float(np.linalg.norm(tt))}


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
        self.frames += 1
        matched = set()
        for bi, b in enumerate(frame.bricks):
            T = np.asarray(b.camera_from_brick)
            best, bd = None, 0.08
            for k, p in enumerate(poses):
                if k in matched or p.layout != b.layout:
                    continue
                d = float(np.linalg.norm(np.asarray(p.tvec) - T[:3, 3]))
                if d < bd:
                    best, bd = k, d
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
            e = _pose_errors(b, _rot(p.rvec), np.asarray(p.tvec, float),
                             symmetric_of(p.layout))
            e["eligible"] = elig
            e["ambiguous"] = bool(p.ambiguous)
            e["n_dots"] = len(p.markers)
            self.errors.append(e)
            flip = e["rot_deg"] > 20.0
            self.flips += flip
            self.unflagged_flips += flip and not p.ambiguous
            if p.image_points is not None and len(p.markers):
                mk = np.asarray(p.markers)
                err = np.asarray(p.image_points) - np.asarray(b.centers_px)[mk]
                perm = perm_of(p.layout) if perm_of else None
                if perm is not None:  # a half-turned report labels the dots the other way
                    err2 = np.asarray(p.image_points) - np.asarray(b.centers_px)[perm[mk]]
                    if np.abs(err2).sum() < np.abs(err).sum():
                        err = err2
                self.bias.append(err)
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


# ================================================================================= parts
def _layout(path: str | None):
    from drovisio.layout import load_layout, shipped_layouts_dir

    return load_layout(path or shipped_layouts_dir() / "drick-dots-2x3.json")


def _run_frames(src: FrameSource, det, key: str, seeds, spec, hide=None, gravity=(True, False),
                progress: str = "") -> dict:
    tallies = {g: Tally() for g in gravity}
    sym = {m.name: m.sym_perm is not None for m in det.models}
    perms = {m.name: m.sym_perm for m in det.models}
    t0 = time.time()
    for n, seed in enumerate(seeds):
        fr = src.get(key, seed, spec, hide)
        for g in gravity:
            poses = det.detect(fr.image, gravity=fr.gravity if g else None)
            tallies[g].add(fr, poses, lambda name: sym.get(name, False), tag=f"{key}:{seed}",
                           perm_of=perms.get)
        if progress and (n + 1) % 25 == 0:
            print(f"  {progress}: {n + 1}/{len(seeds)} frames ({time.time() - t0:.0f} s)",
                  file=sys.stderr, flush=True)
    return {("gravity" if g else "no_gravity"): tallies[g].summary() | {
        "missed": tallies[g].missed[:20]} for g in gravity}


def _scene_spec(layout, **kw):
    from drovisio.scenes import SceneSpec

    base = {"layouts": [layout], "n_bricks": 3, "props": 2}
    base.update(kw)
    return SceneSpec(**base)


def part_accuracy(src, det, args, n) -> dict:
    spec = _scene_spec(src.layout, n_bricks=3, props=2)
    return _run_frames(src, det, "acc", range(args.seed, args.seed + n), spec,
                       progress="accuracy")


def part_hidden(src, det, args, n) -> dict:
    out = {}
    spec = _scene_spec(src.layout, n_bricks=3, props=1)
    out["unpainted_1_2"] = _run_frames(src, det, "hid", range(args.seed, args.seed + n), spec,
                                       hide=(1, 2), gravity=(True,), progress="hidden dots")
    spec2 = _scene_spec(src.layout, n_bricks=3, props=1, stack_prob=0.6)
    out["stacked"] = _run_frames(src, det, "stk", range(args.seed, args.seed + n // 2), spec2,
                                 gravity=(True,), progress="stacked bricks")
    return out


def part_clutter(src, det, args, n) -> dict:
    spec = _scene_spec(src.layout, n_bricks=0, props=8, grounds=("clutter",),
                       distance=(0.4, 2.0))
    res = _run_frames(src, det, "clu", range(args.seed, args.seed + n), spec,
                      progress="clutter")
    return {k: {"frames": v["frames"], "false_bricks": v["false_bricks"]}
            for k, v in res.items()}


def part_lighting(src, det, args, n) -> dict:
    out = {}
    for gain in (0.6, 0.8, 1.0, 1.3):
        for gamma in (0.8, 1.0, 1.25):
            spec = _scene_spec(src.layout, n_bricks=3, props=2, gain=(gain, gain),
                               gamma=(gamma, gamma))
            r = _run_frames(src, det, f"lit{gain}-{gamma}", range(args.seed, args.seed + n),
                            spec, gravity=(True,))["gravity"]
            out[f"gain {gain} gamma {gamma}"] = {k: r[k] for k in (
                "eligible", "found", "recall", "lateral_p95_cm", "depth_p95_pct",
                "yaw_p95_deg", "false_bricks")}
    return out


def _minimal_pass(palette_specs):
    import cv2

    ranges = [s.cv_ranges()[0] for s in palette_specs]

    def run(img):
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        for lo, hi in ranges:
            cv2.inRange(hsv, lo, hi)
    return run


_GROUNDS = ("gravel", "grass", "clutter")


def _timing_frames(src, args, nbricks: int, n: int) -> list[Frame]:
    """Bricks on a 5 × 4 grid seen from 1.75 m (so that 20 fit in view, dots ≈ 6–7 px): 1, 5
    or 20 of its cells filled, on gravel, grass or photo clutter; the same camera poses for
    every brick count."""
    from drovisio.synth import (
        BrickInstance,
        Effects,
        Ground,
        Scene,
        camera_over,
        rot_z,
        transform,
    )

    cells = [((c - 2) * 0.40, (r - 1.5) * 0.26) for r in range(4) for c in range(5)]
    pick = {1: [7], 5: [6, 8, 11, 13, 2], 20: list(range(20))}.get(nbricks)
    if pick is None:
        pick = list(range(min(nbricks, 20)))
    frames = []
    for k in range(n):
        seed = args.seed + k

        def build(seed=seed):
            rng = np.random.default_rng(1000 + seed)
            bricks = [BrickInstance(src.layout, transform(rot_z(float(rng.uniform(-0.25, 0.25))),
                                                          [cells[c][0], cells[c][1], 0.1]),
                                    instance=None) for c in pick]
            cfw = camera_over([0.0, 0.0, 0.1], 1.75, float(rng.uniform(0, 10)),
                              float(rng.choice([0.0, 180.0])) + float(rng.uniform(-5, 5)))
            scene = Scene(camera=src.camera, camera_from_world=cfw,
                          ground=Ground(_GROUNDS[seed % 3], seed=seed % 4), bricks=bricks)
            fx = Effects(blur_sigma_px=0.5, noise_sigma=2.0, jpeg_quality=90, seed=seed)
            return scene, fx
        frames.append(src.get_scene(f"tim{nbricks}", seed, build))
    return frames


def part_timing(src, det, args, n, repeats) -> dict:
    """Per-frame time of the detector and of the minimal pass on the same frames, for 1, 5
    and 20 bricks in view. Every repeat visits every frame of every brick count once (minimal
    pass, then detector), so a change of the machine's load hits all counts alike; each
    figure is the median over a frame's repeats, then the median over frames."""
    import cv2

    if args.threads is not None:
        cv2.setNumThreads(args.threads)
    minimal = _minimal_pass(det.specs)
    counts = (1, 5, 20)
    frames = {nb: _timing_frames(src, args, nb, n) for nb in counts}
    wall, cpu = time.perf_counter, time.process_time
    from drovisio.detect.dots import kernels as dots_kernels

    compiled = dots_kernels.enabled()
    samples = {(nb, k): ([], [], [], [], []) for nb in counts for k in range(n)}
    found = {nb: [0] * n for nb in counts}
    for fr_list in frames.values():
        for fr in fr_list:
            for _ in range(3):  # warm-up
                minimal(fr.image)
                det.detect(fr.image, gravity=fr.gravity)
    for _ in range(repeats):
        for nb in counts:
            for k, fr in enumerate(frames[nb]):
                a, b, ca, cb, _ = samples[(nb, k)]
                t, c = wall(), cpu()
                minimal(fr.image)
                a.append(wall() - t)
                ca.append(cpu() - c)
                t, c = wall(), cpu()
                poses = det.detect(fr.image, gravity=fr.gravity)
                b.append(wall() - t)
                cb.append(cpu() - c)
                found[nb][k] = len(poses)
    if compiled:
        # the same detector on its numpy path, for comparison (a pass of its own: interleaved,
        # its larger working set would evict the compiled path's data between calls)
        dots_kernels.set_enabled(False)
        try:
            for _ in range(max(3, repeats // 4)):
                for nb in counts:
                    for k, fr in enumerate(frames[nb]):
                        t = wall()
                        det.detect(fr.image, gravity=fr.gravity)
                        samples[(nb, k)][4].append(wall() - t)
        finally:
            dots_kernels.set_enabled(True)
    out = {"threads": cv2.getNumThreads(), "repeats": repeats, "frames_per_count": n,
           "compiled_kernels": compiled}
    base = None
    for nb in counts:
        t_min, t_det, c_min, c_det = ([float(np.median(samples[(nb, k)][i])) for k in range(n)]
                                      for i in range(4))
        inview = [sum(int(np.sum(x.visible)) >= 4 for x in fr.bricks) for fr in frames[nb]]
        row = {"frames": n, "bricks_in_view_median": float(np.median(inview)),
               "bricks_found_median": float(np.median(found[nb])),
               "minimal_ms": 1e3 * float(np.median(t_min)),
               "detect_ms": 1e3 * float(np.median(t_det)),
               "ratio": float(np.median(np.asarray(t_det) / np.asarray(t_min))),
               "minimal_cpu_ms": 1e3 * float(np.median(c_min)),
               "detect_cpu_ms": 1e3 * float(np.median(c_det)),
               "ratio_cpu": float(np.median(c_det) / max(np.median(c_min), 1e-9)),
               "loadavg": os.getloadavg()[0]}
        if compiled:
            t_npy = [float(np.median(samples[(nb, k)][4])) for k in range(n)]
            row["numpy_path_ms"] = 1e3 * float(np.median(t_npy))
            row["numpy_path_vs_compiled"] = float(np.median(np.asarray(t_npy)
                                                            / np.asarray(t_det)))
        if base is None:
            base = row
        row["vs_1_brick"] = row["detect_ms"] / base["detect_ms"]
        row["vs_1_brick_cpu"] = row["detect_cpu_ms"] / base["detect_cpu_ms"]
        out[f"{nb}_bricks"] = row
    return out


def part_kernels(src, det, args, n, repeats) -> dict:
    """Median time of each compiled kernel and of what it replaces, on the same inputs (the
    stages of the 20-brick timing frames), in this process."""
    import cv2

    from drovisio.camera import PIXEL_STENCIL
    from drovisio.camera_kernels import lens_coefficients
    from drovisio.detect.dots import kernels as K
    from drovisio.detect.dots.blobs import refine_centers
    from drovisio.detect.dots.color import ClaheMap
    from drovisio.detect.dots.match import BlobGeometry, generate_hypotheses
    from drovisio.pose import batch as dots_pose

    if not K.enabled():
        return {"skipped": "numba is not installed (or DROVISIO_NUMBA=0)"}
    cfg = det.config
    m = det.models[0]
    T = m.plane_from_brick
    cases: dict[str, list[tuple]] = {}

    def both(name, fast, ref):
        cases.setdefault(name, []).append((fast, ref))

    for fr in _timing_frames(src, args, 20, n):
        img = fr.image
        blobs, hsv = det.blobs(img)
        poses = det.detect(img, gravity=fr.gravity)
        if not len(blobs) or not poses:
            continue
        idx = np.arange(len(blobs))

        def off(fn):
            def run():
                K.set_enabled(False)
                try:
                    return fn()
                finally:
                    K.set_enabled(True)
            return run

        both("sub-pixel centres (all blobs)", lambda: refine_centers(img, blobs, idx),
             off(lambda: refine_centers(img, blobs, idx)))
        v = hsv[:, :, 2]
        x, y = np.ascontiguousarray(blobs.x), np.ascontiguousarray(blobs.y)
        raw = v[np.clip(np.rint(y).astype(int), 0, v.shape[0] - 1),
                np.clip(np.rint(x).astype(int), 0, v.shape[1] - 1)].astype(float)
        both("CLAHE at the blobs", lambda: K.clahe_at(hsv, x, y, 8, 8, cfg.clahe_stride,
                                                      cfg.clahe_clip),
             lambda: ClaheMap(v, cfg.clahe_clip, cfg.clahe_tiles, cfg.clahe_stride)(x, y, raw))
        q, cov = det._blob_geometry(blobs)
        geo = BlobGeometry.build(q, cov, blobs.color, ~blobs.border)
        hyp = lambda: generate_hypotheses(m, geo, cfg.seeds_per_blob, cfg.ratio_tol,  # noqa
                                          cfg.match_tol, cfg.min_dots)
        both("matching hypotheses", hyp, off(hyp))
        # poses: the bricks found, their dots' normalised image points
        B = len(poses)
        qs = np.zeros((B, m.n, 2))
        w = np.zeros((B, m.n))
        for b, p in enumerate(poses):
            qs[b, p.markers] = det._normalize(p.image_points)
            w[b, p.markers] = 1.0
        Pm = np.repeat(m.P[None], B, axis=0)
        Rpb, tpb = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
        both("IPPE, both solutions (vs cv2.solvePnPGeneric per brick)",
             lambda: K.ippe(Pm, qs, w, Rpb, tpb),
             lambda: [cv2.solvePnPGeneric(m.X[w[b] > 0], qs[b][w[b] > 0], np.eye(3), None,
                                          flags=cv2.SOLVEPNP_IPPE) for b in range(B)])
        R0 = np.array([cv2.Rodrigues(p.rvec)[0] for p in poses])
        t0 = np.array([p.tvec for p in poses])
        X = np.repeat(m.X[None], B, axis=0)
        lm = lambda: dots_pose.refine_poses(X, qs, w, R0, t0 + 0.003, 4)  # noqa: E731
        both("Levenberg-Marquardt, all bricks", lm, off(lm))
        px = np.stack([blobs.x, blobs.y], axis=1)
        Kc, dist = det.camera.K, det.camera.dist
        d12 = None if det.camera.is_fisheye else lens_coefficients(dist)
        if d12 is not None:
            args12 = (Kc[0, 0], Kc[1, 1], Kc[0, 2], Kc[1, 2], d12)
            both("undistortion + local Jacobian (vs cv2.undistortPoints, 5-point stencil)",
                 lambda: K.undistort(px, *args12),
                 lambda: cv2.undistortPoints((px[None] + PIXEL_STENCIL[:, None]).reshape(-1, 1, 2),
                                             Kc, dist, None, None, None,
                                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                              20, 1e-12)))
    out = {}
    for name, pairs in cases.items():
        tf, tr = [], []
        for fast, ref in pairs:
            fast()
            ref()
            a, b = [], []
            for _ in range(repeats):
                t = time.perf_counter()
                fast()
                a.append(time.perf_counter() - t)
                t = time.perf_counter()
                ref()
                b.append(time.perf_counter() - t)
            tf.append(float(np.median(a)))
            tr.append(float(np.median(b)))
        out[name] = {"compiled_us": 1e6 * float(np.median(tf)),
                     "reference_us": 1e6 * float(np.median(tr)),
                     "speedup": float(np.median(np.asarray(tr) / np.asarray(tf)))}
    return out


def _rss_kb() -> int:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") // 1024


def part_memory(src, det, args, nframes) -> dict:
    """Resident memory over ``nframes`` calls of :func:`detect_dots` (with a stream state) on
    a loop of cached frames with 1, 5 and 20 bricks.

    RSS is sampled every 250 frames after the warm-up (after ``gc.collect()``). It oscillates
    by about a megabyte as malloc grows and trims its heap for the frames' temporaries, so
    besides the raw end − warm-up difference the report gives the growth of the floor (lowest
    sample of the last quarter − lowest of the first quarter) and the trend (least-squares
    slope × frames); with ``--memory-trace`` also the growth of Python's own allocations
    (tracemalloc), which is what a leak would show first.
    """
    import tracemalloc

    from drovisio.detect.dots import DotsState, detect_dots

    frames = (_timing_frames(src, args, 1, 2) + _timing_frames(src, args, 5, 2)
              + _timing_frames(src, args, 20, 2))
    state = DotsState()
    nf = len(frames)
    # warm-up and end both just after the last frame of the loop (the same objects alive)
    nframes = max(nf * 2, -(-nframes // nf) * nf)
    warm = max(nf, min(1000, nframes // 10) // nf * nf) - 1
    xs, samples = [], []
    t0 = time.time()
    rss_warm = None
    traced0 = None
    if args.memory_trace:
        tracemalloc.start()
    for k in range(nframes):
        fr = frames[k % len(frames)]
        detect_dots(fr.image, src.camera, [src.layout], gravity=fr.gravity, state=state)
        if k == warm:
            gc.collect()
            rss_warm = _rss_kb()
            if args.memory_trace:
                traced0 = tracemalloc.get_traced_memory()[0]
        if k >= warm and (k - warm) % 250 == 0:
            gc.collect()
            xs.append(k)
            samples.append(_rss_kb())
        if (k + 1) % 2000 == 0:
            print(f"  memory: {k + 1}/{nframes} frames ({time.time() - t0:.0f} s, RSS "
                  f"{_rss_kb() / 1024:.1f} MB)", file=sys.stderr, flush=True)
    gc.collect()
    rss_end = _rss_kb()
    xs.append(nframes)
    samples.append(rss_end)
    traced = None
    if traced0 is not None:
        traced = (tracemalloc.get_traced_memory()[0] - traced0) / 1024
        tracemalloc.stop()
    q = max(1, len(samples) // 4)
    slope = float(np.polyfit(np.asarray(xs, float), np.asarray(samples, float), 1)[0]) \
        if len(samples) > 2 else 0.0
    return {"frames": nframes, "warmup_frames": warm, "rss_after_warmup_kb": rss_warm,
            "rss_end_kb": rss_end, "growth_kb": rss_end - rss_warm,
            "floor_growth_kb": min(samples[-q:]) - min(samples[:q]),
            "trend_kb": slope * (nframes - warm),
            "band_kb": max(samples) - min(samples),
            "python_heap_growth_kb": traced, "seconds": time.time() - t0}


# ================================================================================= report
def _fmt(v, nd=2):
    if v is None:
        return "–"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.{nd}f}"
    return str(v)


def _print_report(rep: dict) -> None:
    w = print
    w("\ndrovisio bench dots — colour-dot bricks")
    w("=" * 78)
    acc = rep.get("accuracy")
    if acc:
        w("\nAccuracy (random scenes 0.4–2 m, tilt ≤ 40°; errors at ≤ 2 m, p95)")
        w(f"{'':24}{'recall':>8}{'rec.6dots':>10}{'lat cm':>8}{'depth %':>8}{'yaw °':>7}"
          f"{'flips':>6}{'unflag':>7}{'ambig':>7}{'false':>6}")
        for k in ("gravity", "no_gravity"):
            r = acc[k]
            w(f"{k + ' (' + str(r['eligible']) + ' bricks)':24}{_fmt(100 * r['recall'], 1):>8}"
              f"{_fmt(100 * r['recall_all_dots'], 1):>10}{_fmt(r['lateral_p95_cm']):>8}"
              f"{_fmt(r['depth_p95_pct']):>8}{_fmt(r['yaw_p95_deg']):>7}{r['flips']:>6}"
              f"{r['unflagged_flips']:>7}{_fmt(100 * r['ambiguous_share'], 0) + '%':>7}"
              f"{r['false_bricks']:>6}")
        r = acc["gravity"]
        w(f"dot centres vs BrickTruth.dot_centers_px: bias ({r['center_bias_px'][0]:+.3f}, "
          f"{r['center_bias_px'][1]:+.3f}) px, rms {r['center_rms_px']:.3f} px over "
          f"{r['centers']} dots")
    hid = rep.get("hidden")
    if hid:
        w("\nHidden dots (with gravity)")
        for k, v in hid.items():
            r = v["gravity"]
            w(f"  {k:16} recall {_fmt(100 * r['recall'], 1)}% of {r['eligible']} eligible, "
              f"lat {_fmt(r['lateral_p95_cm'])} cm, depth {_fmt(r['depth_p95_pct'])} %, yaw "
              f"{_fmt(r['yaw_p95_deg'])}°, unflagged flips {r['unflagged_flips']}, false "
              f"{r['false_bricks']}")
    clu = rep.get("clutter")
    if clu:
        w("\nClutter without bricks (red cups, blue tarpaulins, photo clutter)")
        for k, v in clu.items():
            w(f"  {k:16} {v['false_bricks']} false bricks in {v['frames']} frames")
    lit = rep.get("lighting")
    if lit:
        w("\nLighting (default palette, with gravity)")
        for k, r in lit.items():
            w(f"  {k:22} recall {_fmt(100 * r['recall'], 1):>5}% of {r['eligible']:>3}, lat "
              f"{_fmt(r['lateral_p95_cm'])} cm, depth {_fmt(r['depth_p95_pct'])} %, yaw "
              f"{_fmt(r['yaw_p95_deg'])}°, false {r['false_bricks']}")
    tim = rep.get("timing")
    if tim:
        kern = "compiled kernels" if tim.get("compiled_kernels") else \
            "numpy path (no numba, or DROVISIO_NUMBA=0)"
        w(f"\nTiming (medians of {tim.get('repeats', '?')} interleaved runs of "
          f"{tim.get('frames_per_count', '?')} frames per count; minimal pass = cvtColor to "
          f"HSV + one cv2.inRange per colour; OpenCV threads {tim['threads']}; {kern}; wall "
          f"clock, then process CPU time)")
        w(f"{'':12}{'in view':>8}{'found':>7}{'minimal ms':>12}{'detect ms':>11}{'ratio':>7}"
          f"{'vs 1 brick':>11}{'cpu ratio':>10}{'cpu vs 1':>9}{'load':>6}{'numpy ms':>10}")
        for k in ("1_bricks", "5_bricks", "20_bricks"):
            r = tim.get(k)
            if r:
                w(f"{k:12}{_fmt(r['bricks_in_view_median'], 0):>8}"
                  f"{_fmt(r['bricks_found_median'], 0):>7}{_fmt(r['minimal_ms'], 3):>12}"
                  f"{_fmt(r['detect_ms'], 3):>11}{_fmt(r['ratio']):>7}"
                  f"{_fmt(r['vs_1_brick']):>11}{_fmt(r['ratio_cpu']):>10}"
                  f"{_fmt(r['vs_1_brick_cpu']):>9}{_fmt(r['loadavg'], 1):>6}"
                  f"{_fmt(r.get('numpy_path_ms'), 3):>10}")
    ker = rep.get("kernels")
    if ker:
        w("\nCompiled kernels vs what they replace (20-brick frames, medians, µs)")
        if "skipped" in ker:
            w(f"  skipped: {ker['skipped']}")
        for name, r in ker.items():
            if isinstance(r, dict):
                w(f"  {name:74}{r['compiled_us']:9.1f}{r['reference_us']:10.1f}"
                  f"  ×{r['speedup']:.1f}")
    mem = rep.get("memory")
    if mem:
        w(f"\nMemory: {mem['frames']} frames ({mem['seconds']:.0f} s), RSS after "
          f"{mem['warmup_frames']} warm-up frames {mem['rss_after_warmup_kb']} kB, at the end "
          f"{mem['rss_end_kb']} kB: growth {mem['growth_kb']:+} kB; floor growth "
          f"{mem['floor_growth_kb']:+} kB, trend {mem['trend_kb']:+.0f} kB, samples within a "
          f"{mem['band_kb']} kB band" + (
              f"; Python heap growth {mem['python_heap_growth_kb']:+.1f} kB"
              if mem["python_heap_growth_kb"] is not None else ""))
    w("\nDefinitions: eligible = ≥ 4 fully visible dots of median size ≥ 6 px (equivalent "
      "diameter); lateral = |(Δx, Δy)| of tvec in the camera frame; depth = |Δz|/z; yaw = "
      "rotation about the brick z of R_trueᵀR_est (mod 180° for rot180_z); flip = > 20° off "
      "(mod symmetry), unflagged = not marked ambiguous; false = no true brick within 8 cm.")


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    if args.json:
        from drovisio.fileio import check_output_path

        check_output_path(args.json, "--json", folder_must_exist=True)
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad:
        print(f"drovisio bench dots: unknown part(s) {', '.join(bad)}; choose from "
              f"{', '.join(PARTS)}", file=sys.stderr)
        return 2
    q = args.quick
    n_acc = args.frames or (40 if q else 300)
    n_hid = args.hidden_frames or (30 if q else 200)
    n_clu = args.clutter_frames or (30 if q else 220)
    n_lit = args.lighting_frames or (2 if q else 12)
    n_tim = args.timing_frames or (3 if q else 6)
    reps = args.timing_repeats or (10 if q else 40)
    n_mem = args.memory_frames or (2000 if q else 20000)
    from drovisio.detect.dots import DotDetector

    layout = _layout(args.layout)
    cache = None if args.no_cache else Path(args.cache or Path.home() / ".cache" / "drovisio"
                                            / "bench-dots")
    src = FrameSource(layout, cache)
    det = DotDetector(src.camera, [layout])
    rep: dict = {"layout": layout.name, "camera": src.camera.name}
    t0 = time.time()
    if "accuracy" in parts:
        rep["accuracy"] = part_accuracy(src, det, args, n_acc)
    if "hidden" in parts:
        rep["hidden"] = part_hidden(src, det, args, n_hid)
    if "clutter" in parts:
        rep["clutter"] = part_clutter(src, det, args, n_clu)
    if "lighting" in parts:
        rep["lighting"] = part_lighting(src, det, args, n_lit)
    if "timing" in parts:
        rep["timing"] = part_timing(src, det, args, n_tim, reps)
    if "memory" in parts:
        rep["memory"] = part_memory(src, det, args, n_mem)
    if "kernels" in parts:
        rep["kernels"] = part_kernels(src, det, args, n_tim, max(10, reps // 2))
    rep["seconds"] = time.time() - t0
    _print_report(rep)
    if args.json:
        from drovisio.fileio import atomic_write_text

        atomic_write_text(args.json, json.dumps(rep, indent=2, default=float))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
