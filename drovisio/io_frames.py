"""Reading frames from the inputs of a command: image files, folders of images, videos.

:func:`iter_frames` yields one :class:`FrameItem` per frame, in input order (a folder's
images in name order, a video frame by frame), and never raises for a bad input: an item
carries either an 8-bit BGR image or an ``error`` message meant for the user, plus optional
``notes`` (e.g. "16-bit image scaled to 8 bits").

Conventions of the output (DESIGN.md, ``drovisio detect``): ``file`` is the path as given
(for a folder, the folder as given joined with the image's name; for a video, the video
path), ``frame`` is the frame's index in its video, or for images their running index over
the images of the run (0-based).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "IMAGE_EXTS",
    "VIDEO_EXTS",
    "FrameItem",
    "iter_frames",
    "list_folder",
    "read_image",
    "to_bgr8",
]

IMAGE_EXTS = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm",
                        ".ppm", ".pnm", ".jp2", ".exr", ".hdr"})
VIDEO_EXTS = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg",
                        ".wmv", ".mjpeg", ".mjpg", ".h264", ".ts"})


@dataclass
class FrameItem:
    """One frame of the input, or the reason it could not be read."""

    file: str
    frame: int
    image: np.ndarray | None = None
    """BGR uint8 (H, W, 3), or None when ``error`` is set."""
    error: str | None = None
    notes: list[str] = field(default_factory=list)
    source: str = ""
    """The input (file, folder or video) this frame came from, as given."""


def to_bgr8(img: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Any image OpenCV reads (grey, BGRA, 16-bit, float) as BGR uint8, and notes on what was
    converted.

    16-bit images are scaled by the bit depth they actually use (a 12-bit camera's 0..4095 maps
    to 0..255, not to 0..15); float images in [0, 1] are multiplied by 255.
    """
    notes: list[str] = []
    a = np.asarray(img)
    if a.dtype == np.uint8:
        pass
    elif a.dtype in (np.uint16, np.int16, np.uint32, np.int32):
        top = int(a.max()) if a.size else 0
        bits = max(8, int(top).bit_length())
        full = (1 << bits) - 1
        notes.append(f"{a.dtype.itemsize * 8}-bit image ({bits} bits used) scaled to 8 bits")
        a = np.clip(np.rint(a.astype(np.float64) * (255.0 / full)), 0, 255).astype(np.uint8)
    elif np.issubdtype(a.dtype, np.floating):
        finite = a[np.isfinite(a)]
        top = float(finite.max()) if finite.size else 1.0
        scale = 255.0 if top <= 1.0 else 255.0 / top
        notes.append(f"floating-point image scaled to 8 bits (x{scale:.4g})")
        a = np.clip(np.rint(np.nan_to_num(a) * scale), 0, 255).astype(np.uint8)
    else:
        raise ValueError(f"unsupported pixel type {a.dtype}")
    import cv2

    if a.ndim == 2:
        notes.append("greyscale image converted to BGR")
        a = cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    elif a.ndim == 3 and a.shape[2] == 1:
        notes.append("greyscale image converted to BGR")
        a = cv2.cvtColor(a[:, :, 0], cv2.COLOR_GRAY2BGR)
    elif a.ndim == 3 and a.shape[2] == 4:
        a = cv2.cvtColor(a, cv2.COLOR_BGRA2BGR)
    elif a.ndim == 3 and a.shape[2] == 2:
        notes.append("grey+alpha image converted to BGR")
        a = cv2.cvtColor(a[:, :, 0], cv2.COLOR_GRAY2BGR)
    elif not (a.ndim == 3 and a.shape[2] == 3):
        raise ValueError(f"unsupported image shape {a.shape}")
    return np.ascontiguousarray(a), notes


def read_image(path: str | os.PathLike) -> tuple[np.ndarray | None, str | None, list[str]]:
    """Read one image file as BGR uint8: (image, None, notes) or (None, error, [])."""
    import cv2

    p = Path(path)
    try:
        data = np.fromfile(p, dtype=np.uint8)  # works for any file name (cv2.imread does not)
    except FileNotFoundError:
        return None, "no such file", []
    except IsADirectoryError:
        return None, "is a folder", []
    except OSError as e:
        return None, f"cannot read: {e.strerror or e}", []
    if data.size == 0:
        return None, "empty file", []
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        return None, "cannot decode as an image (corrupt, truncated or not an image)", []
    try:
        bgr, notes = to_bgr8(img)
    except ValueError as e:
        return None, str(e), []
    return bgr, None, notes


def list_folder(folder: Path) -> list[Path]:
    """Images and videos of a folder (not recursive), in name order; hidden files skipped."""
    items = [p for p in folder.iterdir()
             if p.is_file() and not p.name.startswith(".")
             and p.suffix.lower() in IMAGE_EXTS | VIDEO_EXTS]
    return sorted(items, key=lambda p: p.name)


def _video_frames(path: str, source: str) -> Iterator[FrameItem]:
    import cv2

    cap = cv2.VideoCapture(path)
    try:
        if not cap.isOpened():
            yield FrameItem(path, 0, error="cannot open as a video (unknown format or "
                                           "corrupt file)", source=source)
            return
        k = 0
        while True:
            ok, img = cap.read()
            if not ok or img is None:
                break
            try:
                bgr, notes = to_bgr8(img)
                yield FrameItem(path, k, bgr, None, notes, source=source)
            except ValueError as e:
                yield FrameItem(path, k, error=str(e), source=source)
            k += 1
        if k == 0:
            yield FrameItem(path, 0, error="video has no readable frame", source=source)
    finally:
        cap.release()


def iter_frames(inputs: Iterable[str], messages: list[str] | None = None
                ) -> Iterator[FrameItem]:
    """Frames of the inputs, in order.

    Args:
        inputs: Image files, folders (their images and videos in name order) or videos.
        messages: If given, problems that produce no frame at all (an empty folder) are
            appended here, for the caller to report.

    Yields:
        :class:`FrameItem`; unreadable frames carry ``error`` instead of an image.
    """
    image_index = 0
    for inp in inputs:
        p = Path(inp)
        if p.is_dir():
            files = list_folder(p)
            if not files:
                msg = (f"{inp}: folder has no images or videos (looked for "
                       f"{', '.join(sorted(IMAGE_EXTS))}, {', '.join(sorted(VIDEO_EXTS))})")
                if messages is not None:
                    messages.append(msg)
                continue
            for f in files:
                shown = os.path.join(inp, f.name)
                if f.suffix.lower() in VIDEO_EXTS:
                    yield from _video_frames(shown, inp)
                    continue
                img, err, notes = read_image(f)
                yield FrameItem(shown, image_index, img, err, notes, source=inp)
                image_index += 1
            continue
        if not p.exists():
            yield FrameItem(inp, image_index, error="no such file or folder", source=inp)
            image_index += 1
            continue
        if p.suffix.lower() in VIDEO_EXTS:
            yield from _video_frames(inp, inp)
            continue
        img, err, notes = read_image(p)
        if img is None and p.suffix.lower() not in IMAGE_EXTS:
            # maybe a video with an unusual extension
            import cv2

            cap = cv2.VideoCapture(inp)
            is_video = cap.isOpened()
            cap.release()
            if is_video:
                yield from _video_frames(inp, inp)
                continue
        yield FrameItem(inp, image_index, img, err, notes, source=inp)
        image_index += 1
