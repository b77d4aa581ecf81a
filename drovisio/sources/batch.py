"""The command line's inputs (image files, folders, videos) as one stream of frames, in
order, never raising for a bad input (``drovisio detect``)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drovisio.images import (
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    ImageError,
    is_video_file,
    read_image,
)
from drovisio.raw_frame import EndOfStream
from drovisio.sources.folders import list_folder
from drovisio.sources.video import VideoFileReader

__all__ = ["FrameItem", "iter_inputs"]




@dataclass
class FrameItem:
    """One frame of the command line's inputs, or the reason it could not be read."""

    file: str
    """The path as given (a folder's image: the folder as given joined with its name; a
    video's frame: the video path)."""
    frame: int
    """The frame's index in its video; for images, their running index over the run."""
    image: np.ndarray | None = None
    """BGR uint8 (H, W, 3), or None when ``error`` is set."""
    error: str | None = None
    notes: list[str] = field(default_factory=list)
    source: str = ""
    """The input (file, folder or video) this frame came from, as given."""
    is_video: bool = False


def _video_items(path: str, source: str) -> Iterator[FrameItem]:
    reader = VideoFileReader(path)
    try:
        reader.open()
    except OSError as e:
        yield FrameItem(path, 0, error=str(e).removeprefix(f"{path}: "), source=source,
                        is_video=True)
        return
    n = 0
    try:
        while True:
            try:
                raw = reader.read()
            except EndOfStream:
                break
            if raw is None:
                break
            n += 1
            yield FrameItem(path, raw.index, raw.image, raw.error, raw.notes, source=source,
                            is_video=True)
    finally:
        reader.close()
    if n == 0:
        yield FrameItem(path, 0, error="video has no readable frame", source=source,
                        is_video=True)


def iter_inputs(inputs: Iterable[str], messages: list[str] | None = None
                ) -> Iterator[FrameItem]:
    """The frames of the command line's inputs, in order (a folder's images and videos in
    name order, a video frame by frame), never raising for a bad input.

    Args:
        inputs: Image files, folders or videos.
        messages: Problems that produce no frame at all (an empty folder) are appended here.

    Yields:
        :class:`FrameItem`; unreadable frames carry ``error`` instead of an image.
    """
    image_index = 0
    for inp in inputs:
        p = Path(inp)
        if p.is_dir():
            files = list_folder(p)
            if not files:
                if messages is not None:
                    messages.append(f"{inp}: folder has no images or videos (looked for "
                                    f"{', '.join(sorted(IMAGE_SUFFIXES | VIDEO_SUFFIXES))})")
                continue
            for f in files:
                shown = os.path.join(inp, f.name)
                if is_video_file(f):
                    yield from _video_items(shown, inp)
                    continue
                yield _image_item(f, shown, image_index, inp)
                image_index += 1
            continue
        if p.exists() and p.is_file() and (is_video_file(p) or not _looks_like_image(p)):
            yield from _video_items(inp, inp)
            continue
        yield _image_item(p, inp, image_index, inp)
        image_index += 1


def _looks_like_image(p: Path) -> bool:
    """An image by its suffix, or (unknown suffix) by a header Pillow or OpenCV knows."""
    if p.suffix.lower() in IMAGE_SUFFIXES:
        return True
    import cv2  # deferred: heavy (`drovisio --help` must not load it)

    return bool(cv2.haveImageReader(str(p)))


def _image_item(path: Path, shown: str, index: int, source: str) -> FrameItem:
    try:
        img, notes = read_image(path)
    except ImageError as e:
        return FrameItem(shown, index, error=str(e), source=source)
    return FrameItem(shown, index, img, None, notes, source=source)


