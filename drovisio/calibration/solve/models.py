"""The lens models the calibration solves, the names ``--model`` takes, and the one-line
messages of an unknown or refused model."""

from __future__ import annotations

MODELS = {"plumb_bob": "plumb_bob", "rational": "rational_polynomial",
          "rational_polynomial": "rational_polynomial", "thin_prism": "thin_prism",
          "tilted": "tilted", "fisheye": "fisheye"}
"""Names ``--model`` takes → the calibration's model names (:func:`lens_key`)."""
MODEL_CHOICES = ("auto", "plumb_bob", "rational", "thin_prism", "tilted", "fisheye")
"""What ``--model`` and the calibration page offer."""


def unknown_model(model: str) -> str:
    """The one message for a lens model the calibration does not know."""
    return f"unknown lens model {model!r}: use {', '.join(MODEL_CHOICES)}"


def fail_line(model: str, cause: str, fix: str) -> str:
    return f"the {model} solve {cause}; {fix}"


#: How many of a model's highest-order coefficients a retry holds at 0 ("fewer free
#: coefficients"): fisheye k3 k4, rational k4-k6, thin prism s1-s4, tilted tx ty.
RETRY_FIXED = {"plumb_bob": 1, "rational_polynomial": 3, "thin_prism": 4, "tilted": 2,
                "fisheye": 2}
