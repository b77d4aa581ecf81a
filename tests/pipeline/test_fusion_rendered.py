"""Code + dot fusion on rendered frames of a brick carrying both (pyramid codes and 2×3 dots)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drovisio.camera_file import load_camera
from drovisio.fusion import dots_half_turn_symmetric, so3_exp, so3_log
from drovisio.layout import parse_layout
from drovisio.pipeline import Pipeline, detectors_for
from drovisio.synth import (
    BrickInstance,
    Effects,
    Ground,
    Scene,
    camera_over,
    render,
    rot_z,
    transform,
)

REPO = Path(__file__).resolve().parents[2]


def _hybrid():
    pyr = json.loads((REPO / "marker_layouts" / "drick-aruco-pyramids.json").read_text())
    dots = json.loads((REPO / "marker_layouts" / "drick-dots-2x3.json").read_text())
    d = {k: v for k, v in pyr.items() if k != "description"}
    d.update(name="drick-hybrid", markers=pyr["markers"] + dots["markers"])
    return parse_layout(d, REPO / "marker_layouts" / "drick-hybrid.json")


def test_fused_pose_beats_the_code_pose():
    lay = _hybrid()
    assert lay.symmetry == "none" and dots_half_turn_symmetric(lay)
    cam = load_camera(REPO / "sample_sessions" / "camera.yaml")
    p = Pipeline(source=None, detectors=[], layouts=[lay])  # only its fusion settings
    assert p._symmetric_dots == {"drick-hybrid"}
    dets = detectors_for(cam, [lay])
    assert [d.name for d in dets] == ["aruco", "dots"]
    W = transform(rot_z(0.3), [0.0, 0.0, 0.1])
    rot_err = {"aruco": [], "fused": []}
    for k, (dist, tilt) in enumerate([(1.0, 15), (1.6, 10), (0.9, 30)]):
        cfw = camera_over([0, 0, 0.1], dist, tilt_deg=tilt, heading_deg=20 * k)
        res = render(Scene(cam, cfw, Ground("gravel", 3), [BrickInstance(lay, W, instance=3)]),
                     Effects(noise_sigma=2.0, seed=k), ss=2)
        g = cfw[:3, :3] @ np.array([0.0, 0.0, -1.0])
        poses = [q for d in dets for q in d.detect(res.image, gravity=g)]
        from drovisio.fusion import fuse_frame

        fused = fuse_frame(poses, symmetric_dots=p._symmetric_dots)
        assert [q.method for q in fused] == ["fused"], [q.method for q in poses]
        f = fused[0]
        a = [q for q in poses if q.method == "aruco"][0]
        assert f.instance == 3 and np.linalg.norm(f.tvec - res.bricks[0].tvec) < 0.01
        Rt = so3_exp(res.bricks[0].rvec)
        for name, q in (("aruco", a), ("fused", f)):
            rot_err[name].append(np.degrees(np.linalg.norm(so3_log(Rt.T @ so3_exp(q.rvec)))))
        # the fused covariance is smaller than either input's
        assert np.trace(f.covariance) < min(np.trace(a.covariance),
                                            np.trace([q for q in poses
                                                      if q.method == "dots"][0].covariance))
    assert np.mean(rot_err["fused"]) < 0.7 * np.mean(rot_err["aruco"]), rot_err
