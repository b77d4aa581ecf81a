"""Every one-click fix is tried before it is offered, and the checks cover what the
detectors need (a dot layout needs at least 4 dots on one face)."""

from __future__ import annotations

import trimesh

from drovisio.camera import Camera
from drovisio.designer.checks import (
    MIN_CODE_PX,
    WORKING_DISTANCE_M,
    apply_fix,
    blocking,
    check_design,
)
from drovisio.designer.model import DesignDocument


def _box_with_two_codes(shipped_layouts) -> DesignDocument:
    """A plain 300 x 150 x 120 mm block: code 0 at the centre of the top, code 1 near its end,
    hanging 17.5 mm over the edge."""
    doc = DesignDocument.from_mesh(trimesh.creation.box([0.3, 0.15, 0.12]), "box.stl",
                                   units="m", others=shipped_layouts)
    doc.set_mode("code")
    assert doc.click([0.0, 0.0, 1.0], [0, 0, -1]).action == "added"
    assert doc.click([0.13, 0.0, 1.0], [0, 0, -1]).action == "added"
    return doc


def test_a_fix_that_would_make_things_worse_is_not_offered(shipped_layouts):
    doc = _box_with_two_codes(shipped_layouts)
    raw = {f.key: f for f in check_design(doc, vet_fixes=False)}
    labels = [x.label for x in raw["overhang"].fixes]
    # unvetted, the checks would offer both: centring puts code 1 on code 0, and the size
    # that fits is read only from closer than the working distance
    assert labels == ["Move code 1 to the centre of its face", "Make code 1 40 mm (fits here)"]
    for fix in raw["overhang"].fixes:
        trial = doc.copy()
        apply_fix(trial, fix.action)
        after = {f.key for f in check_design(trial, vet_fixes=False) if f.severity != "info"}
        assert after & {"overlap", "range-short"}, (fix.label, after)
    vetted = {f.key: f for f in check_design(doc)}
    assert vetted["overhang"].fixes == []
    # a 40 mm code spans MIN_CODE_PX pixels only closer than the working distance
    cam = Camera.drone_webcam()
    assert 0.040 * min(cam.fx, cam.fy) / MIN_CODE_PX < WORKING_DISTANCE_M


def test_every_offered_fix_removes_its_finding_and_adds_none(designed):
    designed.nudge_marker(0, 0.01, 0.0)     # code 0 over its pyramid's edge
    designed.set_layout_fields(first_id=20)  # ids of drick-aruco-pyramids
    findings = check_design(designed)
    offered = [(f, x) for f in findings for x in f.fixes]
    assert {f.key for f, _ in offered} >= {"overhang", "ids-clash", "symmetric-dots"}
    for f, fix in offered:
        trial = designed.copy()
        apply_fix(trial, fix.action)
        after = check_design(trial, vet_fixes=False)
        assert not any(g.key == f.key and g.markers == f.markers for g in after), fix.label
        levels = ("error",) if f.severity == "error" else ("error", "warning")
        for key in {g.key for g in after if g.severity in levels}:
            n_after = sum(g.key == key and g.severity in levels for g in after)
            n_before = sum(g.key == key and g.severity in levels for g in findings)
            assert n_after <= n_before, (fix.label, key)


def test_codes_with_one_dot_cannot_be_saved_and_the_fix_deletes_the_dot(designed):
    for i, _ in reversed(designed.dots()[1:]):
        designed.delete_marker(i)
    assert len(designed.dots()) == 1 and len(designed.codes()) == 2
    errors = blocking(check_design(designed))
    assert [f.key for f in errors] == ["dots-few"]
    assert "at least 4 dots" in errors[0].message
    assert [x.label for x in errors[0].fixes] == ["Delete the dots (keep the codes)"]
    apply_fix(designed, errors[0].fixes[0].action)
    assert designed.dots() == [] and len(designed.codes()) == 2
    assert blocking(check_design(designed)) == []
