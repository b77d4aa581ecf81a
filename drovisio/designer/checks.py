"""Live checks of a marker design: what an engineer must fix or know before printing.

:func:`check_design` returns :class:`Finding` objects, each with a severity:

* ``error``: the layout cannot be saved as it is (the layout model would refuse it, or ids
  clash with another layout): export is blocked until it is fixed;
* ``warning``: it can be saved but will work badly (a marker overhangs its face, markers
  overlap, the dot pattern is symmetric so the yaw is ambiguous by 180 deg, markers too small
  to be seen from the working height, suspicious units);
* ``info``: facts (estimated detection distance per marker size, guessed units).

Each finding may offer :class:`Fix` actions (``{"op": ...}`` dicts) that
:func:`apply_fix` performs on the document: set the symmetry, change a dot's colour to break
the symmetry, move a marker to its face centre, shrink it to fit, use a free first id, set the
units.

Detection distance: a code must span at least :data:`MIN_CODE_PX` pixels and a dot
:data:`MIN_DOT_PX` pixels, so seen head-on at distance ``d`` with focal length ``fx`` (px):
``d_max = fx * size / min_px`` (less when seen at an angle).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from drovisio.camera import Camera
from drovisio.designer.fitting import fit_size, fits, markers_overlap
from drovisio.designer.model import DesignDocument, DesignError, DesignMarker
from drovisio.designer.symmetry import (
    dot_symmetries,
    rot180_z_symmetric,
    symmetry_breaking_colour,
)
from drovisio.layout import (
    DOT_COPLANAR_TOL_M,
    LayoutError,
    MarkerLayout,
    parse_layout,
)
from drovisio.layout.checks import plane_outlier

__all__ = ["MIN_CODE_PX", "MIN_DOT_PX", "WORKING_DISTANCE_M", "Fix", "Finding",
           "check_design", "apply_fix", "max_detection_distance", "dot_symmetries",
           "symmetry_breaking_colour", "markers_overlap", "fit_size", "blocking"]

#: A code must span at least this many pixels to be read (the aruco detector's target).
MIN_CODE_PX = 15.0
#: A dot must span at least this many pixels to be found.
MIN_DOT_PX = 6.0
#: Markers should be seen from at least this far (the drone climbs above 1 m and aligns from
#: about 1.5 m); smaller ones get a warning.
WORKING_DISTANCE_M = 1.5


@dataclass
class Fix:
    """One click that fixes a finding: ``label`` for the button, ``action`` for
    :func:`apply_fix`."""

    label: str
    action: dict[str, Any]


@dataclass
class Finding:
    """A live check result. ``key`` is stable (for tests and the page), ``markers`` are the
    indices concerned."""

    key: str
    severity: str  # "error" | "warning" | "info"
    message: str
    markers: list[int] = field(default_factory=list)
    fixes: list[Fix] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"key": self.key, "severity": self.severity, "message": self.message,
                "markers": list(self.markers),
                "fixes": [{"label": f.label, "action": f.action} for f in self.fixes]}


def blocking(findings: list[Finding]) -> list[Finding]:
    """The findings that prevent saving (severity ``error``)."""
    return [f for f in findings if f.severity == "error"]


def _mm(x: float) -> str:
    v = x * 1000
    return f"{v:.0f} mm" if abs(v - round(v)) < 0.05 else f"{v:.1f} mm"


def _m(x: float) -> str:
    return f"{x:.1f} m" if x < 10 else f"{x:.0f} m"


# ------------------------------------------------------------------------------ geometry


def max_detection_distance(size_m: float, camera: Camera, kind: str,
                           where: str = "centre") -> float:
    """How far (m) a marker of ``size_m`` can be detected facing the camera: it must span
    :data:`MIN_CODE_PX` (codes) / :data:`MIN_DOT_PX` (dots) pixels (square root of its area
    in the image, through the camera's own lens model).

    Args:
        where: ``"centre"`` of the picture, or its ``"edge"`` (the marker seen at 90 % of the
            way to the left edge, where a wide or fisheye lens makes things smallest).
    """
    need = MIN_CODE_PX if kind == "aruco" else MIN_DOT_PX
    w, h = camera.size
    u = (w - 1) / 2 - (0.9 * (w - 1) / 2 if where == "edge" else 0.0)
    ray = camera.rays(np.array([[u, (h - 1) / 2]]))[0]
    # the marker faces the camera across the ray: two axes perpendicular to it
    a = np.cross(ray, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(ray, a)
    half = 0.5 * size_m
    square = np.array([-a - b, a - b, a + b, -a + b]) * half

    def span(d: float) -> float:
        px = camera.project(ray * d + square)
        x, y = px[:, 0], px[:, 1]
        return math.sqrt(0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))))

    lo, hi = 1e-3, 1e4            # span falls with distance: bisection in log space
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if span(mid) >= need else (lo, mid)
    return lo


# ------------------------------------------------------------------------------ checks


def check_design(doc: DesignDocument, camera: Camera | None = None, *,
                 vet_fixes: bool = True) -> list[Finding]:
    """All live checks of a design (see the module docstring).

    Args:
        doc: the design (its ``others`` are the layouts whose ids must not be reused).
        camera: the drone's camera for the distance estimate (default: the thesis's 60 deg
            640x480 webcam).
        vet_fixes: try every one-click fix on a copy of the design and offer only those that
            remove their finding and add no warning or error (see :func:`_fix_works`).

    Returns:
        Findings, errors first, then warnings, then infos.
    """
    out: list[Finding] = []
    if not doc.has_mesh:
        return [Finding("no-mesh", "info", "Start by uploading the brick's 3D model (STL, OBJ, "
                        "PLY, GLB or OFF) or by opening an example.")]
    camera = camera or Camera.drone_webcam()
    out += _check_units(doc)
    if not doc.markers:
        out.append(Finding("no-markers", "error", "No markers yet: choose 'Add codes' or "
                           "'Add dots', then click on the model where each one goes."))
    out += _check_faces(doc)
    out += _check_overlaps(doc)
    out += _check_dots(doc)
    out += _check_ids(doc)
    out += _check_range(doc, camera)
    if not any(f.severity == "error" for f in out) and doc.markers:
        try:
            layout = parse_layout(doc.layout_data(None), f"layout {doc.name!r}")
        except LayoutError as e:
            for line in e.issues:
                out.append(Finding("layout-invalid", "error", line.split(": ", 1)[-1]))
        else:
            out += _check_detectors(doc, layout)
    rank = {"error": 0, "warning": 1, "info": 2}
    out = sorted(out, key=lambda f: rank[f.severity])
    if vet_fixes:
        for f in out:
            f.fixes = [x for x in f.fixes if _fix_works(doc, camera, f, x, out)]
    return out


def _check_detectors(doc: DesignDocument, layout: MarkerLayout) -> list[Finding]:
    """What the detectors themselves refuse (the dot detector's own model of the layout),
    so that no layout is saved that the drone then cannot use."""
    if not layout.has_dots:
        return []
    # deferred: the dot detector loads its compiled kernels, which only this check needs
    from drovisio.detect.dots.model import DotModel, LayoutNotSupported

    names = list(dict.fromkeys(layout.dot_colors()))
    try:
        DotModel.from_layout(layout, {n: i for i, n in enumerate(names)}, n_colors=len(names))
    except LayoutNotSupported as e:
        why = str(e).split(": ", 1)[-1]
        return [Finding("dots-unusable", "error", f"The dots cannot be used: {why}. Move "
                        "them onto one flat face, or delete them.", [i for i, _ in doc.dots()])]
    return []


def _serious(findings: list[Finding], levels: tuple[str, ...]) -> dict[str, int]:
    n: dict[str, int] = {}
    for f in findings:
        if f.severity in levels:
            n[f.key] = n.get(f.key, 0) + 1
    return n


def _fix_works(doc: DesignDocument, camera: Camera, finding: Finding, fix: Fix,
               before: list[Finding]) -> bool:
    """A fix is offered only if, applied to a copy of the design, its finding goes away and
    nothing as serious is added (e.g. a code moved onto another one, or shrunk below what
    the drone reads from its working distance). Fixing an error may bring back a warning
    that the error hid (the checks after it did not run); fixing a warning adds none."""
    trial = doc.copy()
    try:
        apply_fix(trial, fix.action)
    except DesignError:
        return False
    after = check_design(trial, camera, vet_fixes=False)
    if any(f.key == finding.key and f.markers == finding.markers
           and f.severity == finding.severity for f in after):
        return False
    levels = ("error",) if finding.severity == "error" else ("error", "warning")
    was, now = _serious(before, levels), _serious(after, levels)
    return all(now[k] <= was.get(k, 0) for k in now)


def _check_units(doc: DesignDocument) -> list[Finding]:
    out = []
    w = doc.units_warning()
    dims = doc.dimensions()
    size = " x ".join(f"{d * 1000:.0f}" for d in dims) + " mm"
    if w is not None:
        msg, guess = w
        out.append(Finding("units-suspect", "warning", msg,
                           fixes=[Fix(f"The numbers are {guess}", {"op": "set_units",
                                                                   "units": guess})]))
    elif doc.units_guessed:
        names = {"mm": "millimetres", "cm": "centimetres", "m": "metres"}
        out.append(Finding("units-guessed", "info", f"Units guessed from the size: "
                           f"{names[doc.units]}, so the brick is {size}. If that is wrong, "
                           "choose the right unit under '1. Brick model'."))
    return out


def _check_faces(doc: DesignDocument) -> list[Finding]:
    out = []
    for i, m in enumerate(doc.markers):
        label = doc.marker_label(i)
        if m.face is None:
            out.append(Finding("off-surface", "warning", f"{label.capitalize()} is not on the "
                               "model's surface: drag it onto the model or delete it.", [i]))
            continue
        if fits(doc, m):
            continue
        fixes = []
        face = doc.faces.faces[m.face]
        centred = replace(m, center=tuple(doc.faces.centre(face)))
        if fits(doc, centred) and np.linalg.norm(centred.c - m.c) > 1e-6:
            fixes.append(Fix(f"Move {label} to the centre of its face",
                             {"op": "centre_marker", "marker": i}))
        s = fit_size(doc, m)
        if s is not None and s < m.size:
            fixes.append(Fix(f"Make {label} {_mm(s)} (fits here)",
                             {"op": "set_size", "marker": i, "size": s}))
        what = "code" if m.kind == "aruco" else "dot"
        across = "wide" if m.kind == "aruco" else "across"
        out.append(Finding("overhang", "warning", f"{label.capitalize()} is {_mm(m.size)} "
                           f"{across} and hangs over the edge of its face: a {what} folded over "
                           "an edge is not flat and will be misread. Move it, or make it "
                           "smaller.", [i], fixes))
    return out


def _check_overlaps(doc: DesignDocument) -> list[Finding]:
    out = []
    ms = doc.markers
    for i in range(len(ms)):
        for j in range(i + 1, len(ms)):
            if markers_overlap(ms[i], ms[j]):
                out.append(Finding("overlap", "warning", f"{doc.marker_label(i).capitalize()} "
                                   f"and {doc.marker_label(j)} overlap: move one of them apart "
                                   "(or make them smaller).", [i, j]))
    return out


def _check_dots(doc: DesignDocument) -> list[Finding]:
    dots = doc.dots()
    if not dots:
        return _no_dots_findings(doc)
    bricks = doc.brick_markers()
    idx = [i for i, _ in dots]
    bdots = [bricks[i] for i in idx]
    if len(bdots) >= 4:
        off = _off_plane_dot(doc, idx, bdots)
        if off is not None:
            return [off]
    if len(bdots) < 4:
        return [_few_dots(doc, idx, bdots)]
    return _dot_symmetry_findings(doc, idx, bdots)


def _no_dots_findings(doc: DesignDocument) -> list[Finding]:
    if doc.symmetry != "rot180_z":
        return []
    return [Finding("symmetry-wrong", "error", "The layout is marked symmetric "
                    "(half-turn) but has no dots: mark it not symmetric.",
                    fixes=[Fix("Mark as not symmetric",
                               {"op": "set_symmetry", "value": "none"})])]


def _off_plane_dot(doc: DesignDocument, idx: list[int], bdots: list[DesignMarker]
                   ) -> Finding | None:
    """The dot farthest from the dots' plane when beyond the layout's tolerance (brick
    frame, metres)."""
    k, off = plane_outlier(np.array([m.center for m in bdots]))
    if not off > DOT_COPLANAR_TOL_M:
        return None
    i = idx[k]
    return Finding("dots-not-coplanar", "error", f"{doc.marker_label(i).capitalize()}"
                   f" is {off * 1000:.0f} mm off the plane of the other dots: "
                   "the dot detector needs all dots on one flat surface. Move it "
                   "onto the same face as the others, or delete it.", [i],
                   [Fix(f"Delete {doc.marker_label(i)}",
                        {"op": "delete_marker", "marker": i})])


def _few_dots(doc: DesignDocument, idx: list[int], bdots: list[DesignMarker]) -> Finding:
    # the dot detector refuses such a layout outright, codes or not
    return Finding("dots-few", "error", f"Only {len(bdots)} dot(s): the drone needs "
                   "at least 4 dots on one face to find the brick's position and "
                   "turn. Add more dots (the thesis used 6: two rows of 3)"
                   + (", or delete the dots and rely on the codes." if doc.codes()
                      else "."), idx,
                   [Fix("Delete the dots (keep the codes)",
                        {"op": "delete_markers", "markers": idx})]
                   if doc.codes() else [])


def _dot_symmetry_findings(doc: DesignDocument, idx: list[int], bdots: list[DesignMarker]
                           ) -> list[Finding]:
    angles = dot_symmetries(bdots)
    about_z = rot180_z_symmetric(bdots)
    if doc.symmetry == "rot180_z" and not about_z:
        return [Finding("symmetry-wrong", "error", "The layout is marked symmetric "
                        "(half-turn about the brick's z axis) but the dots do not look the "
                        "same after that half-turn: mark it not symmetric.", idx,
                        [Fix("Mark as not symmetric", {"op": "set_symmetry", "value": "none"})])]
    others = [a for a in angles if not (doc.symmetry == "rot180_z" and abs(a - 180) < 1)]
    if not angles:
        return []
    if not others:
        return [Finding("symmetric-declared", "info", "The dot pattern is symmetric and the "
                        "layout says so: from the dots alone the yaw is known only up to a "
                        "half-turn (180 deg)." + (" The codes tell the two ends apart."
                                                  if doc.codes() else ""))]
    return [_symmetric_dots(doc, idx, bdots, others, about_z)]


def _symmetry_fixes(doc: DesignDocument, idx: list[int], bdots: list[DesignMarker],
                    others: list[float], about_z: bool) -> list[Fix]:
    fixes = []
    swap = symmetry_breaking_colour(bdots, list(doc.palette()))
    if swap is not None:
        k, colour = swap
        i = idx[k]
        fixes.append(Fix(f"Make {doc.marker_label(i)} {colour} (breaks the symmetry)",
                         {"op": "set_color", "marker": i, "color": colour}))
    if about_z and others == [180.0] and doc.symmetry != "rot180_z":
        fixes.append(Fix("Keep the pattern and mark the layout as symmetric",
                         {"op": "set_symmetry", "value": "rot180_z"}))
    return fixes


def _symmetric_dots(doc: DesignDocument, idx: list[int], bdots: list[DesignMarker],
                    others: list[float], about_z: bool) -> Finding:
    """The dots look the same after the turns ``others`` (degrees) the layout does not
    declare: an error when the layout model would refuse it, else a warning."""
    turns = ", ".join(f"{a:g} deg" for a in others)
    fixes = _symmetry_fixes(doc, idx, bdots, others, about_z)
    refuses = about_z and doc.symmetry == "none" and not doc.codes()
    if 180.0 in others:
        what = ("so from the dots the drone cannot tell the brick's two ends apart: its turn "
                "(yaw) is ambiguous by 180 deg")
    else:
        what = f"so its turn (yaw) is ambiguous by {turns}"
    return Finding("symmetric-dots", "error" if refuses else "warning",
                   f"The dot pattern looks the same after a turn of {turns}, {what}. "
                   "Change one dot's colour to break the symmetry"
                   + (", or mark the layout as symmetric." if about_z else
                      " (the layout file can only declare a half-turn about the brick's "
                      "z axis through its origin).")
                   + (" The codes still give the full turn when they are seen."
                      if doc.codes() else ""), idx, fixes)


def _check_ids(doc: DesignDocument) -> list[Finding]:
    out: list[Finding] = []
    codes = doc.codes()
    if not codes:
        return out
    block = doc.id_block()
    idx = [i for i, _ in codes]
    slots = sorted(m.code_slot for _, m in codes)
    ipi = doc.effective_ids_per_instance()
    if slots[-1] >= ipi:
        out.append(Finding("ids-slots", "error", f"Code slots go up to {slots[-1]} but each "
                           f"brick has only {ipi} id(s): raise 'ids per brick' to "
                           f"{slots[-1] + 1} or use automatic.", idx,
                           [Fix("Use automatic ids per brick",
                                {"op": "set_ids_per_instance", "value": None})]))
    if doc.dictionary() is None:
        out.append(Finding("ids-too-many", "error", f"The codes need ids {block.start} to "
                           f"{block.stop - 1}, more than this code family has. Make fewer "
                           "bricks, use a lower first id, or choose a family with more codes "
                           "(5x5, 6x6, 7x7).", idx))
    for block_o, name in doc.taken_blocks():
        lo, hi = max(block.start, block_o.start), min(block.stop, block_o.stop)
        if lo < hi:
            free = doc.free_first_id()
            out.append(Finding("ids-clash", "error", f"Ids {lo}..{hi - 1} are already used by "
                               f"the layout '{name}' ({block_o.start}..{block_o.stop - 1}): the "
                               "drone could not tell those bricks apart. Use another first id.",
                               idx, [Fix(f"Use first id {free} (free)",
                                         {"op": "set_first_id", "value": free})]))
    return out


def _check_range(doc: DesignDocument, camera: Camera) -> list[Finding]:
    out = []
    f = min(camera.fx, camera.fy)
    groups: dict[tuple[str, float], list[int]] = {}
    for i, m in enumerate(doc.markers):
        groups.setdefault((m.kind, round(m.size, 4)), []).append(i)
    for (kind, size), idx in sorted(groups.items()):
        d = max_detection_distance(size, camera, kind)
        name = "Codes" if kind == "aruco" else "Dots"
        px = MIN_CODE_PX if kind == "aruco" else MIN_DOT_PX
        edge = max_detection_distance(size, camera, kind, where="edge")
        at_edge = (f" At the edge of this {camera.model.replace('_', ' ')} lens's picture: "
                   f"about {_m(edge)}." if edge < 0.85 * d else "")
        base = (f"{name} of {_mm(size)}: seen up to about {_m(d)} away with this camera "
                f"({camera.name}, {camera.width}x{camera.height}, fx = {f:.0f} px; a "
                f"{'code' if kind == 'aruco' else 'dot'} must span at least {px:g} pixels; "
                "less when seen at an angle)." + at_edge)
        if d < WORKING_DISTANCE_M:
            need = WORKING_DISTANCE_M * px / f
            out.append(Finding("range-short", "warning", base + f" That is closer than the "
                               f"{WORKING_DISTANCE_M:g} m the drone works from: make them at "
                               f"least {_mm(math.ceil(need * 1000) / 1000)}.", idx))
        else:
            out.append(Finding("range", "info", base, idx))
    return out


# ------------------------------------------------------------------------------ fixes


def _delete_markers(doc: DesignDocument, action: dict[str, Any]) -> None:
    gone = sorted({int(i) for i in action["markers"]}, reverse=True)
    if not gone:
        raise ValueError("nothing to delete")
    for i in gone:          # from the last, so that the others keep their index
        doc.delete_marker(i)


def _optional_int(v: Any) -> int | None:
    return None if v is None else int(v)


#: What each fix's ``op`` does to the document.
_FIX_OPS: dict[str, Callable[[DesignDocument, dict[str, Any]], None]] = {
    "set_symmetry": lambda doc, a: doc.set_layout_fields(symmetry=a["value"]),
    "set_color": lambda doc, a: doc.set_marker(int(a["marker"]), color=str(a["color"])),
    "centre_marker": lambda doc, a: doc.centre_marker(int(a["marker"])),
    "set_size": lambda doc, a: doc.set_marker(int(a["marker"]), size=float(a["size"])),
    "delete_marker": lambda doc, a: doc.delete_marker(int(a["marker"])),
    "delete_markers": _delete_markers,
    "set_first_id": lambda doc, a: doc.set_layout_fields(first_id=_optional_int(a["value"])),
    "set_ids_per_instance": lambda doc, a: doc.set_layout_fields(
        ids_per_instance=_optional_int(a["value"])),
    "set_units": lambda doc, a: doc.set_units(str(a["units"])),
}


def apply_fix(doc: DesignDocument, action: dict[str, Any]) -> None:
    """Perform a :class:`Fix` action on the document (undoable like any edit).

    Raises:
        DesignError: unknown or malformed action.
    """
    if not isinstance(action, dict) or not isinstance(action.get("op"), str):
        raise DesignError("this fix is not valid any more: reload the page")
    op = action["op"]
    fix = _FIX_OPS.get(op)
    if fix is None:
        raise DesignError(f"unknown fix {op!r}: reload the page")
    try:
        fix(doc, action)
    except (KeyError, TypeError, ValueError) as e:
        if isinstance(e, DesignError):
            raise
        raise DesignError("this fix is not valid any more: reload the page") from None

