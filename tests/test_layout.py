"""Tests of drovisio.layout (marker layout schema) and drovisio.meshes (shipped meshes)."""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from drovisio.layout import (
    DEFAULT_PALETTE,
    SCHEMA_ID,
    ArucoMarker,
    LayoutError,
    MarkerLayout,
    aruco_dictionaries,
    aruco_dictionary_id,
    aruco_dictionary_size,
    aruco_family,
    check_id_clashes,
    layout_json_schema,
    list_shipped_layouts,
    load_layout,
    load_layouts,
    parse_layout,
    save_layout,
    shipped_layouts_dir,
    square_corners,
)

SHIPPED = ["drick-aruco-centre", "drick-aruco-pyramids", "drick-dots-2x3", "landing-pad"]


def _shipped(name: str) -> MarkerLayout:
    return load_layout(shipped_layouts_dir() / f"{name}.json")


def _raw(name: str) -> dict:
    return json.loads((shipped_layouts_dir() / f"{name}.json").read_text())


def _write(tmp_path: Path, file_name: str, data) -> Path:
    p = tmp_path / file_name
    p.write_text(data if isinstance(data, str) else json.dumps(data))
    return p


def _error(path: Path) -> str:
    with pytest.raises(LayoutError) as info:
        load_layout(path)
    return str(info.value)


# ---- shipped layouts --------------------------------------------------------------------


def test_shipped_layouts_listed_and_load_together():
    paths = list_shipped_layouts()
    assert [p.stem for p in paths] == SHIPPED
    layouts = load_layouts(paths)
    assert [lay.name for lay in layouts] == SHIPPED
    for lay in layouts:
        assert lay.source is not None and lay.description
        assert lay.schema_id == SCHEMA_ID
    check_id_clashes(layouts)  # no clash


@pytest.mark.parametrize("name", ["../marker_layouts/drick-aruco-centre", "/etc/passwd",
                                  "meshes/../drick-aruco-centre", ".drick", "drick\x00x",
                                  "drick-aruco-centre.json", "", 3, None])
def test_a_layout_name_is_a_shipped_name_never_a_path(name):
    from drovisio.errors import InputError
    from drovisio.layout import shipped_layout_file

    for p in list_shipped_layouts():
        assert shipped_layout_file(p.stem) == p
    with pytest.raises(InputError) as e:
        shipped_layout_file(name)
    assert str(e.value) == (f"no shipped layout called {name!r}; give one of "
                            f"{', '.join(p.stem for p in list_shipped_layouts())}")


def test_shipped_ids():
    centre, pyramids, dots, pad = (_shipped(n) for n in SHIPPED)
    assert centre.all_ids() == list(range(0, 20))
    assert pyramids.all_ids() == list(range(20, 50))
    assert pad.all_ids() == list(range(50, 70))
    assert dots.all_ids() == [] and not dots.has_codes and dots.first_id is None
    assert pyramids.marker_id(4, 1) == 29
    assert pyramids.instance_slot(29) == (4, 1)
    assert pyramids.instance_slot(19) is None and pyramids.instance_slot(50) is None
    assert pad.instance_slot(57) == (1, 2)
    with pytest.raises(ValueError):
        pyramids.marker_id(15, 0)
    with pytest.raises(ValueError):
        pyramids.marker_id(0, 2)


def test_pyramid_corners_geometry():
    lay = _shipped("drick-aruco-pyramids")
    corners = lay.code_corners_m()
    assert list(corners) == [0, 1]
    h = 0.065 / 2
    for slot, cx in ((0, -0.075), (1, 0.075)):
        c = corners[slot]
        assert c.shape == (4, 3) and c.dtype == np.float64
        expected = np.array([[cx - h, h, 0.02], [cx + h, h, 0.02],
                             [cx + h, -h, 0.02], [cx - h, -h, 0.02]])
        np.testing.assert_allclose(c, expected, atol=1e-12)
    np.testing.assert_allclose(corners[1][0], (0.075 - 0.0325, 0.0325, 0.02), atol=1e-12)
    np.testing.assert_allclose(lay.code_normals()[1], (0, 0, 1))
    np.testing.assert_allclose(lay.code_centers_m()[0], (-0.075, 0, 0.02), atol=1e-12)
    assert lay.code_sizes_m() == {0: 0.065, 1: 0.065}


