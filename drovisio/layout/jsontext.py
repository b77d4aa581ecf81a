"""The layout file's text: JSON with one marker per block and coordinates on one line."""

from __future__ import annotations

import json
from typing import Any

__all__ = ["layout_json_text"]

#: The order of the top-level fields in a written file.
_FIELD_ORDER = ["schema", "name", "description", "units", "dimensions", "mesh", "first_id",
                "ids_per_instance", "instances", "symmetry", "colors", "markers"]


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _dump_compact(obj: Any, indent: int = 0) -> str:
    """JSON with objects indented and short lists of numbers kept on one line."""
    if isinstance(obj, dict):
        return _dump_object(obj, indent)
    if isinstance(obj, list):
        return _dump_list(obj, indent)
    return json.dumps(obj, allow_nan=False, ensure_ascii=False)


def _dump_object(obj: dict[str, Any], indent: int) -> str:
    if not obj:
        return "{}"
    pad, inner = "  " * indent, "  " * (indent + 1)
    items = [f"{inner}{json.dumps(k)}: {_dump_compact(v, indent + 1)}" for k, v in obj.items()]
    return "{\n" + ",\n".join(items) + "\n" + pad + "}"


def _dump_list(obj: list[Any], indent: int) -> str:
    flat = all(_is_number(x) for x in obj)
    # (a row of a nested list may hold booleans: they count as numbers there)
    nested = all(isinstance(x, list) and all(isinstance(y, (int, float)) for y in x)
                 for x in obj)
    if flat or (nested and obj):
        return json.dumps(obj, allow_nan=False)
    if not obj:
        return "[]"
    pad, inner = "  " * indent, "  " * (indent + 1)
    items = [f"{inner}{_dump_compact(v, indent + 1)}" for v in obj]
    return "[\n" + ",\n".join(items) + "\n" + pad + "]"


def layout_json_text(data: dict[str, Any]) -> str:
    """A layout's file data (``MarkerLayout.to_dict()``) as JSON text: file units, full float
    precision (``repr``), readable layout (one marker per block, coordinates on one line).

    Args:
        data: the JSON-ready dict; the id fields it lacks are added as null.
    """
    # Files without codes state their id fields explicitly as null (contract example).
    for k in ("first_id", "ids_per_instance", "instances"):
        data.setdefault(k, None)
    data = {k: data[k] for k in _FIELD_ORDER if k in data} | {k: v for k, v in data.items()
                                                              if k not in _FIELD_ORDER}
    return _dump_compact(data) + "\n"
