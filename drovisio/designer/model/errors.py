"""The designer's user-facing error."""

from __future__ import annotations

__all__ = ["DesignError"]


class DesignError(ValueError):
    """A user-facing problem (bad file, impossible edit). The message says what to do."""
