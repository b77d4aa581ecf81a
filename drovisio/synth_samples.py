"""Regenerate ``sample_sessions/``: the data the web tool and the examples run on with no camera.

``drovisio synth samples [--out DIR]`` (or ``make samples``) writes, deterministically:

* ``camera.yaml`` — the true camera of every sample (the thesis's 60° webcam, 640×480, with
  distortion), in the OpenCV form.
* ``calibration/`` — 20 chessboard views (9×6 inner corners, 25 mm squares) as a field session
  would take them: first near the image centre, then toward the edges and corners, tilted;
  ``truth.json`` holds each view's ``camera_from_board`` and true corner pixels.
* ``study/`` — a recorded-style study (renders written as videos and a folder of images, with
  ``protocol.yaml`` giving each step's set-up): ``drovisio study run --protocol
  sample_sessions/study/protocol.yaml --out report/``;
* ``missions/`` — a short simulated mission (three bricks of the shipped wall), recorded for
  the live page's replay;
* ``approach/`` — ``approach.mp4``: a drone descending from 2 m onto a row of five dricks
  (codes on pyramids, a centre code, colour dots), 10 s at 15 fps, camera tilted 20° forward
  under the drone; ``truth.jsonl`` (per frame: time, ``camera_from_world``, each brick's true
  ``camera_from_brick``), ``gravity.jsonl`` (``--gravity-file`` input of ``drovisio detect``),
  ``mount.json`` (``body_from_camera``) and ``scene.json`` (layouts and world poses).
* ``pad/`` — three pictures of the shipped landing pad lying flat, its arrow (x axis) toward
  the nose, seen by the same camera on the same mount (``mount.json``: the truth) with the
  drone standing level at three headings and heights: ``drovisio calibrate mount --camera
  sample_sessions/camera.yaml --aligned --out mount.json sample_sessions/pad`` measures it.

``drovisio synth samples --only pad`` rewrites one part (``calibration``, ``approach``,
``missions``, ``study``, ``pad``).
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from drovisio.calibration.board import parse_board
from drovisio.calibration.geometry import fit_board
from drovisio.camera import Camera
from drovisio.camera_file import save_camera
from drovisio.fileio import atomic_write_bytes, atomic_write_text, write_image
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.mission.check import check_rules
from drovisio.mission.record import write_recording
from drovisio.mission.scenario import load_scenario, shipped_scenario
from drovisio.mission.sim import SimParams, simulate
from drovisio.mount import Mount
from drovisio.resources import sample_sessions_dir
from drovisio.scenes import gravity_in_camera, level_drone_over_code
from drovisio.study.example import write_recorded_example
from drovisio.synth import (
    BrickInstance,
    Effects,
    Ground,
    Scene,
    render,
    render_chessboard,
    rot_z,
    rvec_tvec,
    transform,
)

FPS = 15
SECONDS = 10
JPEG_QUALITY = 90


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def calibration_poses(camera: Camera, square: float = 0.025) -> list[np.ndarray]:
    """20 board poses in the order a person would take them: centre first, then outward,
    each board filling about half the image width and kept wholly inside it."""
    board = parse_board("chessboard:9x6", square)
    # (x, y) image position as fractions, tilt (deg) and the direction of its axis (deg)
    spots = [(0.5, 0.5, 0, 0), (0.5, 0.5, 35, 0), (0.5, 0.5, 35, 90),
             (0.3, 0.3, 35, -40), (0.7, 0.3, 35, 40), (0.7, 0.7, 35, 140),
             (0.3, 0.7, 35, -140), (0.5, 0.2, 40, 0), (0.5, 0.8, 40, 180),
             (0.2, 0.5, 40, -90), (0.8, 0.5, 40, 90), (0.1, 0.1, 25, 45),
             (0.9, 0.1, 25, -45), (0.9, 0.9, 25, -135), (0.1, 0.9, 25, 135),
             (0.5, 0.5, 45, 45), (0.35, 0.5, 30, 120), (0.65, 0.5, 30, -60),
             (0.5, 0.35, 35, -160), (0.5, 0.65, 35, 20)]
    out = []
    for k, (fx, fy, tilt, axis) in enumerate(spots):
        frac = (0.62, 0.52, 0.45)[k % 3]  # board width / image width
        dist = camera.fx * board.width_m / (frac * camera.width)
        target = [fx * (camera.width - 1), fy * (camera.height - 1)]
        fit = fit_board(camera, board, target, dist, tilt, axis, 8.0 * math.sin(k), margin_px=6)
        if fit is None:
            raise RuntimeError(f"calibration sample view {k} does not fit in the image")
        out.append(fit[0])
    return out


def write_calibration_session(out: Path, camera: Camera) -> None:
    out.mkdir(parents=True, exist_ok=True)
    views = []
    for k, T in enumerate(calibration_poses(camera)):
        img, corners, _ = render_chessboard(
            camera, T, square=0.025, ground=Ground(("concrete", "grass")[k % 2], k),
            effects=Effects(blur_sigma_px=0.7, noise_sigma=1.5, seed=k))
        name = f"view_{k:02d}.jpg"
        write_image(out / name, img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        views.append({"file": name, "camera_from_board": T.tolist(),
                      "corners_px": np.round(corners, 5).tolist()})
        _progress(f"  calibration view {k + 1}/20")
    truth = {"board": "chessboard:9x6", "square": 0.025, "camera": "../camera.yaml",
             "note": "corners_px are the true projections of the inner corners, row-major",
             "views": views}
    atomic_write_text(out / "truth.json", json.dumps(truth, indent=1))


def approach_scene() -> tuple[list[BrickInstance], dict]:
    """A row of five dricks on gravel, 0.4 m apart along world x."""
    d = shipped_layouts_dir()
    pyr = load_layout(d / "drick-aruco-pyramids.json")
    centre = load_layout(d / "drick-aruco-centre.json")
    dots = load_layout(d / "drick-dots-2x3.json")
    row = [(pyr, 0), (dots, None), (centre, 1), (dots, None), (pyr, 1)]
    bricks = []
    for i, (lay, inst) in enumerate(row):
        yaw = math.radians((-4, 3, 0, -2, 5)[i])
        bricks.append(BrickInstance(lay, transform(rot_z(yaw), [(i - 2) * 0.4, 0.0, 0.10]),
                                    instance=inst))
    # the names from the loaded layouts (a placed brick keeps its layout untyped)
    meta = {"layouts": sorted({lay.name for lay, _ in row}),
            "bricks": [{"layout": lay.name, "instance": b.instance,
                        "world_from_brick": b.world_from_brick.tolist()}
                       for b, (lay, _) in zip(bricks, row, strict=True)]}
    return bricks, meta


def drone_trajectory(t: float) -> np.ndarray:
    """``world_from_body`` (FRD body: x forward, y right, z down) at time t (s)."""
    s = min(1.0, t / SECONDS)
    ease = 0.5 - 0.5 * math.cos(math.pi * s)
    start, end = np.array([-0.9, -1.1, 2.0]), np.array([0.0, -0.12, 0.45])
    pos = start + (end - start) * ease
    pos += [0.01 * math.sin(2.3 * t), 0.008 * math.sin(3.1 * t + 1), 0.005 * math.sin(1.7 * t)]
    yaw = math.radians(90 - 25 * (1 - ease))  # heading toward +y (north), turning in
    # FRD body axes in the ENU-like world (z up): forward, right, down
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, fwd)
    R = np.stack([fwd, right, down], axis=1)
    roll = math.radians(1.5 * math.sin(2.0 * t))
    R = R @ cv2.Rodrigues(np.array([roll, 0.0, 0.0]))[0]
    return transform(R, pos)


def body_from_camera(tilt_deg: float = 20.0) -> np.ndarray:
    """Camera looking down, its image top toward the drone's front, tilted forward."""
    # camera x (image right) = body y (right); camera y (image down) = −body x; z = body z
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    tilt = cv2.Rodrigues(np.array([0.0, math.radians(tilt_deg), 0.0]))[0]  # toward +x
    return transform(tilt @ R, [0.08, 0.0, 0.05])


