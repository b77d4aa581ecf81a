"""Report helpers: text summary and the uncertainty map as an image."""

from __future__ import annotations

import numpy as np

from drovisio.calibration.report import format_summary, uncertainty_image


def test_summary_lines(rendered_session):
    text = format_summary(rendered_session.report())
    assert "fx " in text and "RMS reprojection error" in text
    assert "projection uncertainty (1σ)" in text and "verdict: OK" in text
    n = len(rendered_session.report()["camera"]["dist"])
    assert "distortion (plumb_bob) " + " ".join(("k1", "k2", "p1", "p2", "k3")[:n]) in text


def test_a_fisheye_summary_names_its_own_coefficients(rendered_session):
    """A fisheye's four coefficients are Kannala–Brandt's k1..k4, not Brown's k1 k2 p1 p2."""
    rep = rendered_session.report()
    rep["camera"] = {**rep["camera"], "model": "fisheye", "dist": [-0.03, -0.02, 0.002, 0.001]}
    text = format_summary(rep)
    assert "distortion (fisheye) k1 k2 k3 k4: -0.03 -0.02 0.002 0.001" in text
    assert "p1" not in text


def test_uncertainty_image(rendered_session):
    img = uncertainty_image(rendered_session.result)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    small = uncertainty_image(rendered_session.result, width=320)
    assert small.shape == (240, 320, 3)
    # corners (higher σ) are brighter than the centre on the viridis scale
    assert small[:8, :8].mean() > small[110:130, 150:170].mean()
