"""Checks that need the whole layout: the id block, the dot colours, the dots' plane and the
declared symmetry. Each returns located problems (empty when all is well); the layout's
validator raises them together."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drovisio.layout.dictionaries import aruco_dictionary_size
from drovisio.layout.errors import Located
from drovisio.layout.markers import ArucoMarker, DotMarker
from drovisio.layout.palette import ColorSpec

__all__ = [
    "DOT_COPLANAR_TOL_M",
    "SYMMETRY_TOL_M",
    "id_issues",
    "color_issues",
    "coplanar_issues",
    "symmetry_issues",
    "dots_rot180_z_symmetric",
    "plane_outlier",
]

DOT_COPLANAR_TOL_M = 0.001  #: dots within 1 mm of their common plane.
SYMMETRY_TOL_M = 0.001  #: a half-turn must map each dot onto a dot within 1 mm.

_ID_FIELDS = ("first_id", "ids_per_instance", "instances")


def _slot_issues(codes: Sequence[tuple[int, ArucoMarker]], ipi: int | None) -> list[Located]:
    """Duplicate slots, and slots beyond ``ids_per_instance``."""
    issues: list[Located] = []
    seen: dict[int, int] = {}
    for i, m in codes:
        if m.id in seen:
            issues.append((("markers", i, "id"), f"duplicate slot {m.id}: already "
                           f"used by markers[{seen[m.id]}]; give each code its own "
                           "slot"))
        else:
            seen[m.id] = i
        if ipi is not None and m.id >= ipi:
            issues.append((("markers", i, "id"), f"slot {m.id} is out of range: "
                           f"ids_per_instance is {ipi}, so slots are 0..{ipi - 1}; "
                           "raise ids_per_instance or renumber the slot"))
    return issues


def _dictionary_range_issues(codes: Sequence[tuple[int, ArucoMarker]], first_id: int,
                             ipi: int, instances: int) -> list[Located]:
    """A dictionary too small for the id block (reported once per dictionary)."""
    issues: list[Located] = []
    end = first_id + ipi * instances
    reported: set[str] = set()
    for i, m in codes:
        size = aruco_dictionary_size(m.dictionary)
        if end > size and m.dictionary not in reported:
            reported.add(m.dictionary)
            issues.append((("markers", i, "dictionary"), f"ids run up to "
                           f"{end - 1} (first_id {first_id} + "
                           f"ids_per_instance {ipi} x instances "
                           f"{instances}) but {m.dictionary} has only {size} "
                           f"ids (0..{size - 1}); use a larger dictionary or lower "
                           "first_id/instances"))
    return issues


def id_issues(codes: Sequence[tuple[int, ArucoMarker]], first_id: int | None,
              ids_per_instance: int | None, instances: int | None) -> list[Located]:
    """Problems with the id block of a layout's codes.

    Args:
        codes: ``(index in markers, code)`` of every ArUco marker.
        first_id, ids_per_instance, instances: the layout's id fields (None when unset).

    Returns:
        Missing id fields, duplicate or out-of-range slots, and dictionaries too small for
        the block; nothing when the layout has no codes.
    """
    if not codes:
        return []
    values = (first_id, ids_per_instance, instances)
    issues: list[Located] = [
        ((k,), "required when the layout has ArUco codes; give an integer (ids = first_id "
               "+ instance * ids_per_instance + slot)")
        for k, v in zip(_ID_FIELDS, values) if v is None
    ]
    issues += _slot_issues(codes, ids_per_instance)
    if first_id is not None and ids_per_instance is not None and instances is not None:
        issues += _dictionary_range_issues(codes, first_id, ids_per_instance, instances)
    return issues


def color_issues(dots: Sequence[tuple[int, DotMarker]], palette: dict[str, ColorSpec]
                 ) -> list[Located]:
    """Dots whose colour is neither in the default palette nor in the layout's ``colors``."""
    return [(("markers", i, "color"), f"unknown colour {m.color!r}; use one "
             f"of {', '.join(palette)} or define it in 'colors'")
            for i, m in dots if m.color not in palette]


def plane_outlier(points: np.ndarray) -> tuple[int, float]:
    """The point farthest from the best-fit plane of ``points`` ((N, 3), N >= 3) and its
    distance to that plane (same unit as ``points``)."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred)[2][2]
    dist = np.abs(centred @ normal)
    worst = int(np.argmax(dist))
    return worst, float(dist[worst])


def coplanar_issues(dots: Sequence[tuple[int, DotMarker]], scale_to_m: float) -> list[Located]:
    """The dot farthest from the dots' best-fit plane, when beyond the tolerance.

    Args:
        dots: ``(index in markers, dot)`` of every dot.
        scale_to_m: metres per file unit.
    """
    if len(dots) < 4:
        return []
    worst, off = plane_outlier(np.array([m.center for _, m in dots], np.float64) * scale_to_m)
    if off > DOT_COPLANAR_TOL_M:
        i = dots[worst][0]
        return [(("markers", i, "center"), f"dots are not coplanar: this dot is "
                 f"{off * 1000:.1f} mm off the best-fit plane of the "
                 f"layout's dots (tolerance {DOT_COPLANAR_TOL_M * 1000:g} mm); put "
                 "all dots on one plane")]
    return []


def symmetry_issues(declared: str, symmetric: bool, *, has_codes: bool) -> list[Located]:
    """A declared ``symmetry`` the dots contradict.

    Args:
        declared: the layout's ``symmetry`` field.
        symmetric: whether a half-turn about z maps the dots onto themselves.
        has_codes: codes fix the orientation, so symmetric dots need no declaration.
    """
    if declared == "rot180_z" and not symmetric:
        return [(("symmetry",), "'rot180_z' but a half-turn about z does not map "
                 "the dots onto dots of the same colour and diameter; use 'none'")]
    if declared == "none" and symmetric and not has_codes:
        return [(("symmetry",), "the dots look the same after a half-turn about z, "
                 "so the yaw is ambiguous by 180 deg; set 'rot180_z' (or make the "
                 "pattern asymmetric)")]
    return []


def dots_rot180_z_symmetric(dots: Sequence[DotMarker], centers_m: np.ndarray,
                            scale_to_m: float) -> bool:
    """Whether a half-turn about z maps every dot onto a dot of the same colour and
    diameter (within :data:`SYMMETRY_TOL_M`).

    Args:
        dots: the dots, file order.
        centers_m: (N, 3) their centres in metres, same order.
        scale_to_m: metres per file unit (for the diameters).
    """
    rot = centers_m * np.array([-1.0, -1.0, 1.0])
    for j, d in enumerate(dots):
        dist = np.linalg.norm(centers_m - rot[j], axis=1)
        ok = [k for k in np.flatnonzero(dist <= SYMMETRY_TOL_M).tolist()
              if dots[k].color == d.color
              and abs(dots[k].diameter - d.diameter) * scale_to_m <= SYMMETRY_TOL_M]
        if not ok:
            return False
    return True
