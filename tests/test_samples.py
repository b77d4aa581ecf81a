"""The shipped sample sessions: complete, consistent with their truth, and regenerable."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from drovisio import synth_samples
from drovisio.camera import Camera
from drovisio.camera_file import load_camera
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.synth import rvec_tvec, transform

SAMPLES = Path(__file__).resolve().parents[1] / "sample_sessions"


def test_sessions_are_small_and_complete():
    files = [p for p in SAMPLES.rglob("*") if p.is_file()]
    assert sum(p.stat().st_size for p in files) < 8e6  # "a few MB in all"
    assert load_camera(SAMPLES / "camera.yaml").almost_equal(Camera.drone_webcam())
    truth = json.loads((SAMPLES / "calibration" / "truth.json").read_text())
    assert len(truth["views"]) == 20
    assert all((SAMPLES / "calibration" / v["file"]).exists() for v in truth["views"])
    mount = json.loads((SAMPLES / "approach" / "mount.json").read_text())
    np.testing.assert_allclose(mount["body_from_camera"], synth_samples.body_from_camera())
    from drovisio.study.protocol import load_protocol

    study = load_protocol(SAMPLES / "study" / "protocol.yaml")
    assert all((SAMPLES / "study" / s.source).exists() for s in study.steps if s.source)


def test_calibration_views_show_the_board_where_truth_says():
    truth = json.loads((SAMPLES / "calibration" / "truth.json").read_text())
    for view in truth["views"][::5]:
        gray = cv2.imread(str(SAMPLES / "calibration" / view["file"]), cv2.IMREAD_GRAYSCALE)
        found, c = cv2.findChessboardCorners(gray, (9, 6))
        assert found, view["file"]
        c = cv2.cornerSubPix(gray, c, (5, 5), (-1, -1), (3, 50, 1e-4)).reshape(-1, 2)
        true_px = np.array(view["corners_px"])
        if np.linalg.norm(c[0] - true_px[0]) > np.linalg.norm(c[0] - true_px[-1]):
            c = c[::-1]
        assert np.abs(c - true_px).max() < 0.5, view["file"]


def test_approach_video_frames_match_their_truth():
    cap = cv2.VideoCapture(str(SAMPLES / "approach" / "approach.mp4"))
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(15)
    truth = [json.loads(line) for line in
             (SAMPLES / "approach" / "truth.jsonl").read_text().splitlines()]
    gravity = [json.loads(line) for line in
               (SAMPLES / "approach" / "gravity.jsonl").read_text().splitlines()]
    assert len(truth) == len(gravity) == 150
    cam = load_camera(SAMPLES / "camera.yaml")
    layouts = {p.stem: load_layout(p) for p in shipped_layouts_dir().glob("*.json")}
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    checked = 0
    frames = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        i = frames
        frames += 1
        assert img.shape == (480, 640, 3)
        g = np.array(gravity[i]["gravity"])
        assert np.linalg.norm(g) == pytest.approx(1.0)
        if i % 15:
            continue
        corners, ids, _ = det.detectMarkers(img)
        found = dict(zip(np.ravel(ids).tolist() if ids is not None else [], corners))
        for b in truth[i]["bricks"]:
            lay = layouts[b["layout"]]
            cfb = transform(np.array(b["rvec"]), b["tvec"])
            for slot, obj in lay.code_corners_m().items():
                mid = lay.marker_id(b["instance"], slot)
                px = cam.project_from(obj, cfb)
                side = np.linalg.norm(px[1] - px[0])
                if mid in found and side >= 20:  # small codes: OpenCV's integer corners
                    assert np.abs(found[mid].reshape(4, 2) - px).max() < 1.5, (i, mid)
                    checked += 1
    assert frames == 150
    assert checked >= 5


def test_calibration_session_is_regenerated_identically(tmp_path: Path, monkeypatch):
    """``make samples`` rebuilds the same data: re-render two views and compare pixels."""
    poses = synth_samples.calibration_poses(Camera.drone_webcam())
    monkeypatch.setattr(synth_samples, "calibration_poses", lambda camera: poses[:2])
    synth_samples.write_calibration_session(tmp_path, Camera.drone_webcam())
    for name in ("view_00.jpg", "view_01.jpg"):
        new = cv2.imread(str(tmp_path / name)).astype(float)
        old = cv2.imread(str(SAMPLES / "calibration" / name)).astype(float)
        assert np.abs(new - old).mean() < 0.5, name
    # and the truth poses are what the generator computes
    truth = json.loads((SAMPLES / "calibration" / "truth.json").read_text())
    np.testing.assert_allclose(truth["views"][1]["camera_from_board"], poses[1], atol=1e-12)
    assert rvec_tvec(poses[1])[1][2] > 0.3
