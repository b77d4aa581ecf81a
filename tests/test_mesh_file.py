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
from drovisio.mesh_file import MAX_DEPTH, MAX_FACES, MAX_NODES, read_mesh
from drovisio.meshes import load_layout_mesh


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
