"""``drovisio bench renderer``: how exact the synthetic renderer is.

Two measurements, both against the camera model the images were rendered with:

* **edge**: a printed code's outer edge, row by row, located by the area of white beside it
  (sub-pixel, no detector involved), against the edge's distorted projection;
* **calibration**: 27 rendered chessboard views (9×6, 25 mm, 3×3 image positions × 3 tilts of
  ~40°, blur 0.8 px, noise 0.5) through OpenCV's own corner finder and ``calibrateCamera``;
  the intrinsics must come back within 0.1 %.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import cv2
import numpy as np

from drovisio.camera import Camera

EXAMPLE = "drovisio bench renderer            # both checks, about 1 min on a small laptop"


def _edge_rows(res, corners_brick: np.ndarray, camera: Camera) -> np.ndarray:
    """Signed error (px) of the left code edge, per image row, measured − projected."""
    truth = res.bricks[0]
    tl, _, _, bl = corners_brick
    s = np.linspace(0, 1, 4001)[:, None]
    edge_px = camera.project_from(tl * (1 - s) + bl * s, truth.camera_from_brick)
    order = np.argsort(edge_px[:, 1])
    gray = res.image.astype(np.float64).mean(axis=2)
    errors = []
    for y in range(int(edge_px[:, 1].min()) + 12, int(edge_px[:, 1].max()) - 12):
        x_pred = float(np.interp(y, edge_px[order, 1], edge_px[order, 0]))
        x0 = int(round(x_pred))
        white, black = gray[y, x0 - 3], gray[y, x0 + 3]  # fully inside margin / border
        frac = np.clip((gray[y, x0 - 2:x0 + 3] - black) / (white - black), 0, 1)
        errors.append((x0 - 2 - 0.5) + frac.sum() - x_pred)
    return np.array(errors)


def edge_check(camera: Camera | None = None, ss: int = 4) -> dict:
    """Render a drick's centre code 0.25 m away and measure its left edge row by row.

    Returns:
        ``{"rows", "mean_px", "rms_px", "max_px"}`` of the signed edge error.
    """
    from drovisio.layout import load_layout, shipped_layouts_dir
    from drovisio.synth import (
        BrickInstance,
        Ground,
        Scene,
        camera_over,
        render,
        rot_z,
        transform,
    )

    cam = camera or Camera.drone_webcam()
    lay = load_layout(shipped_layouts_dir() / "drick-aruco-centre.json")
    brick = BrickInstance(lay, transform(rot_z(math.radians(4)), [0.01, 0.005, 0.10]),
                          instance=3)
    scene = Scene(cam, camera_over([0, 0, 0.10], 0.25, tilt_deg=8, heading_deg=30),
                  ground=Ground("plain"), bricks=[brick])
    err = _edge_rows(render(scene, ss=ss), lay.code_corners_m()[0], cam)
    return {"rows": int(err.size), "mean_px": float(err.mean()),
            "rms_px": float(np.sqrt(np.mean(err ** 2))), "max_px": float(np.abs(err).max())}


def calibration_poses(camera: Camera, square: float = 0.025) -> list[np.ndarray]:
    """27 well-spread board poses: 3×3 image positions × 3 tilts of ~40°, 0.55–0.65 m."""
    from drovisio.synth import transform

    out = []
    k = 0
    for fy in (0.3, 0.5, 0.7):
        for fx in (0.27, 0.5, 0.73):
            for tilt in ([0.75, 0, 0.1], [0, 0.75, -0.1], [0.5, 0.5, 0.3]):
                k += 1
                R = cv2.Rodrigues(np.array(tilt) * (1 if k % 2 else -1))[0]
                d = 0.55 if k % 3 else 0.65
                px = np.array([[fx * (camera.width - 1), fy * (camera.height - 1)]])
                ray = np.r_[camera.normalize(px)[0], 1.0]
                out.append(transform(R, ray * d - R @ np.array([4 * square, 2.5 * square, 0])))
    return out


def calibration_check(camera: Camera | None = None, square: float = 0.025) -> dict:
    """Calibrate with plain OpenCV from rendered chessboard views of a known camera.

    Returns:
        ``{"views", "rms_px", "corner_max_px", "rel_err": {"fx", "fy", "cx", "cy"}}`` where
        ``corner_max_px`` is the largest distance between OpenCV's refined corners and the
        true projections.
    """
    from drovisio.synth import Effects, Ground, render_chessboard

    cam = camera or Camera.drone_webcam()
    objs, pts, worst = [], [], 0.0
    for k, T in enumerate(calibration_poses(cam, square)):
        img, true_px, obj = render_chessboard(
            cam, T, square=square, ss=4, ground=Ground("gravel", k) if k % 3 == 0 else None,
            effects=Effects(blur_sigma_px=0.8, noise_sigma=0.5, seed=k))
        gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        found, c = cv2.findChessboardCorners(gray, (9, 6))
        if not found:
            raise AssertionError(f"view {k}: OpenCV found no board")
        c = cv2.cornerSubPix(gray, c, (5, 5), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
        c = c.reshape(-1, 2)
        if np.linalg.norm(c[0] - true_px[0]) > np.linalg.norm(c[0] - true_px[-1]):
            c = c[::-1]  # OpenCV may number the board from the other end
        worst = max(worst, float(np.abs(c - true_px).max()))
        objs.append(obj.astype(np.float32))
        pts.append(c.astype(np.float32))
    rms, K, _, _, _ = cv2.calibrateCamera(objs, pts, cam.size, None, None)
    rel = {"fx": K[0, 0] / cam.fx - 1, "fy": K[1, 1] / cam.fy - 1,
           "cx": K[0, 2] / cam.cx - 1, "cy": K[1, 2] / cam.cy - 1}
    return {"views": len(objs), "rms_px": float(rms), "corner_max_px": worst,
            "rel_err": {k: float(v) for k, v in rel.items()}}


def main(argv: list[str]) -> int:
    from drovisio.arguments import plain_help
    from drovisio.bounds import ArgumentParser

    parser = ArgumentParser(
        prog="drovisio bench renderer", description=plain_help(__doc__),
        epilog=f"Example:\n  {EXAMPLE}", formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.parse_args(argv)
    t0 = time.time()
    e = edge_check()
    print(f"edge: {e['rows']} rows, signed error mean {e['mean_px']:+.4f} px, "
          f"RMS {e['rms_px']:.4f} px, max {e['max_px']:.4f} px")
    c = calibration_check()
    rel = "  ".join(f"{k} {100 * v:+.4f} %" for k, v in c["rel_err"].items())
    print(f"calibration: {c['views']} views, RMS {c['rms_px']:.4f} px, worst corner "
          f"{c['corner_max_px']:.3f} px; intrinsics vs truth: {rel}")
    print(f"({time.time() - t0:.1f} s)", file=sys.stderr)
    return 0
