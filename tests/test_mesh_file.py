"""Mesh files from outside: a glTF scene's declared parts, nesting and triangles are bounded
before anything is built, for an upload and for a layout's mesh alike."""

from __future__ import annotations

import json
import shutil
import struct

import numpy as np
import pytest

from drovisio.errors import InputError
from drovisio.layout import load_layout, shipped_layouts_dir
from drovisio.mesh_file import (
    MAX_DEPTH,
    MAX_FACES,
    MAX_MESH_BYTES,
    MAX_NODES,
    load_layout_mesh,
    read_mesh,
)


def _glb(nodes: list[dict], roots: list[int], count: int = 3) -> bytes:
    """A GLB of one triangle (its accessor declaring ``count`` vertices) placed by ``nodes``."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": roots}],
           "nodes": nodes, "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
           "buffers": [{"byteLength": len(pos)}],
           "bufferViews": [{"buffer": 0, "byteLength": len(pos)}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": count,
                          "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}]}
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(pos), b"BIN\0") + pos
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_a_scene_of_a_few_placed_parts_is_read_whole():
    nodes = [{"mesh": 0, "translation": [2.0 * k, 0, 0]} for k in range(5)]
    mesh = read_mesh(_glb(nodes, list(range(5))), "five.glb")
    assert len(mesh.faces) == 5
    assert mesh.bounds[1][0] == pytest.approx(9.0)


@pytest.mark.parametrize("case, words", [
    ("many", f"more than {MAX_NODES} placed parts"),
    ("deep", f"nested more than {MAX_DEPTH} deep"),
    ("shared", f"more than {MAX_FACES:,} triangles"),   # one mesh in a few nodes, each 10^6
])
def test_a_scene_that_asks_for_too_much_is_refused_before_it_is_built(case, words):
    if case == "many":       # 10^4 + 1 placements of one triangle: a few hundred kB
        data = _glb([{"mesh": 0}] * (MAX_NODES + 1), list(range(MAX_NODES + 1)))
    elif case == "deep":     # a chain of parts (costs trimesh time quadratic in its depth)
        nodes = [{"children": [k + 1]} for k in range(MAX_DEPTH + 10)] + [{"mesh": 0}]
        data = _glb(nodes, [0])
    else:                    # an accessor declaring 3·10^6 vertices, placed 3 times
        data = _glb([{"mesh": 0}] * 3, [0, 1, 2], count=3_000_000)
    with pytest.raises(InputError) as e:
        read_mesh(data, "bomb.glb")
    msg = str(e.value)
    assert msg.startswith("bomb.glb: ") and words in msg and "STL" in msg and "\n" not in msg


def test_a_layout_naming_such_a_mesh_is_refused_in_one_line(tmp_path):
    shutil.copy(shipped_layouts_dir() / "drick-aruco-centre.json", tmp_path / "brick.json")
    doc = json.loads((tmp_path / "brick.json").read_text())
    doc["mesh"] = "bomb.glb"
    (tmp_path / "brick.json").write_text(json.dumps(doc))
    (tmp_path / "bomb.glb").write_bytes(_glb([{"mesh": 0}] * (MAX_NODES + 1),
                                             list(range(MAX_NODES + 1))))
    with pytest.raises(InputError) as e:
        load_layout_mesh(load_layout(tmp_path / "brick.json"))
    msg = str(e.value)
    assert "brick.json: mesh: bomb.glb: " in msg and "placed parts" in msg
    # the shipped layout's own mesh still loads through the same reader
    mesh = load_layout_mesh(load_layout(shipped_layouts_dir() / "drick-aruco-centre.json"))
    assert mesh is not None and len(mesh.faces) > 10 and np.all(np.isfinite(mesh.vertices))


def test_reading_an_image_leaves_pillows_own_limit_in_place():
    # Pillow's limit is process-wide: it guards every other decode (a mesh's textures)
    import struct as st
    import zlib

    from PIL import Image

    from drovisio.images import ImageError, decode_image, header_size

    def png(w: int, h: int) -> bytes:
        def chunk(t: bytes, d: bytes) -> bytes:
            return st.pack(">I", len(d)) + t + d + st.pack(">I", zlib.crc32(t + d))
        return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", st.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(b"\0" * (w + 1) * min(h, 8)))
                + chunk(b"IEND", b""))

    before = Image.MAX_IMAGE_PIXELS
    assert before is not None
    assert decode_image(png(8, 6), "small.png")[0].shape == (6, 8, 3)
    assert header_size(png(9000, 9000)) == (9000, 9000)
    with pytest.raises(ImageError, match=r"900 Mpx, more than the \d+ Mpx"):
        header_size(png(30000, 30000))
    assert Image.MAX_IMAGE_PIXELS == before


# ---- a layout's mesh: one reader for its bounds, the dots' occluders, the renderer, the views


def _dots_layout(folder, mesh: str, *, dimensions: bool = False):
    """The shipped dots layout in ``folder``, naming ``mesh`` (without dimensions: its bounds
    come from the mesh)."""
    doc = json.loads((shipped_layouts_dir() / "drick-dots-2x3.json").read_text())
    doc["mesh"] = mesh
    if not dimensions:
        doc.pop("dimensions")
    path = folder / "brick.json"
    path.write_text(json.dumps(doc))
    return path


def _hostile_mesh(tmp_path, case: str) -> tuple[str, str]:
    """(the layout's mesh field, what the reader answers after ``LAYOUT: mesh: ``)."""
    d = tmp_path / "lay"
    (d / "meshes").mkdir(parents=True, exist_ok=True)
    (tmp_path / "out.stl").write_bytes((shipped_layouts_dir() / "meshes/drick.stl").read_bytes())
    outside = f"is outside the folder {d}; only files inside it are read: copy the file there"
    if case == "dotdot":
        return "../out.stl", f"'../out.stl' {outside}"
    if case == "link-out":
        (d / "meshes/out.stl").symlink_to(tmp_path / "out.stl")
        return "meshes/out.stl", f"'meshes/out.stl' {outside}"
    if case == "dev-zero":
        (d / "meshes/zero.stl").symlink_to("/dev/zero")
        return "meshes/zero.stl", f"'meshes/zero.stl' {outside}"
    if case == "sparse":
        with open(d / "meshes/big.stl", "wb") as f:
            f.truncate(MAX_MESH_BYTES + 1)
        return "meshes/big.stl", (f"{d / 'meshes/big.stl'}: the mesh is larger than 256 MiB; "
                                  "is it the right file?")
    if case == "placed-1e8":   # 8 levels of 10 children: one triangle placed 10^8 times
        nodes = [{"children": [k + 1] * 10} for k in range(8)] + [{"mesh": 0}]
        (d / "meshes/bomb.glb").write_bytes(_glb(nodes, [0]))
        return "meshes/bomb.glb", (
            f"bomb.glb: the model's scene has more than {MAX_NODES} placed parts. Export the "
            "brick as one mesh (STL is the safest), or simplify the model in your CAD "
            "program, and use the new file.")
    if case == "not-a-mesh":
        (d / "meshes/notes.stl").write_text("the brick's notes\n")
        return "meshes/notes.stl", (
            "notes.stl: this is not a STL 3D model (its content does not match the format). "
            "Check that you picked the right file, or export the brick again as STL, OBJ, "
            "PLY, GLB/GLTF or OFF.")
    assert case == "missing"
    return "meshes/gone.stl", (f"'meshes/gone.stl' not found in {d}; put the mesh there or "
                               "remove the mesh field")


HOSTILE = ["dotdot", "link-out", "dev-zero", "sparse", "placed-1e8", "not-a-mesh", "missing"]


@pytest.mark.parametrize("case", HOSTILE)
def test_every_reader_of_a_layouts_mesh_refuses_it_in_the_same_line(tmp_path, case):
    from drovisio.detect.dots.model import DotModel
    from drovisio.synth import brick_mesh_for

    field, why = _hostile_mesh(tmp_path, case)
    path = _dots_layout(tmp_path / "lay", field)
    lay = load_layout(path)
    expected = f"{path}: mesh: {why}"
    colours = {c: i for i, c in enumerate(sorted(set(lay.dot_colors())))}
    readers = {"reader": lambda: load_layout_mesh(lay),
               "bounds": lambda: lay.dimensions_m,
               "occluders": lambda: DotModel.from_layout(lay, colours),
               "renderer": lambda: brick_mesh_for(lay)}
    for name, read in readers.items():
        with pytest.raises(InputError) as e:
            read()
        assert str(e.value) == expected, name


def _picture(d):
    import cv2

    from drovisio.camera import Camera
    from drovisio.camera_file import save_camera

    save_camera(Camera.drone_webcam(), d / "camera.yaml")
    cv2.imwrite(str(d / "frame.png"), np.full((480, 640, 3), 90, np.uint8))
    return d / "camera.yaml", d / "frame.png"


@pytest.mark.parametrize("case", HOSTILE)
def test_detect_refuses_a_layout_whose_mesh_is_hostile_in_one_line(tmp_path, capsys, case):
    from drovisio.cli import main

    field, why = _hostile_mesh(tmp_path, case)
    path = _dots_layout(tmp_path / "lay", field, dimensions=True)
    before = path.read_bytes()
    camera, frame = _picture(tmp_path)
    rc = main(["detect", "--camera", str(camera), "--layout", str(path), str(frame)])
    out, err = capsys.readouterr()
    assert (rc, out, err) == (2, "", f"drovisio detect: {path}: mesh: {why}\n")
    assert path.read_bytes() == before


def test_run_and_bench_refuse_a_mesh_outside_the_layouts_folder(tmp_path, capsys):
    from drovisio.cli import main

    field, why = _hostile_mesh(tmp_path, "link-out")
    path = _dots_layout(tmp_path / "lay", field, dimensions=True)
    camera, frame = _picture(tmp_path / "lay")
    sink = tmp_path / "poses.jsonl"
    rc = main(["run", "--source", str(frame), "--camera", str(camera), "--layout", str(path),
               "--sink", f"jsonl:{sink}", "--quiet"])
    out, err = capsys.readouterr()
    assert (rc, err) == (2, f"drovisio run: {path}: mesh: {why}\n") and not sink.exists()
    rc = main(["bench", "dots", "--layout", str(path), "--frames", "1", "--no-cache"])
    out, err = capsys.readouterr()
    assert (rc, err) == (2, f"drovisio bench: {path}: mesh: {why}\n")


def _without_image_size(camera):
    """``camera`` with its image size taken out (OpenCV's tutorial files omit it): the run
    then takes the first frame's size, and makes its detectors for it."""
    from drovisio.camera_file import load_camera

    lines = camera.read_text().splitlines(keepends=True)
    camera.write_text("".join(x for x in lines if not x.startswith(("image_width:",
                                                                     "image_height:"))))
    assert not load_camera(camera).size_known
    return camera


@pytest.mark.parametrize("record", ["rec", "rec.mcap"])
@pytest.mark.parametrize("case", ["missing", "not-a-mesh"])
def test_run_without_an_image_size_refuses_a_bad_mesh_before_writing_anything(
        tmp_path, capsys, case, record):
    """The detectors wait for the first frame's size, but the mesh is read before any sink or
    recording is opened: a sink's existing file is kept byte for byte, nothing is made."""
    from drovisio.cli import main

    field, why = _hostile_mesh(tmp_path, case)
    path = _dots_layout(tmp_path / "lay", field, dimensions=True)
    camera, frame = _picture(tmp_path)
    _without_image_size(camera)
    kept = tmp_path / "poses.jsonl"
    kept.write_bytes(b'{"file":"earlier.png","frame":0,"bricks":[]}\n')
    before = {p: p.read_bytes() if p.is_file() else None for p in tmp_path.rglob("*")}
    rc = main(["run", "--source", str(frame), "--camera", str(camera), "--layout", str(path),
               "--sink", f"jsonl:{kept}", "--sink", f"jsonl:{tmp_path / 'out' / 'new.jsonl'}",
               "--record", str(tmp_path / record), "--quiet"])
    out, err = capsys.readouterr()
    assert {p: p.read_bytes() if p.is_file() else None for p in tmp_path.rglob("*")} == before
    assert (rc, out, err) == (2, "", f"drovisio run: {path}: mesh: {why}\n")


def test_serve_refuses_a_bad_mesh_before_opening_its_sinks(tmp_path, capsys):
    import socket

    from drovisio.cli import main

    field, why = _hostile_mesh(tmp_path, "missing")
    path = _dots_layout(tmp_path / "lay", field, dimensions=True)
    camera, _ = _picture(tmp_path)
    _without_image_size(camera)
    before = sorted(tmp_path.rglob("*"))
    with socket.socket() as taken:   # a serve that got past its checks ends at its port
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        rc = main(["serve", "--port", str(taken.getsockname()[1]), "--camera", str(camera),
                   "--layout", str(path), "--sink", f"jsonl:{tmp_path / 'new.jsonl'}",
                   "--data", str(tmp_path / "data")])
    out, err = capsys.readouterr()
    assert sorted(tmp_path.rglob("*")) == before
    assert (rc, err) == (2, f"drovisio serve: {path}: mesh: {why}\n")


def test_an_absolute_mesh_path_is_refused_when_the_layout_is_read(tmp_path, capsys):
    from drovisio.cli import main

    (tmp_path / "lay").mkdir()
    path = _dots_layout(tmp_path / "lay", str(tmp_path / "out.stl"), dimensions=True)
    camera, frame = _picture(tmp_path)
    rc = main(["detect", "--camera", str(camera), "--layout", str(path), str(frame)])
    out, err = capsys.readouterr()
    assert (rc, out) == (2, "")
    assert err == (f"drovisio detect: {path}: mesh: mesh path '{tmp_path / 'out.stl'}' is "
                   "absolute; give it relative to the layout file, e.g. 'meshes/drick.stl'\n")


def test_a_shipped_layouts_mesh_is_the_file_as_trimesh_reads_it():
    # the one reader changes nothing for a valid mesh: the poses and renders stay the same
    import trimesh

    from drovisio.detect.dots.model import DotModel
    from drovisio.synth import brick_mesh_for

    for f in sorted(shipped_layouts_dir().glob("*.json")):
        lay = load_layout(f)
        ref = trimesh.load(lay.mesh_path(), force="mesh")
        for mesh in (load_layout_mesh(lay), brick_mesh_for(lay)):
            assert np.array_equal(mesh.vertices, ref.vertices)
            assert np.array_equal(mesh.faces, ref.faces)
        if lay.has_dots:
            colours = {c: i for i, c in enumerate(sorted(set(lay.dot_colors())))}
            occ = DotModel.from_layout(lay, colours).occluders
            tris = np.asarray(ref.vertices)[np.asarray(ref.faces)]
            assert len(occ) > 0 and all((tris == t).all(axis=(1, 2)).any() for t in occ)


def test_a_missing_mesh_with_a_shipped_name_is_built(tmp_path):
    from drovisio.meshes import drick_mesh

    lay = load_layout(_dots_layout(tmp_path, "meshes/drick.stl"))
    np.testing.assert_array_equal(load_layout_mesh(lay).vertices, drick_mesh().vertices)
    np.testing.assert_allclose(lay.dimensions_m, [0.30, 0.15, 0.12])
