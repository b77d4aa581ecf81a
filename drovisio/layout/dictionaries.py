"""ArUco dictionaries: the names a layout may use, their sizes, families and code bits."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

__all__ = [
    "aruco_dictionaries",
    "aruco_dictionary_id",
    "aruco_dictionary_size",
    "aruco_code_bits",
    "aruco_family",
    "accepted_dictionary_names",
    "check_dictionary_name",
]


@dataclass(frozen=True)
class _DictInfo:
    name: str  # canonical name
    value: int  # cv2.aruco.DICT_* constant
    size: int  # number of codes
    family: str  # dictionaries of the same family share codes (prefix-nested)


def _family_of(name: str) -> str:
    parts = name.split("_")  # DICT_4X4_50 -> ["DICT", "4X4", "50"]
    if len(parts) == 3 and parts[1][0].isdigit() and "X" in parts[1] and parts[2].isdigit():
        return f"DICT_{parts[1]}"
    return name.upper()


@lru_cache(maxsize=1)
def _dictionary_table() -> tuple[dict[str, _DictInfo], tuple[str, ...]]:
    """Accepted names -> info, and the canonical names in cv2 constant order."""
    by_value: dict[int, list[str]] = {}
    for attr in dir(cv2.aruco):
        if attr.startswith("DICT_"):
            value = getattr(cv2.aruco, attr)
            if isinstance(value, int):
                by_value.setdefault(value, []).append(attr)
    table: dict[str, _DictInfo] = {}
    canonical: list[str] = []
    for value in sorted(by_value):
        names = sorted(by_value[value])
        # OpenCV's documented spelling has a lower-case 'h' (DICT_APRILTAG_36h11); the
        # upper-case aliases are accepted as well.
        name = next((n for n in names if n != n.upper()), names[0])
        size = int(cv2.aruco.getPredefinedDictionary(value).bytesList.shape[0])
        info = _DictInfo(name=name, value=value, size=size, family=_family_of(name))
        canonical.append(name)
        for n in names:
            table[n] = info
    return table, tuple(canonical)


def aruco_dictionaries() -> list[str]:
    """Names of the predefined ArUco dictionaries, in OpenCV's constant order.

    Returns:
        Canonical names such as ``"DICT_4X4_50"`` or ``"DICT_APRILTAG_36h11"``. The
        upper-case aliases OpenCV also defines (``"DICT_APRILTAG_36H11"``) are accepted in
        layout files too.
    """
    return list(_dictionary_table()[1])


def accepted_dictionary_names() -> list[str]:
    """Every name a layout file may use (canonical names and aliases), in OpenCV's constant
    order, aliases of one constant sorted by name (the schema's ``enum``)."""
    table = _dictionary_table()[0]
    return sorted(table, key=lambda n: (table[n].value, n))


def _dict_info(name: str) -> _DictInfo:
    table = _dictionary_table()[0]
    try:
        return table[name]
    except KeyError:
        raise ValueError(
            f"unknown dictionary {name!r}; use one of {', '.join(aruco_dictionaries())}"
        ) from None


def check_dictionary_name(name: str) -> None:
    """Raise ``ValueError`` (listing the valid names) when ``name`` is no predefined
    dictionary."""
    _dict_info(name)


def aruco_dictionary_id(name: str) -> int:
    """The ``cv2.aruco`` constant of a dictionary name.

    Args:
        name: a predefined dictionary name, e.g. ``"DICT_4X4_50"``.

    Returns:
        The integer for ``cv2.aruco.getPredefinedDictionary``.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    return _dict_info(name).value


def aruco_dictionary_size(name: str) -> int:
    """Number of codes (ids ``0 .. size-1``) in a predefined dictionary."""
    return _dict_info(name).size


@lru_cache(maxsize=1024)
def aruco_code_bits(dictionary: str | int, marker_id: int) -> np.ndarray:
    """A code's cells, its black border included: (n, n) uint8, 1 = white, 0 = black; row 0
    is the printed image's top edge, column 0 its left edge (read-only, cached).

    Args:
        dictionary: The dictionary's name (``DICT_4X4_50``) or OpenCV's id for it.
        marker_id: The code's id in the dictionary.
    """
    did = aruco_dictionary_id(dictionary) if isinstance(dictionary, str) else int(dictionary)
    d = cv2.aruco.getPredefinedDictionary(did)
    n = d.markerSize + 2
    img = cv2.aruco.generateImageMarker(d, int(marker_id), n, borderBits=1)
    out = (img > 127).astype(np.uint8)
    out.flags.writeable = False
    return out


def aruco_family(name: str) -> str:
    """Family of a predefined dictionary: dictionaries of one family share their codes.

    ``DICT_4X4_50`` is the first 50 codes of ``DICT_4X4_100``, and so on up to
    ``_1000``; the same holds for 5X5, 6X6 and 7X7. ``DICT_ARUCO_ORIGINAL``,
    ``DICT_ARUCO_MIP_36h12`` and each ``DICT_APRILTAG_*`` are their own family.

    Returns:
        ``"DICT_4X4"`` etc. for the nested families, else the upper-cased name.
    """
    return _dict_info(name).family
