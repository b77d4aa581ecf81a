"""The reader protocol every kind of source implements, and the playback paces."""

from __future__ import annotations

from typing import Literal, Protocol

from drovisio.raw_frame import RawFrame

__all__ = ["Pace", "Reader"]

Pace = Literal["realtime", "max"]
"""How a finite source is played: at its media timing, or as fast as it is consumed."""


class Reader(Protocol):
    """One kind of source. ``open`` raises on failure; ``read`` returns a frame (possibly one
    carrying ``error``), None on a failure (the source is lost), or raises
    :class:`~drovisio.raw_frame.EndOfStream` when a finite source ends.

    Attributes:
        label: What to call the source in messages.
        finite: True for files, folders and recordings (they end; they are not retried).
        lossless: True when every frame must reach the consumer (a playback paced by its
            consumer); :class:`~drovisio.sources.FrameSource` then waits instead of dropping.
    """

    label: str
    finite: bool

    def open(self) -> None: ...

    def read(self) -> RawFrame | None: ...

    def close(self) -> None: ...
