"""``drovisio bench dots --cache DIR``: the cache folder is the user's, so its pictures are
read by the image reader, with its bounds; an entry it refuses is rendered again."""

from __future__ import annotations

import json
import os

import numpy as np

from drovisio.bench.dots.frames import FrameSource, bench_layout
from drovisio.errors import LIMITS
from drovisio.fileio import write_image


def _entry(cache, png_writer) -> tuple:
    src = FrameSource(bench_layout(None), cache)
    (cache / "k-1-t.json").write_text(json.dumps({"gravity": [0, 0, 1], "bricks": []}))
    png_writer(cache / "k-1-t.png")
    return src._cached("k", 1, "t")


def test_a_cached_picture_is_read_within_the_image_bounds(tmp_path, monkeypatch):
    def picture(p):
        write_image(p, np.zeros((48, 64, 3), np.uint8))

    hit, png, _ = _entry(tmp_path / "a", picture)
    assert hit is not None and hit.image.shape == (48, 64, 3)
    # over the pixel cap: refused from its header (no frame comes out of the cache)
    monkeypatch.setattr(LIMITS, "max_image_pixels", 1000)
    hit, png2, _ = _entry(tmp_path / "b", picture)
    assert hit is None and png2 == tmp_path / "b" / "k-1-t.png"


def test_a_pipe_in_the_cache_is_never_opened(tmp_path):
    hit, _, _ = _entry(tmp_path, os.mkfifo)   # opening it would wait for a writer forever
    assert hit is None
