"""Report helpers: text summary and the uncertainty map as an image."""

from __future__ import annotations

import numpy as np

from drovisio.calibration.report import format_summary, uncertainty_image


def test_summary_lines(rendered_session):
    text = format_summary(rendered_session.report())
    assert "fx " in text and "RMS reprojection error" in text
    assert "projection uncertainty (1σ)" in text and "verdict: OK" in text


def test_uncertainty_image(rendered_session):
    img = uncertainty_image(rendered_session.result)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    small = uncertainty_image(rendered_session.result, width=320)
    assert small.shape == (240, 320, 3)
    # corners (higher σ) are brighter than the centre on the viridis scale
    assert small[:8, :8].mean() > small[110:130, 150:170].mean()
