"""What a click on the 3D view does (the click modes) and what it did (:class:`ClickResult`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["MODES", "Mode", "ClickResult"]

#: What a click on the model does.
MODES = ("code", "dot", "select", "origin")
Mode = Literal["code", "dot", "select", "origin"]


@dataclass
class ClickResult:
    """What a click did: ``action`` in ``added``, ``selected``, ``origin``, ``missed``,
    ``none``; ``marker`` the marker index concerned; ``message`` a sentence for the user."""

    action: str
    message: str
    marker: int | None = None
    point: tuple[float, float, float] | None = None
