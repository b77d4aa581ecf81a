"""True-scale print pages: a page is a list of drawing operations in millimetres (y down, as on
paper), written as PDF (vector, Helvetica) by :func:`pdf_bytes`. Used by the marker designer's
print sheets and the calibration board printout: what is drawn 25 mm wide measures 25 mm on
paper printed at 100 %.

Operations (tuples): ``("rect", x, y, w, h, fill, stroke, dash, line_width)``,
``("circle", cx, cy, r, fill, stroke, dash, line_width)``,
``("line", x1, y1, x2, y2, stroke, line_width, dash)``,
``("text", x, y, size_pt, text, bold[, anchor])`` — colours are RGB in 0..1 or None.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass, field

__all__ = ["MM_TO_PT", "A4_MM", "A3_MM", "LETTER_MM", "Rgb", "Page", "num", "pdf_bytes"]

MM_TO_PT = 72.0 / 25.4
A4_MM = (210.0, 297.0)
A3_MM = (297.0, 420.0)
LETTER_MM = (215.9, 279.4)

#: A colour of an operation: red, green, blue in 0..1.
Rgb = tuple[float, float, float]


@dataclass
class Page:
    """One page: its size in millimetres and its drawing operations (module doc)."""

    width: float
    height: float
    ops: list[tuple] = field(default_factory=list)


def _pdf_str(text: str) -> bytes:
    raw = text.encode("cp1252", errors="replace")
    return b"(" + raw.replace(b"\\", b"\\\\").replace(b"(", b"\\(").replace(b")", b"\\)") + b")"


def num(v: float) -> str:
    """A number for PDF/SVG text: 4 decimals at most, no trailing zeros."""
    s = f"{v:.4f}".rstrip("0").rstrip(".")
    return s if s not in ("-0", "") else "0"


def _text_width_pt(text: str, size: float, bold: bool) -> float:
    # Helvetica's average advance is about 0.5 em (0.55 bold); good enough to centre labels.
    return len(text) * size * (0.55 if bold else 0.5)


def _pdf_page_content(p: Page) -> bytes:
    H = p.height * MM_TO_PT
    out: list[str] = []

    def X(x: float) -> str:
        return num(x * MM_TO_PT)

    def Y(y: float) -> str:
        return num(H - y * MM_TO_PT)

    def style(fill: Rgb | None, stroke: Rgb | None, dash: Sequence[float] | None,
              lw: float) -> list[str]:
        s = []
        if fill is not None:
            s.append(f"{num(fill[0])} {num(fill[1])} {num(fill[2])} rg")
        if stroke is not None:
            s.append(f"{num(stroke[0])} {num(stroke[1])} {num(stroke[2])} RG")
            s.append(f"{num(lw * MM_TO_PT)} w")
            s.append(f"[{' '.join(num(d * MM_TO_PT) for d in dash)}] 0 d" if dash else "[] 0 d")
        return s

    def paint(fill: Rgb | None, stroke: Rgb | None) -> str:
        return "B" if fill is not None and stroke is not None else ("f" if fill is not None
                                                                   else "S")

    for op in p.ops:
        kind = op[0]
        if kind == "rect":
            _, x, y, w, h, fill, stroke, dash, lw = op
            out += style(fill, stroke, dash, lw)
            out.append(f"{X(x)} {num(H - (y + h) * MM_TO_PT)} {num(w * MM_TO_PT)} "
                       f"{num(h * MM_TO_PT)} re {paint(fill, stroke)}")
        elif kind == "circle":
            _, cx, cy, r, fill, stroke, dash, lw = op
            out += style(fill, stroke, dash, lw)
            k = 0.5522847498 * r
            pts = [(cx + r, cy), (cx + r, cy + k, cx + k, cy + r, cx, cy + r),
                   (cx - k, cy + r, cx - r, cy + k, cx - r, cy),
                   (cx - r, cy - k, cx - k, cy - r, cx, cy - r),
                   (cx + k, cy - r, cx + r, cy - k, cx + r, cy)]
            out.append(f"{X(pts[0][0])} {Y(pts[0][1])} m")
            for c in pts[1:]:
                out.append(f"{X(c[0])} {Y(c[1])} {X(c[2])} {Y(c[3])} {X(c[4])} {Y(c[5])} c")
            out.append("h " + paint(fill, stroke))
        elif kind == "line":
            _, x1, y1, x2, y2, stroke, lw, dash = op
            out += style(None, stroke, dash, lw)
            out.append(f"{X(x1)} {Y(y1)} m {X(x2)} {Y(y2)} l S")
        elif kind == "text":
            x, y, size, text, bold = op[1:6]
            anchor = op[6] if len(op) > 6 else "start"
            w = _text_width_pt(text, size, bold)
            xp = x * MM_TO_PT - (w if anchor == "end" else w / 2 if anchor == "middle" else 0)
            out.append("0 0 0 rg")
            out.append(f"BT /{'F2' if bold else 'F1'} {num(size)} Tf {num(xp)} {Y(y)} Td "
                       + _pdf_str(text).decode("latin-1") + " Tj ET")
    return ("\n".join(out) + "\n").encode("latin-1")


def pdf_bytes(pages: list[Page], title: str, producer: str = "Drovisio") -> bytes:
    """The pages as one PDF document (bytes)."""
    objs: list[bytes] = []

    def add(body: bytes) -> int:
        objs.append(body)
        return len(objs)

    catalog = add(b"")  # placeholder, filled below
    pages_id = add(b"")
    f1 = add(b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica "
             b"/Encoding /WinAnsiEncoding >>")
    f2 = add(b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica-Bold "
             b"/Encoding /WinAnsiEncoding >>")
    kids = []
    for p in pages:
        content = _pdf_page_content(p)
        cid = add(f"<< /Length {len(content)} >>\nstream\n".encode() + content + b"endstream")
        pid = add((f"<< /Type /Page /Parent {pages_id} 0 R /MediaBox [0 0 "
                   f"{num(p.width * MM_TO_PT)} {num(p.height * MM_TO_PT)}] /Resources << /Font "
                   f"<< /F1 {f1} 0 R /F2 {f2} 0 R >> >> /Contents {cid} 0 R >>").encode())
        kids.append(pid)
    objs[catalog - 1] = f"<< /Type /Catalog /Pages {pages_id} 0 R >>".encode()
    objs[pages_id - 1] = (f"<< /Type /Pages /Kids [{' '.join(f'{k} 0 R' for k in kids)}] "
                          f"/Count {len(kids)} >>").encode()
    buf = io.BytesIO()
    buf.write(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for i, body in enumerate(objs, start=1):
        offsets.append(buf.tell())
        buf.write(f"{i} 0 obj\n".encode() + body + b"\nendobj\n")
    xref = buf.tell()
    buf.write(f"xref\n0 {len(objs) + 1}\n0000000000 65535 f \n".encode())
    for off in offsets:
        buf.write(f"{off:010d} 00000 n \n".encode())
    buf.write((f"trailer\n<< /Size {len(objs) + 1} /Root {catalog} 0 R /Info << /Title "
               f"{_pdf_str(title).decode('latin-1')} /Producer "
               f"{_pdf_str(producer).decode('latin-1')} >> >>\nstartxref\n{xref}\n%%EOF\n"
               ).encode("latin-1"))
    return buf.getvalue()