def test_corner_order_matches_opencv_square_object_points():
    s = 0.065
    c = square_corners((0, 0, 0), (0, 0, 1), (0, 1, 0), s)
    opencv = np.array([[-s / 2, s / 2, 0], [s / 2, s / 2, 0], [s / 2, -s / 2, 0],
                       [-s / 2, -s / 2, 0]])
    np.testing.assert_allclose(c, opencv, atol=1e-15)
    # OpenCV's GridBoard lists each marker's corners in the same order TL, TR, BR, BL, in a
    # board frame with y down and z into the board: a half-turn about x maps it onto ours.
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    board = cv2.aruco.GridBoard((1, 1), s, 0.01, d)
    obj = np.asarray(board.getObjPoints()[0], np.float64).reshape(4, 3)
    obj = (obj - obj.mean(axis=0)) * (1, -1, -1)
    np.testing.assert_allclose(obj, opencv, atol=1e-7)
    # The detector's corner 0 is the printed image's top-left corner.
    img = np.full((200, 200), 255, np.uint8)
    img[50:150, 50:150] = cv2.aruco.generateImageMarker(d, 7, 100)
    corners, ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers(img)
    assert ids is not None and np.asarray(ids).ravel().tolist() == [7]
    expected = [[49.5, 49.5], [149.5, 49.5], [149.5, 149.5], [49.5, 149.5]]
    np.testing.assert_allclose(np.asarray(corners[0]).reshape(4, 2), expected, atol=1.0)


def test_landing_pad_geometry():
    pad = _shipped("landing-pad")
    corners = pad.code_corners_m()
    assert sorted(corners) == [0, 1, 2, 3, 4]
    np.testing.assert_allclose(corners[0][0], (-0.15, 0.15, 0), atol=1e-12)
    centres = np.array([pad.code_centers_m()[s] for s in range(1, 5)])
    np.testing.assert_allclose(np.abs(centres[:, :2]), 0.21, atol=1e-12)
    assert {tuple(np.sign(c[:2])) for c in centres} == {(1, 1), (1, -1), (-1, 1), (-1, -1)}
    assert pad.code_sizes_m()[3] == pytest.approx(0.08)
    np.testing.assert_allclose(pad.dimensions_m, (0.6, 0.6, 0.01))


def test_dots_layout():
    lay = _shipped("drick-dots-2x3")
    pts = lay.dot_centers_m()
    assert pts.shape == (6, 3)
    assert sorted(map(tuple, np.round(pts, 9))) == sorted(
        (x, y, 0.0) for x in (-0.1, 0.0, 0.1) for y in (0.05, -0.05))
    assert lay.dot_colors() == ["red", "blue", "red"] * 2
    np.testing.assert_allclose(lay.dot_diameters_m(), 0.02)
    np.testing.assert_allclose(lay.dot_normals(), np.tile((0, 0, 1.0), (6, 1)))
    assert lay.symmetry == "rot180_z"
    assert lay.code_corners_m() == {}


def test_center_normal_up_equals_explicit_corners(tmp_path):
    for name in ("drick-aruco-centre", "drick-aruco-pyramids", "landing-pad"):
        raw = _raw(name)
        ref = load_layout(shipped_layouts_dir() / f"{name}.json").code_corners_m()
        explicit = copy.deepcopy(raw)
        for m in explicit["markers"]:
            corners = square_corners(m.pop("center"), m.pop("normal"), m.pop("up"), m["size"])
            m["corners"] = corners.tolist()  # full precision
        got = load_layout(_write(tmp_path, f"{name}.json", explicit)).code_corners_m()
        assert got.keys() == ref.keys()
        for slot in ref:
            np.testing.assert_array_equal(got[slot], ref[slot])
    # Hand-written decimal corners of pyramid slot 1 mean the same square.
    raw = _raw("drick-aruco-pyramids")
    m = raw["markers"][1]
    for k in ("center", "normal", "up"):
        del m[k]
    m["corners"] = [[0.0425, 0.0325, 0.02], [0.1075, 0.0325, 0.02], [0.1075, -0.0325, 0.02],
                    [0.0425, -0.0325, 0.02]]
    lay = parse_layout(raw, "hand.json")
    np.testing.assert_allclose(lay.code_corners_m()[1], _shipped("drick-aruco-pyramids")
                               .code_corners_m()[1], atol=1e-15)
    np.testing.assert_allclose(lay.code_normals()[1], (0, 0, 1))


