"""Stage 5, grouping: the frame's refined codes grouped into bricks, duplicated ids apart.

Codes are grouped by their layout's id blocks into brick instances. A code id read more than
once in a frame (one printed id on several objects) is taken out of its brick and each copy
is posed on its own: which copy belongs to the brick's other codes is unknown, and merging
them would make one wrong brick.
"""

from __future__ import annotations

from drovisio.detect.aruco.codes import BrickKey, CodeDetection

__all__ = ["group_by_brick", "split_duplicates"]


def group_by_brick(codes: list[CodeDetection]) -> dict[BrickKey, list[CodeDetection]]:
    """The codes whose corner fit is ``ok``, by brick ``(layout name, instance, 0)``, in
    the order of ``codes``."""
    groups: dict[BrickKey, list[CodeDetection]] = {}
    for c in codes:
        if c.refined is None or not c.refined.ok:
            continue
        groups.setdefault((c.layout.name, c.instance, 0), []).append(c)
    return groups


def _image_order(c: CodeDetection) -> tuple[float, ...]:
    assert c.refined is not None  # grouped codes are refined
    return (c.marker_id, *c.refined.corners_px.mean(axis=0)[::-1])


def split_duplicates(groups: dict[BrickKey, list[CodeDetection]]
                     ) -> tuple[dict[BrickKey, list[CodeDetection]], dict[int, int]]:
    """Take the codes whose id was read more than once out of their bricks.

    Each copy is posed on its own under keys ``(layout, instance, 1..)`` (flagged
    ``duplicate``); the brick's remaining codes keep key ``(layout, instance, 0)``.

    Returns:
        (the groups; code id -> how many times it was read, for ids read more than once).
    """
    duplicates: dict[int, int] = {}
    out: dict[BrickKey, list[CodeDetection]] = {}
    for (name, inst, _), group in groups.items():
        ids = [c.marker_id for c in group]
        dup = {i for i in ids if ids.count(i) > 1}
        if not dup:
            out[(name, inst, 0)] = group
            continue
        rest = [c for c in group if c.marker_id not in dup]
        if rest:
            out[(name, inst, 0)] = rest
        # copies in image order (top to bottom, left to right): stable keys for a frame
        copies = sorted((c for c in group if c.marker_id in dup), key=_image_order)
        for k, c in enumerate(copies, start=1):
            out[(name, inst, k)] = [c]
        for i in dup:
            duplicates[i] = ids.count(i)
    return out, duplicates
