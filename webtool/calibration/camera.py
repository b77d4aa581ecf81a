"""The calibration page's camera: which frame source the settings ask for, the camera's
status as the page shows it, and the reader that reopens a fresh source after every loss.

The frames are read by :class:`drovisio.sources.FrameSource` (its own thread; on loss it closes
the reader and reopens it with a growing pause). The calibration page wants a *fresh* reader at
every reopening (a sample playback starts over, a test's scripted camera comes back as another
object), and treats the end of a source like a lost camera; :class:`FreshReader` adapts a
reader factory to that.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drovisio.images import is_image_file
from drovisio.raw_frame import EndOfStream, RawFrame
from drovisio.sources import PlaybackReader, Reader, list_folder, reader_for

__all__ = [
    "BACKOFF_S",
    "CameraStatus",
    "FreshReader",
    "default_source_factory",
    "sample_files",
    "source_label",
]

#: (first, longest) pause between reopen attempts after a loss, seconds
BACKOFF_S = (0.5, 4.0)


@dataclass
class CameraStatus:
    """The camera as the page shows it."""

    state: str = "stopped"  # stopped | starting | ok | disconnected
    message: str = ""
    since: float = 0.0      # UNIX time of the last state change
    failures: int = 0       # losses in a row


def sample_files(settings: Any) -> list[Path]:
    """The sample session's calibration images (its ``calibration/`` folder, else itself)."""
    folder = Path(settings.sample_session)
    for cand in (folder / "calibration", folder):
        if cand.is_dir():
            files = [f for f in list_folder(cand) if is_image_file(f)]
            if files:
                return files
    return []


def default_source_factory(settings: Any) -> Callable[[], Reader]:
    """The frame source ``settings`` ask for (a fresh reader per call): the sample session or
    a folder of photos played as if live, else the camera, stream or video (which loops)."""
    if settings.source is None:
        def sample() -> Reader:
            files = sample_files(settings)
            if not files:
                raise FileNotFoundError(f"no sample calibration images in "
                                        f"{settings.sample_session}")
            return PlaybackReader(files, settings.sample_seconds_per_view,
                                  label="sample session (no camera)")
        return sample
    if Path(settings.source).is_dir():
        return lambda: PlaybackReader.from_folder(
            Path(settings.source), seconds_per_view=settings.sample_seconds_per_view)
    return lambda: reader_for(settings.source, loop=True)


def source_label(settings: Any) -> str:
    """The key a saved session is resumed by (the same source only)."""
    return "sample" if settings.source is None else f"source:{settings.source}"


class FreshReader:
    """A :class:`~drovisio.sources.Reader` that makes a new reader with ``factory`` at every
    opening, turns the end of a source into a loss (so it is reopened), and remembers what
    went wrong for the page.

    It is ``lossless`` (the :class:`~drovisio.sources.FrameSource` waits for its consumer):
    every frame read is offered to the calibration session, as a sample playback expects.

    Attributes:
        losses: Openings that failed plus reads that gave no frame, since the start.
        problem: Why the last loss happened ("" for a camera that stopped giving frames).
        read_error: The error a read raised, if any (shown as the feedback's detail).
    """

    finite = False
    lossless = True

    def __init__(self, factory: Callable[[], Reader]) -> None:
        self._factory = factory
        self._reader: Reader | None = None
        self.label = ""
        self.losses = 0
        self.problem = ""
        self.read_error: str | None = None

    def open(self) -> None:
        self.close()
        reader: Reader | None = None
        try:
            reader = self._factory()
            self.label = str(getattr(reader, "label", ""))
            reader.open()
        except Exception as e:
            if reader is not None:
                reader.close()
            self.losses += 1
            self.problem = f"cannot open the camera ({e})"
            raise
        self._reader = reader

    def read(self) -> RawFrame | None:
        if self._reader is None:
            return None
        try:
            raw = self._reader.read()
        except EndOfStream:
            raw = None
        except Exception as e:  # noqa: BLE001 - a failing read is a lost camera
            raw = None
            self.read_error = str(e)
        if raw is None:
            self.losses += 1
            self.problem = ""
        return raw

    def close(self) -> None:
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.close()
