"""Layout files: parse, load, write (atomically, read back) and re-target a layout to another
dictionary."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from drovisio.errors import LIMITS, InputError
from drovisio.fileio import atomic_write_bytes
from drovisio.layout.dictionaries import aruco_dictionary_size
from drovisio.layout.errors import LayoutError
from drovisio.layout.messages import convert_validation_error
from drovisio.layout.model import MarkerLayout
from drovisio.textfile import check_regular_file, parse_json

__all__ = ["parse_layout", "load_layout", "save_layout", "layout_to_json", "with_dictionary"]


def _reject_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


class _DuplicateKey(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def parse_layout(data: dict[str, Any] | str | bytes, source: str | os.PathLike[str] = "<layout>",
                 ) -> MarkerLayout:
    """Validate a layout given as a dict or JSON text.

    Args:
        data: the parsed JSON object, or JSON text.
        source: what to call it in error messages (a file name; mesh paths are resolved
            relative to it when it is a path).

    Returns:
        The validated layout, in the units of ``data``.

    Raises:
        LayoutError: invalid JSON or an invalid layout (message names source, marker, field).
    """
    src = os.fspath(source)
    if isinstance(data, (str, bytes)):
        try:
            text = data.decode("utf-8") if isinstance(data, bytes) else data
            data = parse_json(text, src, object_pairs_hook=_reject_duplicate_keys)
        except UnicodeDecodeError as e:
            raise LayoutError(f"{src}: not UTF-8 text ({e.reason} at byte {e.start})") from None
        except _DuplicateKey as e:
            raise LayoutError(f"{src}: duplicate key {e.key!r} in a JSON object; keep only "
                              "one") from None
        except InputError as e:
            raise LayoutError(str(e)) from None
    if not isinstance(data, dict):
        raise LayoutError(f"{src}: a layout file must hold one JSON object {{...}}, "
                          f"not {type(data).__name__}")
    try:
        layout = MarkerLayout.model_validate(data)
    except ValidationError as e:
        raise convert_validation_error(e, data, src) from None
    if src and not src.startswith("<"):
        layout._source = Path(src)
    return layout


def load_layout(path: str | os.PathLike[str]) -> MarkerLayout:
    """Read and validate one layout file.

    Args:
        path: the ``.json`` file. Errors name it as given.

    Returns:
        The layout (numbers in the file's units; ``source`` set to ``path``).

    Raises:
        LayoutError: missing/unreadable file, invalid JSON or invalid layout.
    """
    src = os.fspath(path)
    try:
        p = check_regular_file(path, "layout file")
        if p.stat().st_size > LIMITS.max_file_bytes:
            raise LayoutError(f"{src}: larger than {LIMITS.max_file_bytes // 1024} KiB; is it "
                              "the right file?")
        raw = p.read_bytes()
    except InputError as e:
        raise LayoutError(str(e).replace("layout file not found", "no such layout file")) \
            from None
    except OSError as e:
        raise LayoutError(f"{src}: cannot read: {e.strerror}") from None
    return parse_layout(raw, src)


def layout_to_json(layout: MarkerLayout) -> str:
    """The layout as JSON text in the file format: file units, full float precision
    (``repr``), readable layout (one marker per block, coordinates on one line)."""
    return layout.to_json()


def save_layout(layout: MarkerLayout, path: str | os.PathLike[str], overwrite: bool = False
                ) -> Path:
    """Write a layout file atomically (temp file in the same folder, then rename).

    The numbers are written in the layout's own units. ``mesh`` is written as is (it stays
    relative to the new file's folder).

    Args:
        layout: the layout to write.
        path: destination ``.json`` file; its folder must exist.
        overwrite: replace an existing file; without it an existing file is an error.

    Returns:
        The path written.

    Raises:
        LayoutError: the file exists and ``overwrite`` is False.
        drovisio.errors.WriteError: it cannot be written (any previous file is kept).
    """
    dest = Path(path)
    src = os.fspath(path)
    if not overwrite and dest.exists():
        raise LayoutError(f"{src}: already exists; choose another file name or pass "
                          "overwrite=True to replace it")
    text = layout_to_json(layout)
    folder = dest.parent if str(dest.parent) else Path(".")
    if not folder.is_dir():
        raise LayoutError(f"{src}: folder {os.fspath(folder)} does not exist")
    def verify(tmp: Path) -> None:
        if parse_layout(tmp.read_bytes(), src) != layout:
            raise ValueError("the layout read back differs from the one written")

    try:
        atomic_write_bytes(dest, text.encode("utf-8"), overwrite=overwrite, verify=verify)
    except FileExistsError:
        raise LayoutError(f"{src}: already exists; choose another file name or pass "
                          "overwrite=True to replace it") from None
    layout._source = dest
    return dest


def with_dictionary(layout: MarkerLayout, dictionary: str) -> MarkerLayout:
    """The layout with every code in ``dictionary`` (same ids), named ``NAME@DICT`` (without
    the ``DICT_`` prefix): the same brick for a detector that reads another family, e.g.
    AprilTag 3 and ``DICT_APRILTAG_36h11``.

    Raises:
        LayoutError: unknown dictionary, or too few codes in it for the layout's ids.
    """
    try:
        size = aruco_dictionary_size(dictionary)
    except ValueError as e:
        raise LayoutError(str(e)) from None
    need = (layout.first_id or 0) + (layout.instances or 0) * (layout.ids_per_instance or 1)
    if size < need:
        raise LayoutError(f"{dictionary} has {size} codes, {layout.name} needs ids up to "
                          f"{need - 1}")
    data = layout.model_dump(mode="json", by_alias=True)
    data["name"] = f"{layout.name}@{dictionary.removeprefix('DICT_')}"
    for m in data["markers"]:
        if m.get("kind") == "aruco":
            m["dictionary"] = dictionary
    return parse_layout(data, layout.source or "<layout>")