def write_approach_session(out: Path, camera: Camera) -> None:
    out.mkdir(parents=True, exist_ok=True)
    bricks, meta = approach_scene()
    mount = body_from_camera()
    n = FPS * SECONDS
    with tempfile.TemporaryDirectory() as tmp:
        video_tmp = Path(tmp) / "approach.mp4"
        writer = cv2.VideoWriter(str(video_tmp), cv2.VideoWriter.fourcc(*"mp4v"), FPS,
                                 camera.size)
        if not writer.isOpened():
            raise RuntimeError("OpenCV cannot write MP4 (mp4v) video on this machine")
        truth_lines, gravity_lines = [], []
        t0 = time.time()
        for i in range(n):
            t = i / FPS
            world_from_camera = drone_trajectory(t) @ mount
            cfw = np.linalg.inv(world_from_camera)
            scene = Scene(camera, cfw, Ground("gravel", 3), bricks, light_dir=(0.3, -0.4, 1.0))
            res = render(scene, Effects(blur_sigma_px=0.5, motion_px=0.8,
                                        motion_angle_deg=30, noise_sigma=2.0, seed=i), ss=3)
            writer.write(res.image)
            truth_lines.append(json.dumps({
                "frame": i, "t": round(t, 6), "camera_from_world": cfw.tolist(),
                "bricks": [{"layout": b.layout, "instance": b.instance,
                            "rvec": rvec_tvec(b.camera_from_brick)[0].tolist(),
                            "tvec": b.tvec.tolist(), "markers": b.code_ids}
                           for b in res.bricks]}))
            gravity_lines.append(json.dumps({"file": "approach.mp4", "frame": i, "gravity": [
                round(float(g), 9) for g in gravity_in_camera(cfw)]}))
            if i % 15 == 14:
                _progress(f"  approach frame {i + 1}/{n} ({(time.time() - t0) / (i + 1):.2f} "
                          "s/frame)")
        writer.release()
        atomic_write_bytes(out / "approach.mp4", video_tmp.read_bytes())
    atomic_write_text(out / "truth.jsonl", "\n".join(truth_lines) + "\n")
    atomic_write_text(out / "gravity.jsonl", "\n".join(gravity_lines) + "\n")

    note = "camera 20° tilted forward, 8 cm ahead and 5 cm below the body origin"
    atomic_write_text(out / "mount.json", json.dumps(Mount(mount, note=note).to_file(),
                                                     indent=1))
    atomic_write_text(out / "scene.json", json.dumps({"fps": FPS, "frames": n, **meta},
                                                     indent=1))


