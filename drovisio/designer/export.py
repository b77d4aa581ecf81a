"""Export a marker design: the layout JSON, a GLB to look at, true-scale print sheets.

* :func:`build_layout` - the :class:`drovisio.layout.MarkerLayout`, validated by the same
  model every other tool loads layouts with (metres, brick frame).
* :func:`save_design` - write ``NAME.json`` and ``meshes/NAME.stl`` (the mesh in the brick
  frame, metres) into a layouts folder, never overwriting silently.
* :func:`export_glb` - the mesh with the markers on it (codes with their real pattern, dots
  in their colour), viewable in any glTF viewer.
* :func:`print_sheet_pdf` / :func:`print_sheet_svg` - print sheets at **true scale**: every
  code and dot at its physical size, its id and where it goes, dashed cut lines, and a
  100 mm scale bar on every page to check the printer (print at 100 %, "Actual size").

The PDF is written directly (a few drawing operators, standard Helvetica, no extra
dependency). Its user unit is the PDF point (1/72 in) with no scaling, so a code of side
``s`` metres is a square of ``s * 1000 / 25.4 * 72`` pt.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import cast

import numpy as np
import trimesh

from drovisio.designer.checks import blocking, check_design, fit_size
from drovisio.designer.model import DesignDocument, DesignError, DesignMarker
from drovisio.fileio import atomic_write_bytes
from drovisio.layout import (
    LayoutError,
    MarkerLayout,
    aruco_code_bits,
    parse_layout,
    save_layout,
)
from drovisio.printing import A3_MM, A4_MM, MM_TO_PT, Page, Rgb, num, pdf_bytes

__all__ = ["MM_TO_PT", "A4_MM", "A3_MM", "SavedDesign", "build_layout", "save_design",
           "export_glb", "SheetItem", "sheet_items", "sheet_pages",
           "print_sheet_pdf", "print_sheet_svg", "mesh_stl_bytes"]

PAGE_MARGIN_MM = 12.0
HEADER_MM = 30.0
GAP_MM = 4.0
LABEL_MM = 8.0


# ------------------------------------------------------------------------------ layout


def build_layout(doc: DesignDocument, mesh_ref: str | None = None) -> MarkerLayout:
    """The design as a validated layout (brick frame, metres).

    Args:
        doc: the design.
        mesh_ref: the layout's ``mesh`` field (relative to where the JSON will be saved);
            default ``meshes/NAME.stl``.

    Raises:
        DesignError: the layout model refuses it (the message lists every problem).
    """
    ref = mesh_ref if mesh_ref is not None else f"meshes/{doc.name}.stl"
    try:
        return parse_layout(doc.layout_data(ref), f"layout {doc.name!r}")
    except LayoutError as e:
        raise DesignError("The layout is not valid yet:\n" + "\n".join(e.issues)) from None


def mesh_stl_bytes(doc: DesignDocument) -> bytes:
    """The mesh in the brick frame, metres, as binary STL."""
    return cast(bytes, doc.brick_mesh().export(file_type="stl"))


@dataclass
class SavedDesign:
    layout_path: Path
    mesh_path: Path
    layout: MarkerLayout


def _write_new(path: Path, data: bytes, overwrite: bool) -> None:
    try:
        atomic_write_bytes(path, data, overwrite=overwrite, mode=0o644)
    except FileExistsError:
        raise DesignError(f"{path} already exists: choose another name, or tick "
                          "'Replace existing files'.") from None


def save_design(doc: DesignDocument, folder: str | os.PathLike[str], overwrite: bool = False,
                ) -> SavedDesign:
    """Save ``NAME.json`` and ``meshes/NAME.stl`` into a layouts folder.

    Nothing is written when the design has errors (see :func:`drovisio.designer.checks
    .check_design`) or when a file exists and ``overwrite`` is False (a mesh file with the
    very same content is reused).

    Raises:
        DesignError: errors in the design, an existing file, or a folder that cannot be
            written; the message says what to do.
    """
    errors = blocking(check_design(doc))
    if errors:
        raise DesignError("Fix these problems first:\n" + "\n".join(f.message for f in errors))
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", doc.name):
        raise DesignError(f"the name {doc.name!r} cannot be a file name: use letters, digits, "
                          "'-', '_' and '.' only")
    folder = Path(folder)
    if not folder.is_dir():
        raise DesignError(f"the layouts folder {folder} does not exist")
    layout_path = folder / f"{doc.name}.json"
    mesh_rel = f"meshes/{doc.name}.stl"
    mesh_path = folder / mesh_rel
    layout = build_layout(doc, mesh_rel)
    stl = mesh_stl_bytes(doc)
    if not overwrite:
        if layout_path.exists():
            raise DesignError(f"A layout named '{doc.name}' already exists ({layout_path}): "
                              "choose another name, or tick 'Replace existing files'.")
        if mesh_path.exists() and mesh_path.read_bytes() != stl:
            raise DesignError(f"A different mesh file {mesh_path} already exists: choose "
                              "another name, or tick 'Replace existing files'.")
    try:
        mesh_path.parent.mkdir(exist_ok=True)
        if overwrite or not mesh_path.exists():
            _write_new(mesh_path, stl, overwrite)
        save_layout(layout, layout_path, overwrite=overwrite)
    except LayoutError as e:
        raise DesignError(str(e)) from None
    except PermissionError as e:
        raise DesignError(f"cannot write into {folder}: {e.strerror}") from None
    return SavedDesign(layout_path, mesh_path, layout)


# ------------------------------------------------------------------------------ codes


def code_image_rgb(dictionary: str, marker_id: int, px_per_cell: int = 16,
                   margin_cells: float = 0.0) -> np.ndarray:
    """The code as an RGB uint8 image (for textures), optionally with a white margin."""
    bits = aruco_code_bits(dictionary, marker_id)
    img = np.kron(bits, np.ones((px_per_cell, px_per_cell), np.uint8)) * 255
    m = int(round(margin_cells * px_per_cell))
    if m:
        img = np.pad(img, m, constant_values=255)
    return np.repeat(img[:, :, None], 3, axis=2)


# ------------------------------------------------------------------------------ GLB


def _quad(c: np.ndarray, r: np.ndarray, u: np.ndarray, x0: float, x1: float, y0: float,
          y1: float) -> np.ndarray:
    """(4, 3) corners of the rectangle [x0, x1] x [y0, y1] on the plane through ``c``
    spanned by ``r`` and ``u``."""
    return np.array([c + r * x0 + u * y0, c + r * x1 + u * y0, c + r * x1 + u * y1,
                     c + r * x0 + u * y1])


def _quads_mesh(quads: list[np.ndarray], colors: list[tuple[int, int, int]]) -> trimesh.Trimesh:
    V = np.concatenate(quads) if quads else np.zeros((0, 3))
    F = []
    C = []
    for k, col in enumerate(colors):
        b = 4 * k
        F += [[b, b + 1, b + 2], [b, b + 2, b + 3]]
        C += [list(col) + [255]] * 4
    return trimesh.Trimesh(V, np.array(F, np.int64).reshape(-1, 3),
                           vertex_colors=np.array(C, np.uint8).reshape(-1, 4), process=False)


def marker_geometry(m: DesignMarker, dictionary: str | None, marker_id: int | None,
                    rgb: tuple[int, int, int] | None, lift: float = 0.0004,
                    segments: int = 48) -> trimesh.Trimesh:
    """A marker as a coloured surface mesh, lifted ``lift`` off its face along the normal:
    a code's white paper margin and its black/white cells, or a dot's disc."""
    c, r, u, n = m.c + m.n * lift, m.r, m.u, m.n
    h = m.size / 2
    if m.kind == "aruco":
        assert dictionary is not None and marker_id is not None
        bits = aruco_code_bits(dictionary, marker_id)
        k = bits.shape[0]
        cs = m.size / k
        quads = [_quad(c - n * lift * 0.25, r, u, -h - cs * 0.4, h + cs * 0.4, -h - cs * 0.4,
                       h + cs * 0.4)]
        cols = [(245, 245, 245)]
        for i in range(k):
            for j in range(k):
                if bits[i, j]:
                    continue
                x0 = -h + j * cs
                y1 = h - i * cs
                quads.append(_quad(c, r, u, x0, x0 + cs, y1 - cs, y1))
                cols.append((15, 15, 15))
        return _quads_mesh(quads, cols)
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = c + np.outer(np.cos(ang), r) * h + np.outer(np.sin(ang), u) * h
    V = np.vstack([c, ring])
    F = [[0, 1 + i, 1 + (i + 1) % segments] for i in range(segments)]
    col = list(rgb or (200, 40, 40)) + [255]
    return trimesh.Trimesh(V, np.array(F), vertex_colors=np.array([col] * len(V), np.uint8),
                           process=False)


def export_glb(doc: DesignDocument, instance: int = 0) -> bytes:
    """The mesh (brick frame, metres) with the markers on it, as GLB bytes. Codes carry the
    ids of brick ``instance``."""
    scene = trimesh.Scene()
    body = doc.brick_mesh()
    body.visual = trimesh.visual.ColorVisuals(body, vertex_colors=np.tile(
        np.array([170, 172, 176, 255], np.uint8), (len(body.vertices), 1)))
    scene.add_geometry(body, geom_name="brick")
    dictionary = doc.dictionary()
    first = doc.effective_first_id() if doc.codes() else 0
    ipi = doc.effective_ids_per_instance()
    pal = doc.palette()
    for i, m in enumerate(doc.brick_markers()):
        if m.kind == "aruco":
            if dictionary is None:
                continue
            g = marker_geometry(m, dictionary, first + instance * ipi + m.code_slot, None)
        else:
            g = marker_geometry(m, None, None, pal[m.dot_color].display_rgb())
        scene.add_geometry(g, geom_name=f"marker-{i}-{doc.marker_label(i).replace(' ', '-')}")
    return scene.export(file_type="glb")


# ------------------------------------------------------------------------------ sheets


@dataclass
class SheetItem:
    """One marker to print: ``kind`` aruco/dot, ``size`` metres, ``margin`` metres of white
    paper kept around a code inside its cut line, a label and, for codes, the id."""

    kind: str
    size: float
    label: str
    detail: str
    marker_id: int | None = None
    dictionary: str | None = None
    rgb: tuple[int, int, int] | None = None
    margin: float = 0.0


def _axis_name(v: np.ndarray) -> str:
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) > 0.97:
        return ("+" if v[k] > 0 else "-") + "xyz"[k]
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def sheet_items(doc: DesignDocument, instances: list[int] | None = None,
                dot_sets: int = 1) -> list[SheetItem]:
    """What a print sheet holds: every code of the chosen brick instances (default all) and
    ``dot_sets`` sets of dots."""
    bm = doc.brick_markers()
    codes = sorted(((i, m) for i, m in enumerate(bm) if m.kind == "aruco"),
                   key=lambda t: t[1].code_slot)
    items = _code_items(doc, codes, instances) if codes else []
    pal = doc.palette()
    dots = [(i, m) for i, m in enumerate(bm) if m.kind == "dot"]
    for _ in range(max(0, dot_sets)):
        for k, (_, m) in enumerate(dots, start=1):
            pos = ", ".join(f"{v * 1000:.0f}" for v in m.center)
            items.append(SheetItem("dot", m.size, f"dot {k} {m.color}",
                                   f"Ø {m.size * 1000:g} mm · at ({pos}) mm",
                                   rgb=pal[m.dot_color].display_rgb()))
    return items


def _code_items(doc: DesignDocument, codes: list[tuple[int, DesignMarker]],
                instances: list[int] | None) -> list[SheetItem]:
    """The codes (brick frame, by slot) of the chosen brick instances (default all)."""
    dictionary = doc.dictionary()
    if dictionary is None:
        raise DesignError("the codes need more ids than their family has: fix the ids "
                          "first (see the checks)")
    first, ipi = doc.effective_first_id(), doc.effective_ids_per_instance()
    ks = list(range(doc.instances)) if instances is None else list(instances)
    for k in ks:
        if not 0 <= k < doc.instances:
            raise DesignError(f"brick number {k} is outside 0..{doc.instances - 1}")
    margins = _code_margins(doc, codes, aruco_code_bits(dictionary, 0).shape[0])
    items: list[SheetItem] = []
    for k in ks:
        for i, m in codes:
            mid = first + k * ipi + m.code_slot
            pos = ", ".join(f"{v * 1000:.0f}" for v in m.center)
            items.append(SheetItem(
                "aruco", m.size, f"id {mid}",
                f"brick {k} slot {m.slot} · {m.size * 1000:g} mm · at ({pos}) mm · "
                f"top edge toward {_axis_name(m.u)}",
                marker_id=mid, dictionary=dictionary, margin=margins[i]))
    return items


def _code_margins(doc: DesignDocument, codes: list[tuple[int, DesignMarker]], cells: int
                  ) -> dict[int, float]:
    """White paper kept around each code (metres, by marker index): one cell (at most
    10 mm), less if the face is smaller."""
    margins = {}
    for i, m in codes:
        cell = min(m.size / cells, 0.01)
        margin = cell
        fm = doc.markers[i]
        if fm.face is not None:
            s = fit_size(doc, replace(fm, size=m.size + 2 * cell), min_size=m.size)
            margin = max((s - m.size) / 2, 0.001) if s is not None else 0.001
            margin = min(margin, cell)
        margins[i] = margin
    return margins


def _header(page: Page, title: str, note: str, number: int, total_hint: str) -> float:
    x0 = PAGE_MARGIN_MM
    y = PAGE_MARGIN_MM + 5
    page.ops.append(("text", x0, y, 13, title, True))
    page.ops.append(("text", page.width - PAGE_MARGIN_MM, y, 9, f"page {number}{total_hint}",
                     False, "end"))
    y += 5
    page.ops.append(("text", x0, y, 8.5, "Print at 100 % ('Actual size' - not 'Fit to page'). "
                     "Check with a ruler: the black bar must be exactly 100 mm long.", False))
    y += 4
    page.ops.append(("text", x0, y, 8.5, note, False))
    y += 3
    # 100 mm scale bar: a filled black bar with 10 mm ticks under it.
    page.ops.append(("rect", x0, y, 100.0, 2.5, (0, 0, 0), None, None, 0))
    for k in range(11):
        tick = 3.0 if k % 5 == 0 else 1.8
        page.ops.append(("line", x0 + 10 * k, y + 2.5, x0 + 10 * k, y + 2.5 + tick, (0, 0, 0),
                         0.25, None))
    page.ops.append(("text", x0, y + 9, 7.5, "0", False))
    page.ops.append(("text", x0 + 100, y + 9, 7.5, "100 mm", False, "middle"))
    page.ops.append(("text", x0 + 106, y + 2.6, 8, "<- 100 mm scale bar", False))
    return y + 13


def _draw_item(page: Page, it: SheetItem, x: float, y: float) -> None:
    """Draw an item whose cut box's top-left corner is at (x, y) mm."""
    s = it.size * 1000
    mg = it.margin * 1000
    box = s + 2 * mg
    grey = (0.45, 0.45, 0.45)
    if it.kind == "aruco":
        page.ops.append(("rect", x, y, box, box, None, grey, (2.0, 1.5), 0.2))  # cut line
        bx, by = x + mg, y + mg
        page.ops.append(("rect", bx, by, s, s, (0, 0, 0), None, None, 0))  # the code square
        bits = aruco_code_bits(it.dictionary, it.marker_id)
        k = bits.shape[0]
        cs = s / k
        for i in range(k):
            j = 0
            while j < k:
                if bits[i, j]:
                    j0 = j
                    while j < k and bits[i, j]:
                        j += 1
                    page.ops.append(("rect", bx + j0 * cs, by + i * cs, (j - j0) * cs, cs,
                                     (1, 1, 1), None, None, 0))
                else:
                    j += 1
    else:
        r = s / 2
        cx, cy = x + r, y + r
        col = tuple(c / 255 for c in it.rgb or (200, 40, 40))
        page.ops.append(("circle", cx, cy, r, col, None, None, 0))
        page.ops.append(("circle", cx, cy, r, None, grey, (2.0, 1.5), 0.2))  # cut line
        box = s
    page.ops.append(("text", x, y + box + 3.6, 8.5, it.label, True))
    page.ops.append(("text", x, y + box + 7.0, 6.5, it.detail, False))