def test_tilted_code_frame():
    # A code on a vertical face looking along -y, image top toward +z; up not perpendicular.
    c = square_corners((0, -0.075, -0.05), (0, -2, 0), (0, 0.3, 1), 0.04)
    # Seen from the front (from -y), right is +x: TL is at -x, +z.
    np.testing.assert_allclose(c[0], (-0.02, -0.075, -0.03), atol=1e-12)
    np.testing.assert_allclose(c[2], (0.02, -0.075, -0.07), atol=1e-12)
    m = ArucoMarker(kind="aruco", dictionary="DICT_4X4_50", id=0, size=0.04,
                    corners=[tuple(p) for p in c])
    np.testing.assert_allclose(m.normal_array(), (0, -1, 0), atol=1e-12)
    np.testing.assert_allclose(m.up_array(), (0, 0, 1), atol=1e-12)


def test_mm_layout_same_metres(tmp_path):
    for name in ("drick-aruco-pyramids", "drick-dots-2x3"):
        raw = _raw(name)
        mm = copy.deepcopy(raw)
        mm["units"] = "mm"
        mm["dimensions"] = [v * 1000 for v in raw["dimensions"]]
        for m in mm["markers"]:
            for k in ("size", "diameter"):
                if k in m:
                    m[k] *= 1000
            m["center"] = [v * 1000 for v in m["center"]]
        a = _shipped(name)
        b = load_layout(_write(tmp_path, f"{name}-mm.json", mm))
        assert b.scale_to_m == 0.001 and a.scale_to_m == 1.0
        np.testing.assert_allclose(b.dimensions_m, a.dimensions_m, atol=1e-12)
        np.testing.assert_allclose(b.dot_centers_m(), a.dot_centers_m(), atol=1e-12)
        np.testing.assert_allclose(b.dot_diameters_m(), a.dot_diameters_m(), atol=1e-12)
        for slot, c in a.code_corners_m().items():
            np.testing.assert_allclose(b.code_corners_m()[slot], c, atol=1e-12)
        # Saved back in millimetres.
        out = save_layout(b, tmp_path / f"{name}-mm-out.json")
        assert json.loads(out.read_text())["units"] == "mm"
        assert json.loads(out.read_text())["dimensions"][0] == pytest.approx(300)


# ---- save / schema ----------------------------------------------------------------------


def test_save_load_round_trip(tmp_path):
    for name in SHIPPED:
        lay = _shipped(name)
        out = save_layout(lay, tmp_path / f"{name}.json")
        back = load_layout(out)
        assert back == lay and back.source == out
        with pytest.raises(ValidationError, match="frozen"):
            back.name = "renamed"
        assert back.model_dump() == lay.model_dump()
        # The shipped files are exactly what save_layout writes.
        assert out.read_text() == (shipped_layouts_dir() / f"{name}.json").read_text()
    assert sorted(os.listdir(tmp_path)) == sorted(f"{n}.json" for n in SHIPPED)


def test_save_refuses_overwrite_and_is_atomic(tmp_path):
    lay = _shipped("drick-aruco-centre")
    path = tmp_path / "x.json"
    path.write_text("keep me")
    with pytest.raises(LayoutError, match="already exists.*overwrite=True") as info:
        save_layout(lay, path)
    assert "x.json" in str(info.value)
    assert path.read_text() == "keep me"
    assert os.listdir(tmp_path) == ["x.json"]  # no temp file left behind
    save_layout(lay, path, overwrite=True)
    assert load_layout(path) == lay
    assert os.listdir(tmp_path) == ["x.json"]
    with pytest.raises(LayoutError, match="does not exist"):
        save_layout(lay, tmp_path / "missing-folder" / "y.json")


def test_json_schema():
    schema = layout_json_schema()
    assert isinstance(schema, dict)
    json.dumps(schema)  # JSON-ready
    text = json.dumps(schema)
    assert '"aruco"' in text and '"dot"' in text
    assert schema["properties"]["markers"]["items"]["discriminator"]["propertyName"] == "kind"
    assert schema["properties"]["schema"]["const"] == SCHEMA_ID
    assert set(schema["properties"]["units"]["enum"]) == {"m", "cm", "mm"}
    assert schema["additionalProperties"] is False
    assert "DICT_4X4_50" in schema["$defs"]["ArucoMarker"]["properties"]["dictionary"]["enum"]
    assert "description" in schema["properties"]


