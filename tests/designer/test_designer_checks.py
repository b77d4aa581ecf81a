"""Live checks of a design and their one-click fixes."""

from __future__ import annotations

import numpy as np
import pytest

from drovisio.camera import Camera
from drovisio.designer.checks import (
    apply_fix,
    blocking,
    check_design,
    dot_symmetries,
    max_detection_distance,
)
from drovisio.designer.model import DesignError


def keys(doc, severity=None):
    return [f.key for f in check_design(doc) if severity is None or f.severity == severity]


def finding(doc, key):
    found = [f for f in check_design(doc) if f.key == key]
    assert found, f"no {key!r} finding in {keys(doc)}"
    return found[0]


def test_clean_design_has_only_notes_but_a_symmetry_warning(designed):
    # all six dots red in a 2x3 grid: a half-turn maps the pattern onto itself
    assert keys(designed, "error") == []
    assert keys(designed, "warning") == ["symmetric-dots"]
    assert dot_symmetries([m for _, m in designed.dots()]) == [180.0]


@pytest.mark.parametrize("fix_index", [0, 1])
def test_symmetry_warning_clears_with_either_fix(designed, fix_index):
    f = finding(designed, "symmetric-dots")
    labels = [x.label for x in f.fixes]
    assert "breaks the symmetry" in labels[0] and "symmetric" in labels[1]
    apply_fix(designed, f.fixes[fix_index].action)
    assert "symmetric-dots" not in keys(designed)
    if fix_index == 1:
        assert designed.symmetry == "rot180_z" and "symmetric-declared" in keys(designed)
    designed.undo()
    assert "symmetric-dots" in keys(designed)


def test_dots_only_symmetric_layout_is_an_error_until_fixed(designed):
    for i, _ in reversed(designed.codes()):
        designed.delete_marker(i)
    f = finding(designed, "symmetric-dots")
    assert f.severity == "error"  # the layout model refuses it: export is blocked
    apply_fix(designed, f.fixes[-1].action)  # mark symmetric
    assert blocking(check_design(designed)) == []


def test_overhang_with_fixes(designed):
    designed.nudge_marker(0, 0.01, 0.0)  # code 0 slides 10 mm: over the pyramid's edge
    f = finding(designed, "overhang")
    assert f.markers == [0] and "hangs over the edge" in f.message
    labels = [x.label for x in f.fixes]
    assert labels[0].startswith("Move code 0 to the centre")
    assert "mm (fits here)" in labels[1]
    apply_fix(designed, f.fixes[1].action)  # shrink to fit where it is
    assert "overhang" not in keys(designed)
    assert designed.markers[0].size < 0.065
    designed.undo()
    apply_fix(designed, finding(designed, "overhang").fixes[0].action)  # or centre it
    assert "overhang" not in keys(designed)


def test_big_dot_overhangs_its_face(designed):
    designed.set_marker(2, size=0.03)  # 30 mm at (-0.1, 0.05): touches the pyramid's base
    assert finding(designed, "overhang").markers == [2]


def test_overlap(designed):
    designed.nudge_marker(3, 0.0, 0.09)  # dot 2 moves onto dot 1's spot
    f = finding(designed, "overlap")
    assert f.markers == [2, 3]


def test_dots_not_coplanar_is_an_error(designed):
    designed.set_mode("dot")
    designed.click([0.0, -0.5, -0.05], [0, 1, 0])  # a dot on the -y side face
    f = finding(designed, "dots-not-coplanar")
    assert f.severity == "error" and "Move it onto the same face" in f.message
    apply_fix(designed, f.fixes[0].action)  # delete it
    assert "dots-not-coplanar" not in keys(designed)


def test_id_clash_and_free_id_fix(designed):
    designed.set_layout_fields(first_id=20)  # drick-aruco-pyramids owns 20..49
    f = finding(designed, "ids-clash")
    assert f.severity == "error" and "drick-aruco-pyramids" in f.message
    assert f.fixes[0].action == {"op": "set_first_id", "value": 70}
    apply_fix(designed, f.fixes[0].action)
    assert "ids-clash" not in keys(designed)


def test_too_many_ids_for_the_family(designed):
    designed.set_layout_fields(first_id=990, instances=10)
    assert "ids-too-many" in keys(designed, "error")


def test_detection_distance_estimate(designed):
    cam = Camera.drone_webcam()
    d_code = max_detection_distance(0.065, cam, "aruco")
    d_dot = max_detection_distance(0.02, cam, "dot")
    f = min(cam.fx, cam.fy)
    # through the lens model: at the centre the pinhole figure, to the lens's distortion
    assert d_code == pytest.approx(f * 0.065 / 15, rel=0.01)
    assert d_dot == pytest.approx(f * 0.02 / 6, rel=0.01)
    # a code seen at that distance spans the 15 px (projected with the camera's own model)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 0.0325
    px = cam.project(np.column_stack([corners, np.full(4, d_code)]))
    assert np.sqrt(np.prod(np.ptp(px, axis=0))) == pytest.approx(15, rel=1e-3)
    msgs = [x.message for x in check_design(designed, cam) if x.key == "range"]
    assert any(f"up to about {d_code:.1f} m" in m and "15 pixels" in m for m in msgs)
    assert any(f"up to about {d_dot:.1f} m" in m and "6 pixels" in m for m in msgs)
    designed.set_marker(0, size=0.03)  # 30 mm code: ~1.1 m only
    short = finding(designed, "range-short")
    assert short.markers == [0] and "make them at least 41 mm" in short.message


def test_units_warning_offers_the_right_unit(drick_bytes):
    from drovisio.designer.model import DesignDocument
    from drovisio.meshes import drick_mesh

    mm = drick_mesh()
    mm.apply_scale(1000)
    doc = DesignDocument.from_mesh(mm, "drick-mm.stl", units="m")
    f = finding(doc, "units-suspect")
    assert f.fixes[0].action == {"op": "set_units", "units": "mm"}
    apply_fix(doc, f.fixes[0].action)
    assert doc.units == "mm" and "units-suspect" not in keys(doc)


def test_bad_fix_is_refused(designed):
    with pytest.raises(DesignError):
        apply_fix(designed, {"op": "format_disk"})
    with pytest.raises(DesignError):
        apply_fix(designed, {"op": "set_color", "marker": 99, "color": "red"})


def test_detection_distance_follows_a_fisheye_lens():
    from drovisio.bench.lens import FISHEYE_150

    cam = FISHEYE_150
    centre = max_detection_distance(0.065, cam, "aruco")
    edge = max_detection_distance(0.065, cam, "aruco", where="edge")
    assert centre == pytest.approx(min(cam.fx, cam.fy) * 0.065 / 15, rel=0.02)
    # an equidistant fisheye keeps the radial scale and stretches the tangential one by
    # theta / sin(theta): a code near the edge spans more pixels than at the centre (a
    # pinhole model would say far more: 1/cos^2 and 1/cos; the lens's k1..k4 add 4 %)
    ray = cam.rays(np.array([[0.05 * (cam.width - 1), (cam.height - 1) / 2]]))[0]
    theta = np.arccos(ray[2])
    assert edge / centre == pytest.approx(np.sqrt(theta / np.sin(theta)), rel=0.06)
