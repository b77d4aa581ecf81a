"""The designer's document: mesh files, units, brick frame, placing/editing markers, undo."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import trimesh

from drovisio.designer.model import (
    DesignDocument,
    DesignError,
    guess_units,
    read_mesh,
    units_problem,
)
from drovisio.layout import load_layout, parse_layout, shipped_layouts_dir
from drovisio.meshes import drick_mesh


def _export(mesh: trimesh.Trimesh, fmt: str) -> bytes:
    data = mesh.export(file_type=fmt)
    return data if isinstance(data, bytes) else data.encode()


# ------------------------------------------------------------------ files


@pytest.mark.parametrize("fmt", ["stl", "obj", "ply", "glb", "off"])
def test_reads_every_format(fmt):
    mesh = read_mesh(_export(drick_mesh(), fmt), f"brick.{fmt}")
    assert len(mesh.faces) == 68
    np.testing.assert_allclose(mesh.extents, [0.30, 0.15, 0.12], atol=1e-6)


@pytest.mark.parametrize("name,data,words", [
    ("notes.txt", b"hello", "not 3D models"),
    ("photo.stl", b"\x89PNG\r\n\x1a\n" + bytes(200), "not a STL 3D model"),
    ("letter.stl", b"Dear site engineer, the bricks arrive on Monday.\n", "not a STL"),
    ("broken.glb", b"glTF" + bytes(40), "could not read"),
    ("empty.stl", b"", "empty (0 bytes)"),
    ("empty.stl", b"solid x\nendsolid x\n", "no triangles"),
    ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangles"),
    ("binary-empty.stl", bytes(80) + (0).to_bytes(4, "little"), "no triangles"),
])
def test_bad_files_say_what_to_do(name, data, words):
    with pytest.raises(DesignError) as e:
        read_mesh(data, name)
    msg = str(e.value)
    assert words in msg and name in msg
    assert any(w in msg for w in ("Export", "export", "upload", "picked"))


def test_units_guess_and_warning():
    assert guess_units(0.3) == "m" and guess_units(12.0) == "cm" and guess_units(300.0) == "mm"
    assert units_problem(0.3, "m") is None
    msg, unit = units_problem(300.0, "m")  # a drick drawn in mm, declared as metres
    assert unit == "mm" and "300 m" in msg and "millimetres" in msg and "'mm'" in msg
    assert units_problem(300.0, "mm") is None


def test_mm_mesh_declared_as_metres_is_flagged(shipped_layouts):
    mm = drick_mesh()
    mm.apply_scale(1000.0)
    doc = DesignDocument.from_mesh_bytes(_export(mm, "stl"), "drick-mm.stl", units="m")
    assert doc.units == "m" and doc.units_warning() is not None
    auto = DesignDocument.from_mesh_bytes(_export(mm, "stl"), "drick-mm.stl")
    assert auto.units == "mm" and auto.units_guessed
    np.testing.assert_allclose(auto.dimensions(), [0.30, 0.15, 0.12], atol=1e-6)


# ------------------------------------------------------------------ placing


def test_clicks_place_snapped_markers_on_faces(designed):
    doc = designed
    codes = [m for _, m in doc.codes()]
    assert [m.slot for m in codes] == [0, 1]
    np.testing.assert_allclose([m.center for m in codes], [[-0.075, 0, 0.02], [0.075, 0, 0.02]],
                               atol=1e-6)  # snapped to the pyramid tops' centres
    for m in codes:
        np.testing.assert_allclose(m.normal, [0, 0, 1], atol=1e-9)
        np.testing.assert_allclose(m.up, [0, 1, 0], atol=1e-9)  # image top toward +y
        assert m.size == pytest.approx(0.065)
    dots = np.array([m.center for _, m in doc.dots()])
    want = [[x, y, 0.0] for x in (-0.1, 0.0, 0.1) for y in (0.05, -0.05)]
    np.testing.assert_allclose(dots, want, atol=1e-6)  # snapped to the 5 mm grid
    assert doc.selected == 7


def test_click_modes_select_and_miss(designed):
    doc = designed
    doc.set_mode("select")
    r = doc.click([0.1, -0.049, 1.0], [0, 0, -1])
    assert r.action == "selected" and doc.markers[r.marker].kind == "dot"
    assert doc.click([3.0, 3.0, 1.0], [0, 0, -1]).action == "missed"
    assert doc.selected is None
    with pytest.raises(DesignError):
        doc.set_mode("paint")


def test_edit_markers_and_undo_redo(designed):
    doc = designed
    before = list(doc.markers)
    doc.rotate_marker(0, 90)
    np.testing.assert_allclose(doc.markers[0].up, [-1, 0, 0], atol=1e-12)
    doc.set_marker(0, size=0.05)
    doc.nudge_marker(2, 0.005, 0.0)
    np.testing.assert_allclose(doc.markers[2].center, [-0.095, 0.05, 0], atol=1e-9)
    doc.set_marker(1, slot=0)  # swapped with code 0
    assert (doc.markers[0].slot, doc.markers[1].slot) == (1, 0)
    doc.set_marker(3, color="blue")
    doc.delete_marker(4)
    assert len(doc.markers) == 7
    for _ in range(6):
        assert doc.undo()
    assert doc.markers == before
    assert doc.undo() and len(doc.markers) == len(before) - 1  # the last placement, too
    while doc.redo():
        pass
    assert len(doc.markers) == 7 and doc.markers[0].size == pytest.approx(0.05)
    with pytest.raises(DesignError):
        doc.set_marker(2, slot=3)  # dots have no slot
    with pytest.raises(DesignError):
        doc.set_marker(2, color="purple")


def test_brick_frame_moves_without_moving_markers(designed):
    doc = designed
    world_before = [m.c for m in doc.markers]
    # origin on the +x pyramid top, then back to the top-centre, align x, turn
    hit = doc.hit([0.075, 0.0, 1.0], [0, 0, -1])
    face = doc.faces.of_triangle(hit.face_index).index
    doc.set_origin_on_face(face)
    bm = doc.brick_markers()
    np.testing.assert_allclose(bm[1].center, [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(doc.dimensions(), [0.30, 0.15, 0.12], atol=1e-6)
    doc.turn_frame(90)
    np.testing.assert_allclose(doc.brick_markers()[0].center, [0, 0.15, 0], atol=1e-9)
    assert doc.align_x_with_longest_edge()
    np.testing.assert_allclose(doc.dimensions(), [0.30, 0.15, 0.12], atol=1e-6)
    doc.flip_frame()
    np.testing.assert_allclose(doc.brick_markers()[0].normal, [0, 0, -1], atol=1e-9)
    doc.origin_to_top_centre()
    doc.flip_frame()
    doc.reset_frame()
    # markers never moved on the mesh
    for a, m in zip(world_before, doc.markers, strict=True):
        np.testing.assert_allclose(m.c, a)
    np.testing.assert_allclose(doc.brick_from_mesh, np.eye(4))


def test_origin_click_on_a_side_face(drick_doc):
    doc = drick_doc
    doc.set_mode("origin")
    r = doc.click([0.5, 0.0, -0.05], [-1, 0, 0])  # the +x end face
    assert r.action == "origin"
    B = doc.brick_from_mesh
    np.testing.assert_allclose(B[:3, :3] @ [1, 0, 0], [0, 0, 1], atol=1e-9)  # z = face normal
    np.testing.assert_allclose(B[:3, :3] @ [0.15, 0, -0.05] + B[:3, 3], [0, 0, 0], atol=1e-7)


def test_units_change_keeps_markers_on_the_model(drick_bytes):
    doc = DesignDocument.from_mesh_bytes(drick_bytes, "drick.stl", units="mm")
    doc.set_mode("dot")
    doc.click([0.0, 0.00005, 10.0], [0, 0, -1])  # in mm the mesh is 0.3 mm long
    doc.set_units("m")
    np.testing.assert_allclose(doc.dimensions(), [0.30, 0.15, 0.12], atol=1e-6)
    hit = doc.hit(doc.markers[0].c + [0, 0, 0.01], [0, 0, -1])
    assert hit is not None and np.linalg.norm(hit.point - doc.markers[0].c) < 1e-9
    doc.undo()
    assert doc.units == "mm"


def test_open_shipped_layout_round_trips(shipped_layouts):
    lay = load_layout(shipped_layouts_dir() / "drick-aruco-pyramids.json")
    doc = DesignDocument.from_layout(lay, others=shipped_layouts)
    assert doc.name == lay.name and all(m.face is not None for m in doc.markers)
    again = parse_layout(doc.layout_data("meshes/drick.stl"))
    assert again.first_id == lay.first_id and again.ids_per_instance == 2
    for slot, c in lay.code_corners_m().items():
        np.testing.assert_allclose(again.code_corners_m()[slot], c, atol=1e-6)
    assert math.isclose(again.dimensions[2], 0.12, abs_tol=1e-6)


def test_auto_first_id_avoids_shipped_blocks(designed):
    doc = designed
    # shipped 4x4 blocks: 0-19, 20-49, 50-69 -> the first free block starts at 70
    assert doc.effective_first_id() == 70
    assert doc.dictionary() == "DICT_4X4_100"  # smallest 4x4 dictionary holding 70..89
    doc.set_layout_fields(instances=20)
    assert doc.dictionary() == "DICT_4X4_250"


def test_read_mesh_gltf_scene_is_flattened():
    scene = trimesh.Scene([drick_mesh(), trimesh.creation.box(extents=(0.1, 0.1, 0.1))])
    buf = io.BytesIO(scene.export(file_type="glb"))
    mesh = read_mesh(buf.getvalue(), "two.glb")
    assert len(mesh.faces) == 68 + 12


def test_a_refused_marker_leaves_no_undo_step(designed):
    """A dot of a colour the palette lacks is refused and leaves the history as it was: the
    next undo undoes the last real edit, not a step that changed nothing."""
    doc = designed
    doc.set_marker(0, size=0.05)
    face = doc.faces.faces.index(next(f for f in doc.faces.faces if f.normal[2] > 0.9))
    point = doc.faces.centre(doc.faces.faces[face])
    with pytest.raises(DesignError):
        doc.add_marker("dot", face, point, color="no-such-colour")
    assert doc.undo() and doc.markers[0].size != pytest.approx(0.05)