# ---- dictionaries and colours -----------------------------------------------------------


def test_dictionaries():
    names = aruco_dictionaries()
    assert names[:4] == ["DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000"]
    assert "DICT_APRILTAG_36h11" in names and "DICT_ARUCO_ORIGINAL" in names
    assert aruco_dictionary_size("DICT_4X4_100") == 100
    assert aruco_dictionary_id("DICT_4X4_100") == cv2.aruco.DICT_4X4_100
    assert aruco_family("DICT_4X4_50") == aruco_family("DICT_4X4_1000") == "DICT_4X4"
    assert aruco_family("DICT_APRILTAG_36H11") == aruco_family("DICT_APRILTAG_36h11")
    assert aruco_family("DICT_APRILTAG_36h11") != aruco_family("DICT_APRILTAG_36h10")
    assert aruco_family("DICT_ARUCO_ORIGINAL") != aruco_family("DICT_5X5_1000")


def _hsv(bgr):
    return cv2.cvtColor(np.array([[bgr]], np.uint8), cv2.COLOR_BGR2HSV)[0, 0]


def test_default_palette_paints_fall_in_their_own_range_only():
    assert set(DEFAULT_PALETTE) >= {"red", "blue", "green", "yellow"}
    assert DEFAULT_PALETTE["red"].hsv == ((170, 80, 70), (10, 255, 255))
    assert DEFAULT_PALETTE["blue"].hsv == ((80, 85, 75), (115, 255, 255))
    for name, spec in DEFAULT_PALETTE.items():
        hsv = _hsv(spec.bgr)
        for other, ospec in DEFAULT_PALETTE.items():
            assert ospec.contains(hsv) == (other == name), (name, other, hsv)
        # cv2.inRange agrees with contains().
        px = np.array([[hsv]], np.uint8)
        hit = any(cv2.inRange(px, lo, hi)[0, 0] for lo, hi in spec.cv_ranges())
        assert hit
    assert len(DEFAULT_PALETTE["red"].cv_ranges()) == 2
    assert DEFAULT_PALETTE["red"].contains((175, 200, 200))
    assert DEFAULT_PALETTE["red"].contains((5, 200, 200))
    assert not DEFAULT_PALETTE["red"].contains((90, 200, 200))


def test_layout_colors_override_palette():
    raw = _raw("drick-dots-2x3")
    raw["colors"] = {"red": {"hsv": [[165, 60, 60], [12, 255, 255]]},
                     "orange": {"hsv": [[11, 100, 100], [19, 255, 255]], "bgr": [0, 128, 255]}}
    raw["markers"][1]["color"] = "orange"
    raw["markers"][4]["color"] = "orange"
    lay = parse_layout(raw, "colours.json")
    pal = lay.palette()
    assert pal["red"].hsv[0] == (165, 60, 60) and pal["blue"] == DEFAULT_PALETTE["blue"]
    assert pal["orange"].display_bgr() == (0, 128, 255)
    assert pal["orange"].contains(_hsv(pal["orange"].display_bgr()))
    assert pal["red"].contains(_hsv(pal["red"].display_bgr()))  # derived from the range


# ---- errors -----------------------------------------------------------------------------


def _bad(tmp_path, file_name, base, mutate) -> str:
    data = copy.deepcopy(_raw(base))
    mutate(data)
    return _error(_write(tmp_path, file_name, data))


def test_error_unknown_dictionary(tmp_path):
    msg = _bad(tmp_path, "bad-dict.json", "drick-aruco-pyramids",
               lambda d: d["markers"][1].update(dictionary="DICT_4X4_51"))
    assert "bad-dict.json" in msg and "markers[1] (aruco id 1)" in msg
    assert "dictionary" in msg and "'DICT_4X4_51'" in msg and "DICT_4X4_100" in msg


def test_error_duplicate_slot(tmp_path):
    msg = _bad(tmp_path, "dup.json", "drick-aruco-pyramids",
               lambda d: d["markers"][1].update(id=0))
    assert "dup.json" in msg and "markers[1]" in msg and ": id:" in msg
    assert "duplicate slot 0" in msg and "markers[0]" in msg


