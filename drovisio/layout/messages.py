"""From pydantic's validation errors to the user's lines: each names the file, the marker
(index and kind/id), the field, and says how to fix it."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Any

from pydantic import ValidationError
from pydantic_core import ErrorDetails

from drovisio.layout.errors import LayoutError, Located, LocatedIssues
from drovisio.layout.model import SCHEMA_ID

__all__ = ["convert_validation_error"]


def _marker_label(raw: Any) -> str:
    if not isinstance(raw, dict):
        return ""
    kind = raw.get("kind")
    if kind == "aruco":
        return f" (aruco id {raw.get('id')})" if "id" in raw else " (aruco)"
    if kind == "dot":
        return f" (dot {raw.get('color')})" if "color" in raw else " (dot)"
    return f" ({kind})" if isinstance(kind, str) else ""


def _marker_prefix(loc: list[Any], data: Any) -> tuple[str, list[Any]]:
    """``markers[2] (aruco id 1)`` and the rest of ``loc`` when it points into a marker."""
    if not (len(loc) >= 2 and loc[0] == "markers" and isinstance(loc[1], int)):
        return "", loc
    raw = None
    if isinstance(data, dict) and isinstance(data.get("markers"), list):
        if 0 <= loc[1] < len(data["markers"]):
            raw = data["markers"][loc[1]]
    rest = loc[2:]
    if rest and rest[0] in ("aruco", "dot"):  # discriminated-union tag
        rest = rest[1:]
    return f"markers[{loc[1]}]{_marker_label(raw)}", rest


def _format_loc(loc: Sequence[Any], data: Any) -> str:
    """('markers', 2, 'aruco', 'corners', 1) -> 'markers[2] (aruco id 1): corners[1]'."""
    prefix, rest = _marker_prefix(list(loc), data)
    out = ""
    for part in rest:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    if prefix and out:
        return f"{prefix}: {out}"
    return prefix or out or "(layout)"


def _jsonable(x: Any) -> bool:
    try:
        json.dumps(x)
        return True
    except (TypeError, ValueError):
        return False


#: What a value of the wrong type should have been, by pydantic error type.
_WANTED_TYPE = {"float_type": "a number", "finite_number": "a finite number",
                "int_type": "an integer", "int_from_float": "an integer",
                "int_parsing": "an integer", "float_parsing": "a number",
                "string_type": "a string", "tuple_type": "a list", "list_type": "a list",
                "dict_type": "an object", "model_type": "an object",
                "model_attributes_type": "an object"}


class _Error:
    """The parts of one pydantic error the messages read."""

    def __init__(self, err: ErrorDetails):
        self.type: str = err["type"]
        self.ctx: dict[str, Any] = dict(err.get("ctx") or {})
        self.input: Any = err.get("input")
        self.loc: tuple[Any, ...] = tuple(err["loc"])
        self.field: str = next((p for p in reversed(self.loc) if isinstance(p, str)), "")
        self.msg: str = err.get("msg", "invalid value")


def _missing(e: _Error) -> Located:
    if e.loc and isinstance(e.loc[-1], int):  # a fixed-length list such as [x, y, z]
        return e.loc[:-1], f"too few items (item [{e.loc[-1]}] is missing)"
    return e.loc, "required field is missing; add it"


def _extra(e: _Error) -> Located:
    return e.loc, "unknown field; remove it or fix its spelling"


def _literal(e: _Error) -> Located:
    if e.field == "schema":
        return e.loc, f"unsupported schema {e.input!r}; this version reads exactly {SCHEMA_ID!r}"
    if e.field == "units":
        return e.loc, f"unknown units {e.input!r}; use one of 'm', 'cm', 'mm'"
    return e.loc, f"invalid value {e.input!r}; use one of {e.ctx.get('expected')}"


def _tag_invalid(e: _Error) -> Located:
    return e.loc + ("kind",), (f"unknown marker kind {e.ctx.get('tag')!r}; use "
                               f"{e.ctx.get('expected_tags')}")


def _tag_missing(e: _Error) -> Located:
    return e.loc + ("kind",), "missing 'kind'; use 'aruco' or 'dot'"


def _bound(e: _Error) -> Located:
    op = ">" if e.type == "greater_than" else ">="
    bound = e.ctx.get("gt", e.ctx.get("ge"))
    return e.loc, f"must be {op} {bound:g} (got {e.input!r})"


def _length(e: _Error) -> Located:
    want = e.ctx.get("min_length") if e.type == "too_short" else e.ctx.get("max_length")
    if e.field == "markers":
        if e.type == "too_short":
            return e.loc, "a layout needs at least one marker"
        got = f"{len(e.input)} markers" if isinstance(e.input, (list, tuple)) else "too many"
        return e.loc, f"{got}, more than the {want} a layout may hold; keep at most {want}"
    if e.field in ("corners",) and isinstance(e.input, (list, tuple)):
        return e.loc, f"expected 4 corners [[x, y, z], ...], got {len(e.input)}"
    if isinstance(e.input, (list, tuple)):
        return e.loc, f"expected {want} items, got {len(e.input)}"
    return e.loc, f"expected {want} items"


def _wrong_type(e: _Error) -> Located:
    got = json.dumps(e.input) if _jsonable(e.input) else repr(e.input)
    return e.loc, f"expected {_WANTED_TYPE[e.type]}, got {got}"


_MESSAGES: dict[str, Callable[[_Error], Located]] = {
    "missing": _missing,
    "extra_forbidden": _extra,
    "literal_error": _literal,
    "union_tag_invalid": _tag_invalid,
    "union_tag_not_found": _tag_missing,
    "greater_than": _bound,
    "greater_than_equal": _bound,
    "too_short": _length,
    "too_long": _length,
    **{typ: _wrong_type for typ in _WANTED_TYPE},
}


def _error_message(err: ErrorDetails) -> list[Located]:
    """The located lines of one pydantic error (several for a validator's issues)."""
    e = _Error(err)
    issues = e.ctx.get("error")
    if e.type == "value_error" and isinstance(issues, LocatedIssues):
        return [(e.loc + sub, msg) for sub, msg in issues.items]
    message = _MESSAGES.get(e.type)
    if message is not None:
        return [message(e)]
    msg = e.msg
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    return [(e.loc, msg)]


def convert_validation_error(exc: ValidationError, data: Any, source: str) -> LayoutError:
    """The :class:`LayoutError` for a failed validation of ``data`` read from ``source``.

    Args:
        exc: pydantic's error.
        data: the validated object (to label markers by their kind and id).
        source: the file name (or ``<layout>``) each line starts with.
    """
    items: list[Located] = []
    for err in exc.errors(include_url=False):
        items.extend(_error_message(err))
    lines = [f"{source}: {_format_loc(loc, data)}: {msg}" for loc, msg in items]
    lines = list(dict.fromkeys(lines))
    return LayoutError("\n".join(lines), lines)
