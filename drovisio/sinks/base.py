"""The sink protocol."""

from __future__ import annotations

from typing import Protocol

__all__ = ["Sink", "SinkError"]


class SinkError(ValueError):
    """A sink that cannot be opened (bad spec, unusable path)."""


class Sink(Protocol):
    name: str

    def send(self, output) -> None: ...

    def close(self) -> None: ...

    def status(self) -> dict: ...
