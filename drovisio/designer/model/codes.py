"""Which ArUco dictionary a design's codes use: the families offered, and the smallest
dictionary of a family that holds the id block."""

from __future__ import annotations

from drovisio.layout import aruco_dictionaries, aruco_dictionary_size, aruco_family

__all__ = ["code_families", "family_dictionaries", "dictionary_for_block"]


def code_families() -> list[tuple[str, str]]:
    """Code families to choose from: ``(family, label)``; a family's dictionaries share codes.

    ``DICT_4X4`` stands for DICT_4X4_50/100/250/1000 (the size is chosen to hold the ids).
    """
    labels = {
        "DICT_4X4": "4x4 codes (big cells: read from farthest; the thesis's choice)",
        "DICT_5X5": "5x5 codes",
        "DICT_6X6": "6x6 codes",
        "DICT_7X7": "7x7 codes (many ids, small cells)",
    }
    out: list[tuple[str, str]] = []
    seen: set[str] = set()
    for d in aruco_dictionaries():
        fam = aruco_family(d)
        if fam in seen:
            continue
        seen.add(fam)
        out.append((fam, labels.get(fam, d)))
    return out


def family_dictionaries(family: str) -> list[str]:
    """The dictionaries of a family, smallest first."""
    names = [d for d in aruco_dictionaries() if aruco_family(d) == family]
    return sorted(names, key=aruco_dictionary_size)


def dictionary_for_block(family: str, end: int) -> str | None:
    """The smallest dictionary of ``family`` holding ids ``0 .. end-1``, or None."""
    for d in family_dictionaries(family):
        if aruco_dictionary_size(d) >= end:
            return d
    return None
