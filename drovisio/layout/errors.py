"""The layout's error types: the user-facing :class:`LayoutError` and the located problems
the validators raise on the way to it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from drovisio.errors import InputError

__all__ = ["LayoutError", "LocatedIssues", "Located"]

#: One problem: its place (pydantic location parts below the validated object) and the
#: sentence telling the user how to fix it.
Located = tuple[tuple[Any, ...], str]


class LayoutError(InputError):
    """A layout file (or a set of layouts) is invalid.

    The message is meant for the user: every line names the file, the place (marker index
    and kind/id, then the field) and says how to fix it. ``issues`` holds the same lines.
    """

    def __init__(self, message: str, issues: Sequence[str] | None = None):
        super().__init__(message)
        self.issues: list[str] = list(issues) if issues is not None else [message]


class LocatedIssues(ValueError):
    """Located problems raised inside validators (converted to :class:`LayoutError`)."""

    def __init__(self, items: list[Located]):
        super().__init__("; ".join(msg for _, msg in items))
        self.items = items
