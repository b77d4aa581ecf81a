"""What every frame reader hands back (:class:`RawFrame`) and how a finite one says it has
no more (:class:`EndOfStream`): below :mod:`drovisio.sources` so that readers living elsewhere
(the MCAP reader) need nothing of it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["EndOfStream", "RawFrame"]


class EndOfStream(Exception):
    """Raised by a finite reader when it has no more frames."""


@dataclass
class RawFrame:
    """What a reader returns for one frame."""

    image: np.ndarray | None
    """BGR uint8 (H, W, 3); None when ``error`` says why the frame could not be decoded."""
    index: int
    media_time: float | None = None
    """Position in the file/recording (s), used to pace playback; None for live sources."""
    name: str = ""
    t_wall: float | None = None
    """Capture time if the reader knows it better than 'now' (UNIX s)."""
    error: str | None = None
    notes: list[str] = field(default_factory=list)
    """Conversions made (e.g. "16-bit image scaled to 8 bits")."""
