"""Exports: validated layout, saving without silent overwrite, GLB, true-scale print sheets,
and the exported layout finding the brick in a render."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
import trimesh

from drovisio.designer.checks import apply_fix, check_design
from drovisio.designer.export import (
    MM_TO_PT,
    build_layout,
    export_glb,
    print_sheet_pdf,
    print_sheet_svg,
    save_design,
)
from drovisio.designer.model import DesignError
from drovisio.layout import aruco_code_bits as code_bits
from drovisio.layout import load_layout

pypdf = pytest.importorskip("pypdf")


def _fix_symmetry(doc):
    f = [x for x in check_design(doc) if x.key == "symmetric-dots"][0]
    apply_fix(doc, f.fixes[0].action)  # one dot changes colour


def test_layout_is_validated_and_in_the_brick_frame(designed):
    _fix_symmetry(designed)
    lay = build_layout(designed)
    assert lay.units == "m" and lay.mesh == f"meshes/{designed.name}.stl"
    assert (lay.first_id, lay.ids_per_instance, lay.instances) == (70, 2, 10)
    assert lay.code_dictionaries() == {0: "DICT_4X4_100", 1: "DICT_4X4_100"}
    np.testing.assert_allclose(lay.code_corners_m()[0][0], [-0.1075, 0.0325, 0.02], atol=1e-6)
    assert len(lay.dot_markers()) == 6 and lay.symmetry == "none"
    np.testing.assert_allclose(lay.dimensions_m, [0.30, 0.15, 0.12], atol=1e-6)


def test_save_never_overwrites_silently(designed, tmp_path):
    _fix_symmetry(designed)
    saved = save_design(designed, tmp_path)
    assert saved.layout_path == tmp_path / "drick.json"
    lay = load_layout(saved.layout_path)
    assert lay.mesh_path() == (tmp_path / "meshes" / "drick.stl").resolve()
    mesh = trimesh.load(lay.mesh_path(), force="mesh")
    np.testing.assert_allclose(mesh.extents, [0.30, 0.15, 0.12], atol=1e-6)
    first = saved.layout_path.read_bytes()
    designed.set_marker(0, size=0.06)
    with pytest.raises(DesignError, match="already exists.*Replace existing files"):
        save_design(designed, tmp_path)
    assert saved.layout_path.read_bytes() == first
    save_design(designed, tmp_path, overwrite=True)
    assert load_layout(saved.layout_path).code_sizes_m()[0] == pytest.approx(0.06)


def test_save_refuses_a_design_with_errors(designed, tmp_path):
    designed.set_layout_fields(first_id=20)  # clashes with a shipped layout
    with pytest.raises(DesignError, match="Fix these problems first"):
        save_design(designed, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_glb_holds_mesh_and_markers(designed):
    _fix_symmetry(designed)
    scene = trimesh.load(io.BytesIO(export_glb(designed)), file_type="glb")
    assert len(scene.geometry) == 1 + 8
    np.testing.assert_allclose(scene.bounds, [[-0.15, -0.075, -0.1], [0.15, 0.075, 0.02045]],
                               atol=2e-4)


# ------------------------------------------------------------------ print sheets


def _page_ops(page):
    from pypdf.generic import ContentStream

    return ContentStream(page.get_contents(), page.pdf).operations


def black_squares_pt(page) -> list[tuple[float, float]]:
    """(width, height) in pt of every black-filled rectangle of a PDF page, read from its
    content stream (no transformation matrix may scale them)."""
    fill = (0.0, 0.0, 0.0)
    pending: list[tuple[float, float]] = []
    out = []
    for operands, op in _page_ops(page):
        if op == b"cm":
            raise AssertionError("the sheet must not scale its drawing (no cm operator)")
        if op == b"rg":
            fill = tuple(float(v) for v in operands)
        elif op == b"g":
            fill = (float(operands[0]),) * 3
        elif op == b"re":
            pending.append((float(operands[2]), float(operands[3])))
        elif op in (b"f", b"F", b"f*", b"B", b"b"):
            if fill == (0.0, 0.0, 0.0):
                out += pending
            pending = []
        elif op in (b"S", b"n", b"s"):
            pending = []
    return out


def test_pdf_codes_are_true_scale(designed):
    _fix_symmetry(designed)
    designed.set_marker(1, size=0.05)  # two code sizes on the sheet
    designed.set_layout_fields(instances=4)
    reader = pypdf.PdfReader(io.BytesIO(print_sheet_pdf(designed)))
    assert len(reader.pages) >= 1
    sizes = []
    bars = []
    for page in reader.pages:
        w, h = float(page.mediabox.width), float(page.mediabox.height)
        assert w == pytest.approx(210 * MM_TO_PT, rel=1e-6) and \
            h == pytest.approx(297 * MM_TO_PT, rel=1e-6)
        for rw, rh in black_squares_pt(page):
            if abs(rw - rh) <= 1e-6 * rw:
                sizes.append(rw)
            else:
                bars.append(rw)
    want = sorted([0.065 / 0.0254 * 72] * 4 + [0.05 / 0.0254 * 72] * 4)  # 4 bricks x 2 codes
    assert len(sizes) == len(want)
    for got, exp in zip(sorted(sizes), want, strict=True):
        assert abs(got - exp) / exp < 1e-3  # within 0.1 %
    # the 100 mm scale bar on every page
    assert len(bars) == len(reader.pages)
    for b in bars:
        assert abs(b - 100 / 25.4 * 72) / (100 / 25.4 * 72) < 1e-3
    text = "".join(p.extract_text() for p in reader.pages)
    for mid in (70, 71, 76, 77):
        assert f"id {mid}" in text
    assert "100 mm" in text and "Actual size" in text
    for k in range(1, 7):
        assert f"dot {k}" in text


def test_pdf_code_pattern_reads_back(designed):
    """The white cells drawn over each black square reproduce the code's bits."""
    _fix_symmetry(designed)
    designed.set_layout_fields(instances=1)
    page = pypdf.PdfReader(io.BytesIO(print_sheet_pdf(designed))).pages[0]
    rects = []
    fill = None
    for operands, op in _page_ops(page):
        if op == b"rg":
            fill = tuple(float(v) for v in operands)
        elif op == b"re":
            rects.append((fill, [float(v) for v in operands]))
    black = [r for f, r in rects if f == (0.0, 0.0, 0.0) and abs(r[2] - r[3]) < 1e-6]
    x0, y0, s, _ = black[0]  # code id 70
    n = code_bits("DICT_4X4_100", 70).shape[0]
    cs = s / n
    grid = np.zeros((n, n), np.uint8)
    for f, (x, y, w, h) in rects:
        if f != (1.0, 1.0, 1.0) or not (x0 - 1e-6 <= x < x0 + s and y0 - 1e-6 <= y < y0 + s):
            continue
        row = int(round((y0 + s - (y + h)) / cs))  # PDF y grows upward
        for col in range(int(round((x - x0) / cs)), int(round((x + w - x0) / cs))):
            grid[row, col] = 1
    np.testing.assert_array_equal(grid, code_bits("DICT_4X4_100", 70))