def test_error_slot_out_of_range(tmp_path):
    msg = _bad(tmp_path, "slot.json", "drick-aruco-pyramids",
               lambda d: d["markers"][1].update(id=2))
    assert "slot.json" in msg and "markers[1]" in msg and "ids_per_instance is 2" in msg


def test_error_degenerate_square(tmp_path):
    def mutate(d):
        m = d["markers"][0]
        for k in ("center", "normal", "up"):
            del m[k]
        m["corners"] = [[0, 0, 0], [0.065, 0, 0], [0.065, 0.07, 0], [0, 0.065, 0]]

    msg = _bad(tmp_path, "square.json", "drick-aruco-pyramids", mutate)
    assert "square.json" in msg and "markers[0] (aruco id 0)" in msg and "corners" in msg
    assert "size" in msg

    def skew(d):  # right sides, wrong angles (a rhombus)
        m = d["markers"][0]
        for k in ("center", "normal", "up"):
            del m[k]
        s, a = 0.065, np.radians(80)
        m["corners"] = [[0, 0, 0], [s, 0, 0], [s + s * np.cos(a), -s * np.sin(a), 0],
                        [s * np.cos(a), -s * np.sin(a), 0]]

    msg = _bad(tmp_path, "rhombus.json", "drick-aruco-pyramids", skew)
    assert "rhombus.json" in msg and "markers[0]" in msg and "corners" in msg
    assert "angle" in msg

    msg = _bad(tmp_path, "parallel.json", "drick-aruco-pyramids",
               lambda d: d["markers"][1].update(up=[0, 0, 5]))
    assert "parallel.json" in msg and "markers[1]" in msg and "up" in msg and "parallel" in msg
    msg = _bad(tmp_path, "zero.json", "drick-aruco-pyramids",
               lambda d: d["markers"][0].update(normal=[0, 0, 0]))
    assert "zero.json" in msg and "markers[0]" in msg and "normal" in msg


def test_error_unknown_colour(tmp_path):
    msg = _bad(tmp_path, "colour.json", "drick-dots-2x3",
               lambda d: d["markers"][4].update(color="purple"))
    assert "colour.json" in msg and "markers[4] (dot purple)" in msg and "color" in msg
    assert "red" in msg and "blue" in msg  # lists the known colours


def test_error_dots_not_coplanar(tmp_path):
    msg = _bad(tmp_path, "plane.json", "drick-dots-2x3",
               lambda d: d["markers"][2].update(center=[0.1, 0.05, 0.02]))
    assert "plane.json" in msg and "markers[2] (dot red)" in msg and "center" in msg
    assert "coplanar" in msg
    # Within 1 mm (after conversion to metres) is fine, in m and in mm units.
    raw = _raw("drick-dots-2x3")
    raw["markers"][2]["center"] = [0.1, 0.05, 0.0004]
    parse_layout(raw, "ok.json")
    raw["units"] = "mm"
    raw["dimensions"] = [300.0, 150.0, 120.0]
    for m in raw["markers"]:
        m["diameter"] = 20.0
        m["center"] = [v * 1000 for v in m["center"]]
    parse_layout(raw, "ok-mm.json")
    raw["markers"][2]["center"][2] = 5.0  # 5 mm off
    with pytest.raises(LayoutError, match=r"plane-mm\.json: markers\[2\].*coplanar"):
        parse_layout(raw, "plane-mm.json")


def test_error_bad_units_and_schema(tmp_path):
    msg = _bad(tmp_path, "units.json", "landing-pad", lambda d: d.update(units="inch"))
    assert "units.json" in msg and "units" in msg and "'m', 'cm', 'mm'" in msg
    msg = _bad(tmp_path, "schema.json", "landing-pad",
               lambda d: d.update(schema="drovisio/marker-layout@2"))
    assert "schema.json" in msg and "schema" in msg and SCHEMA_ID in msg
    msg = _bad(tmp_path, "typo.json", "landing-pad", lambda d: d["markers"][3].update(sise=1))
    assert "typo.json" in msg and "markers[3] (aruco id 3)" in msg and "sise" in msg


