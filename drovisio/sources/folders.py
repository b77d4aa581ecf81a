"""Folders as sources: a folder of images played at a fixed rate, and a recording folder
(``drovisio run --record DIR``) played with its recorded timing."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from drovisio.errors import InputError
from drovisio.images import IMAGE_SUFFIXES, VIDEO_SUFFIXES, ImageError, is_video_file, read_image
from drovisio.raw_frame import EndOfStream, RawFrame
from drovisio.textfile import resolve_inside

if TYPE_CHECKING:   # the recording module loads OpenCV, deferred to the first open
    from drovisio.recording import RecordedFrame

__all__ = ["ImageFolderReader", "RecordingReader", "folder_entries", "list_folder"]


def folder_entries(folder: Path, wanted: Callable[[Path], bool]) -> list[Path]:
    """The folder's entries ``wanted`` by name (not recursive), in name order, hidden ones
    and folders skipped. A link to nothing, a loop of links or a pipe is kept: its reader
    names it and says why, rather than the folder seeming to lack it."""
    return sorted((p for p in folder.iterdir()
                   if wanted(p) and not p.name.startswith(".") and not p.is_dir()),
                  key=lambda p: p.name)


def list_folder(folder: Path) -> list[Path]:
    """Images and videos of a folder (:func:`folder_entries`)."""
    return folder_entries(folder, lambda p: p.suffix.lower() in IMAGE_SUFFIXES | VIDEO_SUFFIXES)


class ImageFolderReader:
    """The images of a folder in name order, played at ``fps``; an unreadable image is a
    frame carrying ``error`` (the source goes on)."""

    finite = True
    lossless = False

    def __init__(self, folder: str | Path, fps: float = 10.0, loop: bool = False):
        self.folder = Path(folder)
        self.label = str(folder)
        self.fps = float(fps)
        self.loop = loop
        self.finite = not loop
        self.files: list[Path] = []
        self.i = 0

    def open(self) -> None:
        if not self.folder.is_dir():
            raise OSError(f"{self.folder}: no such folder")
        self.files = [f for f in list_folder(self.folder) if not is_video_file(f)]
        if not self.files:
            raise OSError(f"{self.folder}: no images in the folder (looked for "
                          f"{', '.join(sorted(IMAGE_SUFFIXES))})")
        self.i = 0

    def read(self) -> RawFrame | None:
        if self.i >= len(self.files):
            if not self.loop:
                raise EndOfStream()
            self.i = 0
        f = self.files[self.i]
        i = self.i
        self.i += 1
        try:
            img, notes = read_image(f)
        except ImageError as e:
            return RawFrame(None, i, media_time=i / self.fps, name=f.name, error=str(e))
        return RawFrame(img, i, media_time=i / self.fps, name=f.name, notes=notes)

    def close(self) -> None:
        pass


class RecordingReader:
    """A folder written by ``drovisio run --record DIR``, played with its recorded timing.

    Its index is read and checked once, at the first :meth:`open`
    (:func:`drovisio.recording.read_index`); a reader opened again (the start-up check, then
    the run) keeps it. Each picture is read only inside the folder, links followed."""

    finite = True
    lossless = False

    def __init__(self, folder: str | Path, loop: bool = False):
        self.folder = Path(folder)
        self.label = f"recording {folder}"
        self.loop = loop
        self.finite = not loop
        self.entries: list[RecordedFrame] = []
        self.i = 0
        self.lap = 0

    def open(self) -> None:
        from drovisio.recording import read_index  # deferred: it loads OpenCV

        if not self.entries:
            self.entries = read_index(self.folder)
        if not self.entries:
            raise OSError(f"{self.folder}: the recording holds no frames")
        self.i = 0

    def read(self) -> RawFrame | None:
        if self.i >= len(self.entries):
            if not self.loop:
                raise EndOfStream()
            self.i = 0
            self.lap += 1
        e = self.entries[self.i]
        self.i += 1
        t0 = self.entries[0].t
        span = self.entries[-1].t - t0 + 0.1
        t = e.t - t0 + self.lap * span
        try:
            path = resolve_inside(self.folder, e.image, f"{self.folder / 'frames.jsonl'}: "
                                  "image", "frame image")
            img, notes = read_image(path)
        except (InputError, ImageError) as err:
            return RawFrame(None, e.frame, media_time=t, name=e.image, error=str(err))
        return RawFrame(img, e.frame, media_time=t, name=e.image, notes=notes)

    def close(self) -> None:
        pass
