"""The benchmarks' caches of rendered frames (``--cache DIR``): each entry a picture (PNG,
lossless) and its truth (JSON), the picture written last as the entry's mark of completeness.

The folder is the user's, so what it holds is outside input: the picture is read by the image
reader (its file size and pixel caps, never a pipe), the truth by the text reader and the JSON
parser (size, nesting, digits). Nothing read can run code, as loading a pickle can; an entry
that cannot be read is a miss, and its frame is rendered again.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from drovisio.fileio import atomic_write_text, write_image
from drovisio.images import ImageError, read_image
from drovisio.textfile import parse_json, read_text

__all__ = ["read_entry", "write_entry"]


def read_entry(png: Path, js: Path) -> tuple[np.ndarray, Any] | None:
    """(picture, truth) of a cache entry; None when the entry is not there (yet).

    Raises:
        InputError: a picture or truth the readers refuse, in words naming the file (a
            ``ValueError``).
    """
    if not (png.is_file() and js.is_file()):
        return None
    try:
        image = read_image(png)[0]
    except ImageError as e:   # its words name no file
        raise ImageError(f"{png}: {e}") from None
    return image, parse_json(read_text(js, "bench cache entry"), str(js))


def write_entry(png: Path, js: Path, image: np.ndarray, truth: Any) -> None:
    """Write a cache entry: each file beside and renamed, the picture last (an entry is read
    only when both are there)."""
    atomic_write_text(js, json.dumps(truth), make_parents=True)
    write_image(png, image)