def test_error_symmetry_mismatch(tmp_path):
    msg = _bad(tmp_path, "sym.json", "drick-dots-2x3",
               lambda d: d["markers"][0].update(color="green"))
    assert "sym.json" in msg and "symmetry" in msg
    msg = _bad(tmp_path, "nosym.json", "drick-dots-2x3", lambda d: d.update(symmetry="none"))
    assert "nosym.json" in msg and "rot180_z" in msg


def test_error_ids_beyond_dictionary(tmp_path):
    msg = _bad(tmp_path, "ids.json", "drick-aruco-pyramids", lambda d: d.update(instances=16))
    assert "ids.json" in msg and "markers[0]" in msg and "dictionary" in msg and "50" in msg
    msg = _bad(tmp_path, "noids.json", "drick-aruco-pyramids", lambda d: d.update(instances=None))
    assert "noids.json" in msg and "instances" in msg


def test_error_marker_count_says_the_limit_it_broke(tmp_path):
    from drovisio.errors import LIMITS

    msg = _bad(tmp_path, "many.json", "drick-dots-2x3",
               lambda d: d.update(markers=d["markers"] * 1000))
    assert msg == (f"{tmp_path / 'many.json'}: markers: 6000 markers, more than the "
                   f"{LIMITS.max_markers} a layout may hold; keep at most {LIMITS.max_markers}")
    msg = _bad(tmp_path, "none.json", "drick-dots-2x3", lambda d: d.update(markers=[]))
    assert msg.endswith("markers: a layout needs at least one marker")


def test_error_invalid_json_and_missing_file(tmp_path):
    msg = _error(_write(tmp_path, "broken.json", '{\n  "schema": "x",\n  "name": ,\n}'))
    assert "broken.json" in msg and "line 3" in msg and "column" in msg
    msg = _error(_write(tmp_path, "dupkey.json", '{"name": "a", "name": "b"}'))
    assert "dupkey.json" in msg and "'name'" in msg
    msg = _error(tmp_path / "nowhere.json")
    assert "nowhere.json" in msg and "no such" in msg


def test_error_overlapping_ids_name_both_layouts(tmp_path):
    raw = _raw("drick-aruco-centre")
    raw["name"] = "my-brick"
    raw["first_id"] = 45
    raw["markers"][0]["dictionary"] = "DICT_4X4_1000"  # same family as DICT_4X4_50/_100
    p = _write(tmp_path, "my-brick.json", raw)
    with pytest.raises(LayoutError) as info:
        load_layouts([shipped_layouts_dir() / "drick-aruco-pyramids.json", p])
    msg = str(info.value)
    assert "drick-aruco-pyramids" in msg and "drick-aruco-pyramids.json" in msg
    assert "my-brick" in msg and "my-brick.json" in msg
    assert "45..49" in msg
    # Other family: no clash.
    raw["markers"][0]["dictionary"] = "DICT_5X5_100"
    load_layouts([shipped_layouts_dir() / "drick-aruco-pyramids.json",
                  _write(tmp_path, "other.json", raw)])
    # Same name twice is refused too.
    with pytest.raises(LayoutError, match="same name"):
        load_layouts([shipped_layouts_dir() / "landing-pad.json"] * 2)


# ---- meshes -------------------------------------------------------------------------------


def test_meshes():
    from drovisio.mesh_file import load_layout_mesh
    from drovisio.meshes import drick_mesh, landing_pad_mesh

    m = drick_mesh()
    assert m.is_watertight and m.is_volume
    frustum = 0.02 / 3 * (0.075**2 + 0.07**2 + 0.075 * 0.07)
    assert m.volume == pytest.approx(0.30 * 0.15 * 0.10 + 2 * frustum, rel=1e-9)
    np.testing.assert_allclose(m.bounds, [[-0.15, -0.075, -0.10], [0.15, 0.075, 0.02]])
    pad = landing_pad_mesh()
    assert pad.is_watertight
    np.testing.assert_allclose(pad.bounds, [[-0.3, -0.3, -0.01], [0.3, 0.3, 0.0]])
    for name, ref in (("drick-aruco-pyramids", m), ("landing-pad", pad)):
        lay = _shipped(name)
        assert lay.mesh_path().is_file()
        loaded = load_layout_mesh(lay)
        assert loaded.is_watertight
        assert loaded.volume == pytest.approx(ref.volume, rel=1e-6)
