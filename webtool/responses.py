"""The one JSON response class of the web tool: JSON-safe by construction.

Python's ``json`` writes ``NaN`` and ``Infinity`` (not JSON: a browser's ``JSON.parse`` fails)
and Starlette's ``JSONResponse`` refuses them with a 500. Here every non-finite number becomes
``null`` (the domain says what it means beside it, e.g. the mount page's footprint says the
ground is not in view), numpy scalars and arrays become plain numbers and lists, and the body is
written with ``allow_nan=False`` so that nothing else can slip through. Every route, the error
handler and the app's default use it.
"""

from __future__ import annotations

import json
import math
from typing import Any

from fastapi.responses import JSONResponse as _StarletteJSON

__all__ = ["NO_STORE", "JSONResponse", "json_safe"]

#: the header of every answer that must not be cached (states, frames, downloads, errors)
NO_STORE = {"Cache-Control": "no-store"}


def json_safe(obj: Any, _depth: int = 0) -> Any:
    """``obj`` with non-finite numbers as ``None``, numpy values as Python ones, tuples and
    sets as lists (recursively; nesting past 64 levels is cut to ``None``)."""
    if _depth > 64:
        return None
    if obj is None or isinstance(obj, (str, bool, int)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): json_safe(v, _depth + 1) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [json_safe(v, _depth + 1) for v in obj]
    tolist = getattr(obj, "tolist", None)  # numpy arrays and scalars
    if callable(tolist):
        return json_safe(tolist(), _depth + 1)
    item = getattr(obj, "item", None)
    if callable(item):
        return json_safe(item(), _depth + 1)
    return str(obj)


class JSONResponse(_StarletteJSON):
    """A JSON response that cannot emit NaN or Infinity (see the module doc)."""

    def render(self, content: Any) -> bytes:
        return json.dumps(json_safe(content), ensure_ascii=False, allow_nan=False,
                          separators=(",", ":")).encode("utf-8")