class _Sheets:
    """Pages being filled with items, left to right then row by row (millimetres)."""

    def __init__(self, title: str, note: str):
        self.title, self.note = title, note
        self.pages: list[Page] = []
        self.page: Page | None = None  # the A4 page being filled
        self.x = self.y = self.row_h = 0.0

    def new_page(self, w: float, h: float) -> tuple[Page, float]:
        """A new page with its header; returns it and the top of its free area."""
        p = Page(w, h)
        y = _header(p, self.title, self.note, len(self.pages) + 1, "")
        self.pages.append(p)
        return p, y

    def place_big(self, it: SheetItem, need_w: float, need_h: float) -> None:
        """An item too big for A4: on an A3 page, or a page of its own size."""
        if need_w <= A3_MM[0] - 2 * PAGE_MARGIN_MM and \
                need_h <= A3_MM[1] - 2 * PAGE_MARGIN_MM - HEADER_MM:
            w, h = A3_MM
        else:
            w = max(need_w + 2 * PAGE_MARGIN_MM, 130.0)
            h = need_h + 2 * PAGE_MARGIN_MM + HEADER_MM
        big, by = self.new_page(w, h)
        _draw_item(big, it, PAGE_MARGIN_MM, by)
        size_name = "A3" if (w, h) == A3_MM else f"{w:.0f} x {h:.0f} mm (bigger than A3)"
        big.ops.append(("text", PAGE_MARGIN_MM, h - 4, 8, f"This page is {size_name}: print "
                        "it at 100 % on paper that large (a print shop), or as poster "
                        "tiles at 100 % taped together.", True))
        self.page = None

    def place(self, it: SheetItem, need_w: float, need_h: float) -> None:
        """An item on the current A4 page: next in the row, on a new row, or a new page."""
        if self.page is None or self.page.width != A4_MM[0]:
            self.page, self.y = self.new_page(*A4_MM)
            self.x, self.row_h = PAGE_MARGIN_MM, 0.0
        if self.x + need_w > A4_MM[0] - PAGE_MARGIN_MM + 1e-9:
            self.x = PAGE_MARGIN_MM
            self.y += self.row_h + GAP_MM
            self.row_h = 0.0
        if self.y + need_h > A4_MM[1] - PAGE_MARGIN_MM + 1e-9:
            self.page, self.y = self.new_page(*A4_MM)
            self.x, self.row_h = PAGE_MARGIN_MM, 0.0
        _draw_item(self.page, it, self.x, self.y)
        label_w = max(len(it.detail) * 6.5 * 0.5 * 25.4 / 72, len(it.label) * 8.5 * 0.55
                      * 25.4 / 72)
        self.x += max(need_w, min(label_w, A4_MM[0] - 2 * PAGE_MARGIN_MM)) + GAP_MM
        self.row_h = max(self.row_h, need_h)


