"""Palette proposals from pixels a user points at (drovisio.colors)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drovisio.colors import propose_color, propose_color_report, selection_mask
from drovisio.detect.dots.color import threshold_color, to_hsv
from drovisio.layout import DEFAULT_PALETTE, ColorSpec


def _frame(seed=0):
    """Grey, textured ground with a red, a blue and an orange disc, lit unevenly."""
    rng = np.random.default_rng(seed)
    img = np.full((240, 320, 3), 140, np.float32) + rng.normal(0, 6, (240, 320, 3))
    cv2.circle(img, (60, 60), 14, (40, 40, 210), -1, lineType=cv2.LINE_AA)     # red
    cv2.circle(img, (160, 60), 14, (200, 120, 20), -1, lineType=cv2.LINE_AA)   # blue
    cv2.circle(img, (260, 60), 14, (30, 140, 240), -1, lineType=cv2.LINE_AA)   # orange
    cv2.circle(img, (60, 180), 10, (30, 30, 150), -1, lineType=cv2.LINE_AA)    # red in shade
    ramp = np.linspace(0.7, 1.1, 320, dtype=np.float32)[None, :, None]
    return np.clip(img * ramp, 0, 255).astype(np.uint8)


def test_red_from_clicks_wraps_and_separates():
    img = _frame()
    rep = propose_color_report(img, [(60, 60), (62, 57), (60, 180)], radius=5,
                               palette=DEFAULT_PALETTE, exclude=("red",))
    spec = rep.spec
    assert isinstance(spec, ColorSpec) and spec.wraps            # red straddles hue 0
    hsv = to_hsv(img)
    m = threshold_color(hsv, spec) > 0
    assert m[60, 60] and m[180, 60]                              # both reds, lit and shaded
    assert not m[60, 160] and not m[60, 260] and not m[120, 160]  # blue, orange, ground
    assert rep.inside_selection > 0.95 and rep.inside_rest < 0.02
    assert rep.overlaps == [] and spec.bgr is not None
    assert 0 <= spec.hsv[0][1] <= 255 and spec.hsv[1][1] == 255


def test_blue_from_mask_and_overlap_warning():
    img = _frame()
    mask = np.zeros(img.shape[:2], bool)
    cv2.circle(mask.view(np.uint8), (160, 60), 8, 1, -1)
    spec = propose_color(img, mask)
    assert not spec.wraps and spec.hsv[0][0] <= to_hsv(img)[60, 160, 0] <= spec.hsv[1][0]
    assert spec.contains(to_hsv(img)[60, 160]) and not spec.contains(to_hsv(img)[60, 60])
    # orange tuned against the default palette: it comes close to yellow/red
    rep = propose_color_report(img, [(260, 60)], radius=6, palette=DEFAULT_PALETTE)
    assert rep.spec.contains(to_hsv(img)[60, 260])
    assert all(isinstance(w, str) for w in rep.warnings)


def test_the_detector_uses_a_proposed_colour():
    """A layout whose red is the proposed range finds the same brick."""
    from drovisio.camera import Camera
    from drovisio.detect.dots import detect_dots
    from drovisio.layout import load_layout, parse_layout, shipped_layouts_dir
    from drovisio.synth import (
        BrickInstance,
        Ground,
        Scene,
        camera_over,
        render,
        transform,
    )

    cam = Camera.drone_webcam()
    lay = load_layout(shipped_layouts_dir() / "drick-dots-2x3.json")
    scene = Scene(camera=cam, camera_from_world=camera_over([0, 0, 0.1], 0.8, 0, 90),
                  ground=Ground("grass", 2), bricks=[BrickInstance(lay, transform(t=[0, 0, 0.1]),
                                                                   instance=None)])
    res = render(scene, ss=2)
    dots = res.bricks[0].dot_centers_px
    red = [k for k, c in enumerate(lay.dot_colors()) if c == "red"]
    spec = propose_color(res.image, dots[red], radius=3)
    data = lay.to_dict()
    data["colors"] = {"red": {"hsv": [list(spec.hsv[0]), list(spec.hsv[1])]}}
    tuned = parse_layout(data)
    poses = detect_dots(res.image, cam, [tuned])
    assert len(poses) == 1 and len(poses[0].markers) == 6


def test_bad_selections_are_explained():
    img = _frame()
    with pytest.raises(ValueError, match="not colourful"):
        propose_color(img, [(120, 150)], radius=6)               # grey ground
    with pytest.raises(ValueError, match="no pixel selected"):
        propose_color(img, [(-50, -50)])
    with pytest.raises(ValueError, match="uint8 BGR"):
        propose_color(img[..., 0], [(60, 60)])
    with pytest.raises(ValueError, match="mask or"):
        selection_mask((10, 10), np.zeros((3, 3, 3)))
