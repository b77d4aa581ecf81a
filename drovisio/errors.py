"""The errors a user can do something about, and the limits that keep hostile input bounded.

Every reader of outside input (camera, layout, mount, scenario, gravity files, images, videos,
web bodies) raises an :class:`InputError` whose message is one line of the form
``FILE: FIELD: what is wrong and what to do``; the command line prints it as
``drovisio COMMAND: <message>`` and exits with status 2, the web tool answers it as 422. Errors
of the machine rather than of the input (a full disk) are :class:`WriteError`; anything else is
a bug, reported once by the top-level handler with a path to the full traceback.
"""

from __future__ import annotations

import os

__all__ = [
    "InputError",
    "Limits",
    "WriteError",
    "LIMITS",
    "one_line",
]


class InputError(ValueError):
    """Input that cannot be used; the message names the file, the field and the fix."""

    status = 422
    """HTTP status when a web route meets it."""


class WriteError(OSError):
    """A file could not be written (full disk, no permission); nothing already saved was
    replaced. The message names the file and what to do."""

    status = 507

    def __init__(self, message: str, code: int = 0) -> None:
        super().__init__(message)
        self.errno = code


def one_line(text: object, limit: int = 400) -> str:
    """``text`` folded onto one line and cut to ``limit`` characters (error messages quote
    parts of hostile files; they must stay short)."""
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[: limit - 1] + "…"


class Limits:
    """Bounds on what outside input may ask of the machine (overridable by environment for
    the rare user who needs more).

    Attributes:
        max_image_pixels: Largest image (width × height) decoded; a header claiming more is
            refused before any pixel is allocated (``DROVISIO_MAX_IMAGE_MPX``, megapixels).
        max_image_side: Largest image width or height accepted from a camera file or header.
        max_file_bytes: Largest camera, layout, mount, scenario or gravity file read.
        max_json_depth: Deepest nesting of JSON/YAML objects accepted.
        max_yaml_aliases: Most YAML alias references in one document (alias bombs).
        max_markers: Most markers in one layout.
        max_body_bytes: Largest JSON body a web route reads.
    """

    def __init__(self) -> None:
        mpx = _env_float("DROVISIO_MAX_IMAGE_MPX", 50.0)
        self.max_image_pixels = int(mpx * 1e6)
        self.max_image_side = 20000
        self.max_file_bytes = 16 * 1024 * 1024
        self.max_json_depth = 32
        self.max_yaml_aliases = 100
        self.max_markers = 200
        self.max_body_bytes = 1024 * 1024


def _env_float(name: str, default: float) -> float:
    try:
        v = float(os.environ.get(name, default))
    except ValueError:
        return default
    return v if v > 0 and v == v and v != float("inf") else default


LIMITS = Limits()