def _number_pages(pages: list[Page]) -> None:
    """Turn each header's "page n" into "page n of N"."""
    total = len(pages)
    for p in pages:
        for k, op in enumerate(p.ops):
            if op[0] == "text" and op[4].startswith("page ") and len(op) > 6:
                p.ops[k] = op[:4] + (f"{op[4]} of {total}",) + op[5:]


def sheet_pages(doc: DesignDocument, instances: list[int] | None = None,
                dot_sets: int = 1) -> list[Page]:
    """Lay the items out on pages (A4 portrait; an item too big for A4 gets an A3 page, or a
    page of its own size)."""
    items = sheet_items(doc, instances, dot_sets)
    if not items:
        raise DesignError("nothing to print: add codes or dots first")
    dictionary = doc.dictionary() if doc.codes() else None
    note = (f"Cut along the dashed lines. Codes: {dictionary}, glue each one flat with its "
            "top edge as written under it." if dictionary else
            "Cut along the dashed lines (or use the discs as painting templates).")
    sheets = _Sheets(f"Drovisio markers - {doc.name}", note)
    aw = A4_MM[0] - 2 * PAGE_MARGIN_MM
    ah = A4_MM[1] - 2 * PAGE_MARGIN_MM - HEADER_MM
    for it in items:
        box = it.size * 1000 + 2 * it.margin * 1000
        need_w, need_h = box, box + LABEL_MM
        if need_w > aw or need_h > ah:
            sheets.place_big(it, need_w, need_h)
        else:
            sheets.place(it, need_w, need_h)
    _number_pages(sheets.pages)
    return sheets.pages