def test_svg_page_is_true_scale(designed):
    _fix_symmetry(designed)
    svg = print_sheet_svg(designed, 1)
    assert 'width="210mm" height="297mm" viewBox="0 0 210 297"' in svg
    squares = [float(m) for m in re.findall(r'<rect class="code" [^>]*width="([0-9.]+)"', svg)]
    assert squares and all(abs(s - 65.0) < 1e-3 for s in squares)
    assert re.search(r'<rect x="[0-9.]+" y="[0-9.]+" width="100" height="2.5" fill="#000000"',
                     svg)
    pages = int(re.search(r'data-pages="(\d+)"', svg).group(1))
    with pytest.raises(DesignError, match="does not exist"):
        print_sheet_svg(designed, pages + 1)


# ------------------------------------------------------------------ end to end (no browser)


def test_exported_layout_finds_the_brick_in_a_render(designed, tmp_path):
    """The saved layout + its mesh, rendered by drovisio.synth, are found again by the code
    detector and the dot detector with the true pose (the browser test repeats this on the
    layout the page saves)."""
    from drovisio.designer.verify import verify_layout

    _fix_symmetry(designed)
    saved = save_design(designed, tmp_path)
    results, image = verify_layout(load_layout(saved.layout_path), instance=3)
    assert image.shape == (480, 640, 3)
    by = {r.method: r for r in results}
    assert set(by) == {"aruco", "dots"}
    assert by["aruco"].markers == [76, 77]  # brick 3: 70 + 3 * 2 + slot
    for r in results:
        assert r.found, r
        assert r.position_error_m < 0.01 and abs(r.yaw_error_deg) < 0.5, r
        # whole rotation: the dots' 2x3 grid pins all three angles; two coplanar codes leave
        # the tilt about the line through them the weak part (the shipped
        # drick-aruco-pyramids layout shows up to 1.2 deg in this view too)
        assert r.angle_error_deg < (1.0 if r.method == "dots" else 1.5), r