#: The pad pictures: (drone heading deg, body origin height m) of each.
PAD_SHOTS = ((0.0, 1.0), (120.0, 1.2), (240.0, 1.4))


def write_pad_session(out: Path, camera: Camera) -> None:
    """Pictures of the landing pad for measuring the mount (see the module docstring)."""
    out.mkdir(parents=True, exist_ok=True)
    pad = load_layout(shipped_layouts_dir() / "landing-pad.json")
    mount = body_from_camera()
    for i, (heading, height) in enumerate(PAD_SHOTS):
        res = level_drone_over_code(mount, pad, heading, 0.0, height, seed=i, camera=camera)
        ok, jpg = cv2.imencode(".jpg", res.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        (out / f"pad_{i:02d}.jpg").write_bytes(jpg.tobytes())
        _progress(f"  pad picture {i + 1}/{len(PAD_SHOTS)}")
    note = ("the mount these pictures were rendered with (camera 20° tilted forward, 8 cm "
            "ahead and 5 cm below the body origin); the pad's arrow points to the nose")
    (out / "mount.json").write_text(json.dumps(Mount(mount, note=note).to_file(), indent=1))


def write_demo_mission(out: Path) -> None:
    """A short simulated mission (the shipped wall, first three bricks), recorded for the
    live page's replay panel (``drovisio serve`` lists ``missions/`` by default)."""
    scn = load_scenario(shipped_scenario("wall-2-courses"))
    scn = scn.subset(scn.order[:3])
    tr = simulate(scn, (), SimParams(seed=0))
    write_recording(tr, out / "wall-first-3-bricks",
                    extra={"rules": {r.rule: r.held for r in check_rules(tr)}})
    _progress("  demo mission recorded")


PARTS = ("calibration", "approach", "missions", "study", "pad")


def main(out_dir: str | Path | None = None, only: str | None = None) -> int:
    """Write all sample sessions (or the part ``only``) into ``out_dir`` (default: the repo's
    sample_sessions/)."""
    out = Path(out_dir) if out_dir is not None else sample_sessions_dir()
    camera = Camera.drone_webcam()
    out.mkdir(parents=True, exist_ok=True)
    save_camera(camera, out / "camera.yaml")
    _progress(f"Writing sample sessions into {out}")
    if only in (None, "calibration"):
        write_calibration_session(out / "calibration", camera)
    if only in (None, "approach"):
        write_approach_session(out / "approach", camera)
    if only in (None, "missions"):
        write_demo_mission(out / "missions")
    if only in (None, "study"):

        write_recorded_example(out / "study", frames=6)
    if only in (None, "pad"):
        write_pad_session(out / "pad", camera)
    _progress("Done.")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1] if len(sys.argv) > 1 else None))