# ---- PDF


def print_sheet_pdf(doc: DesignDocument, instances: list[int] | None = None,
                    dot_sets: int = 1) -> bytes:
    """The print sheet as PDF bytes (true scale; see the module docstring)."""
    return pdf_bytes(sheet_pages(doc, instances, dot_sets), title="Drovisio markers - " + doc.name,
                     producer="Drovisio marker designer")


# ---- SVG


def _xml(text: str) -> str:
    return (text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            .replace('"', "&quot;"))


def print_sheet_svg(doc: DesignDocument, page: int = 1, instances: list[int] | None = None,
                    dot_sets: int = 1) -> str:
    """One page (1-based) of the print sheet as SVG text, in millimetres (true scale:
    ``width="210mm"`` with a viewBox in mm)."""
    pages = sheet_pages(doc, instances, dot_sets)
    if not 1 <= page <= len(pages):
        raise DesignError(f"the print sheet has {len(pages)} page(s); page {page} does not "
                          "exist")
    p = pages[page - 1]
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{num(p.width)}mm" '
           f'height="{num(p.height)}mm" viewBox="0 0 {num(p.width)} {num(p.height)}" '
           f'data-pages="{len(pages)}">',
           f'<title>{_xml("Drovisio markers - " + doc.name)} (page {page} of '
           f'{len(pages)})</title>',
           f'<rect x="0" y="0" width="{num(p.width)}" height="{num(p.height)}" fill="#fff"/>']

    def col(c: Rgb | None) -> str:
        return "none" if c is None else "#" + "".join(f"{int(round(v * 255)):02x}" for v in c)

    def stroke_attrs(stroke: Rgb | None, dash: Sequence[float] | None, lw: float) -> str:
        if stroke is None:
            return ""
        s = f' stroke="{col(stroke)}" stroke-width="{num(lw)}"'
        if dash:
            s += f' stroke-dasharray="{" ".join(num(d) for d in dash)}"'
        return s

    for op in p.ops:
        kind = op[0]
        if kind == "rect":
            _, x, y, w, h, fill, stroke, dash, lw = op
            cls = ' class="code"' if fill == (0, 0, 0) and abs(w - h) < 1e-9 else ""
            out.append(f'<rect{cls} x="{num(x)}" y="{num(y)}" width="{num(w)}" height="{num(h)}" '
                       f'fill="{col(fill)}"{stroke_attrs(stroke, dash, lw)}'
                       + (' shape-rendering="crispEdges"' if fill is not None else "") + "/>")
        elif kind == "circle":
            _, cx, cy, r, fill, stroke, dash, lw = op
            out.append(f'<circle cx="{num(cx)}" cy="{num(cy)}" r="{num(r)}" fill="{col(fill)}"'
                       f'{stroke_attrs(stroke, dash, lw)}/>')
        elif kind == "line":
            _, x1, y1, x2, y2, stroke, lw, dash = op
            out.append(f'<line x1="{num(x1)}" y1="{num(y1)}" x2="{num(x2)}" y2="{num(y2)}"'
                       f'{stroke_attrs(stroke, dash, lw)}/>')
        elif kind == "text":
            x, y, size, text, bold = op[1:6]
            anchor = op[6] if len(op) > 6 else "start"
            out.append(f'<text x="{num(x)}" y="{num(y)}" font-family="Helvetica, Arial, '
                       f'sans-serif" font-size="{num(size * 25.4 / 72)}"'
                       + (' font-weight="bold"' if bold else "")
                       + (f' text-anchor="{anchor}"' if anchor != "start" else "")
                       + f">{_xml(text)}</text>")
    out.append("</svg>")
    return "\n".join(out) + "\n"
