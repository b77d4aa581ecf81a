"""Fuzzing every reader of outside input and every JSON route (hypothesis).

Properties, for inputs derived from valid files by mutation (numbers replaced by NaN, ±inf,
huge, negative or text; keys dropped, duplicated or renamed; deep nesting; truncation; random
bytes) and for arbitrary JSON:

* a reader either returns a value or raises the project's one input error
  (:class:`drovisio.errors.InputError`) with a one-line message — never anything else;
* every JSON route answers without a 500, whatever the body;
* the work is bounded (input sizes, example counts; no wall-clock deadline: a busy machine
  is not a failure) and no output file is left half
  written.

Runs are derandomized (the same examples in CI and here) and bounded: about a minute in all.
The number of inputs tried per target is printed at the end of the test session.
"""

from __future__ import annotations

import json
import math
import random
import string
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drovisio.errors import InputError
from drovisio.resources import layouts_dir, sample_sessions_dir, scenarios_dir

SAMPLE = sample_sessions_dir()
TRIED: dict[str, int] = {}

FUZZ = settings(max_examples=400, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large])


def tried(name: str) -> None:
    TRIED[name] = TRIED.get(name, 0) + 1


@pytest.fixture(scope="session", autouse=True)
def _report_counts(request):
    """tests/conftest.py prints these counts in the session summary."""
    request.config.fuzz_tried = TRIED
    yield


# ------------------------------------------------------------------ mutations of valid text

WEIRD = ["nan", ".nan", "NaN", "inf", "-inf", "Infinity", "1e308", "-1e308", "1e-320", "-1",
         "0", "99999999999999999999", "abc", '"abc"', "null", "true", "[]", "{}", "[1, 2",
         "&a", "*a", "!!python/object:os.system", "'", '"', "\\x00"]


def mutate_bytes(raw: bytes, seed: int, flips: int, cut: float, cut_share: float = 0.3,
                 min_len: int = 0) -> bytes:
    """``flips`` random bytes of a valid file changed; when ``cut < cut_share`` the file is
    also cut short (to ``cut / cut_share`` of its length, ``min_len`` bytes at least)."""
    data = bytearray(raw)
    rnd = random.Random(seed)
    for _ in range(flips):
        data[rnd.randrange(len(data))] = rnd.randrange(256)
    if cut < cut_share:
        data = data[:max(min_len, int(len(data) * cut / cut_share))]
    return bytes(data)


def mutate(text: str, rnd: random.Random, n: int) -> str:
    """``n`` random edits of a valid file's text."""
    for _ in range(n):
        op = rnd.randrange(8)
        if op == 0:      # a number becomes something weird
            nums = [m for m in _numbers(text)]
            if nums:
                a, b = rnd.choice(nums)
                text = text[:a] + rnd.choice(WEIRD) + text[b:]
        elif op == 1:    # a line disappears
            lines = text.splitlines()
            if lines:
                del lines[rnd.randrange(len(lines))]
                text = "\n".join(lines)
        elif op == 2:    # a line is duplicated
            lines = text.splitlines()
            if lines:
                i = rnd.randrange(len(lines))
                lines.insert(i, lines[i])
                text = "\n".join(lines)
        elif op == 3:    # cut short
            text = text[:rnd.randrange(len(text) + 1)]
        elif op == 4:    # random characters somewhere
            i = rnd.randrange(len(text) + 1)
            text = text[:i] + "".join(rnd.choice(string.printable) for _ in range(5)) + text[i:]
        elif op == 5:    # deep nesting
            i = rnd.randrange(len(text) + 1)
            depth = rnd.choice([50, 500, 5000])
            text = text[:i] + "[" * depth + "]" * depth + text[i:]
        elif op == 6:    # a number becomes a huge one
            nums = [m for m in _numbers(text)]
            if nums:
                a, b = rnd.choice(nums)
                text = text[:a] + str(rnd.choice([10 ** 6, 10 ** 9, 2 ** 31, 10 ** 30])) + text[b:]
        else:            # a key renamed
            i = text.find(":", rnd.randrange(len(text) + 1))
            if i > 0:
                text = text[:i] + "_x" + text[i:]
    return text


def _numbers(text: str) -> list[tuple[int, int]]:
    import re

    return [(m.start(), m.end()) for m in re.finditer(r"-?\d+(\.\d+)?(e[-+]?\d+)?", text)]


def valid_texts() -> dict[str, list[str]]:
    import tempfile

    from drovisio.camera import Camera
    from drovisio.camera_file import save_camera

    out: dict[str, list[str]] = {"camera": [], "layout": [], "mount": [], "scenario": []}
    with tempfile.TemporaryDirectory() as d:
        for name, fmt in (("c.yaml", None), ("c.xml", None), ("c.json", None),
                          ("c.ros.yaml", "ros")):
            for cam in (Camera.drone_webcam(),
                        Camera.from_fov(1280, 800, 150, dist=[0.01, 0.0, 0.0, 0.0],
                                        model="fisheye")):
                out["camera"].append(save_camera(cam, Path(d) / name, fmt).read_text())
    out["layout"] = [p.read_text() for p in sorted(layouts_dir().glob("*.json"))]
    out["mount"] = [(SAMPLE / "approach" / "mount.json").read_text()]
    out["scenario"] = [p.read_text() for p in sorted(scenarios_dir().glob("*.yaml"))]
    return out


VALID = valid_texts()


def _check_error(e: Exception) -> None:
    assert isinstance(e, InputError), f"{type(e).__name__}: {e}"
    # a listing of several problems has a line each (the CLI folds them into one)
    assert all(line.strip() for line in str(e).strip().splitlines()), "an empty line"
    assert len(str(e)) < 5000, "error message too long (a hostile file is quoted whole?)"


# ------------------------------------------------------------------ readers


@FUZZ
@given(seed=st.integers(0, 2 ** 32 - 1), edits=st.integers(1, 4),
       which=st.integers(0, len(VALID["camera"]) - 1))
def test_camera_reader(tmp_path_factory, seed, edits, which):
    from drovisio.camera_file import load_camera

    text = mutate(VALID["camera"][which], random.Random(seed), edits)
    suffix = [".yaml", ".xml", ".json", ".yaml"][which // 2]
    p = tmp_path_factory.mktemp("cam") / f"camera{suffix}"
    p.write_text(text)
    tried("camera file")
    try:
        cam = load_camera(p)
    except Exception as e:  # noqa: BLE001
        _check_error(e)
        return
    assert np.all(np.isfinite(cam.K)) and cam.fx > 0 and 0 < cam.width <= 20000


@FUZZ
@given(seed=st.integers(0, 2 ** 32 - 1), edits=st.integers(1, 4),
       which=st.integers(0, len(VALID["layout"]) - 1))
def test_layout_reader(seed, edits, which):
    from drovisio.layout import parse_layout

    text = mutate(VALID["layout"][which], random.Random(seed), edits)
    tried("layout file")
    try:
        lay = parse_layout(text, "fuzzed.json")
    except Exception as e:  # noqa: BLE001
        _check_error(e)
        return
    assert np.all(np.isfinite(lay.dimensions_m)) and np.all(lay.dimensions_m > 0)


@FUZZ
@given(seed=st.integers(0, 2 ** 32 - 1), edits=st.integers(1, 4))
def test_mount_reader(tmp_path_factory, seed, edits):
    from drovisio.mount import load_mount

    text = mutate(VALID["mount"][0], random.Random(seed), edits)
    p = tmp_path_factory.mktemp("mount") / random.Random(seed).choice(["m.json", "m.yaml"])
    p.write_text(text)
    tried("mount file")
    try:
        m = load_mount(p)
    except Exception as e:  # noqa: BLE001
        _check_error(e)
        return
    assert np.all(np.isfinite(m.body_from_camera))


@settings(FUZZ, max_examples=150)
@given(seed=st.integers(0, 2 ** 32 - 1), edits=st.integers(1, 4))
def test_scenario_reader(seed, edits):
    from drovisio.mission.scenario import parse_scenario

    text = mutate(VALID["scenario"][0], random.Random(seed), edits)
    tried("scenario file")
    try:
        parse_scenario(text, "fuzzed.yaml")
    except Exception as e:  # noqa: BLE001
        _check_error(e)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10 ** 12, 10 ** 12)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4)
    | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=20)


@FUZZ
@given(lines=st.lists(st.one_of(
    json_values,
    st.fixed_dictionaries({"file": st.text(max_size=10) | st.integers(),
                           "gravity": st.lists(st.floats(allow_nan=True), max_size=4)
                           | json_values},
                          optional={"frame": st.integers(-5, 10 ** 9) | json_values})),
    max_size=5))
def test_gravity_file_reader(tmp_path_factory, lines):
    from drovisio.commands.detect import GravityTable

    p = tmp_path_factory.mktemp("grav") / "g.jsonl"
    p.write_text("\n".join(json.dumps(x) for x in lines))
    tried("gravity file")
    try:
        t = GravityTable.load(str(p))
    except Exception as e:  # noqa: BLE001
        _check_error(e)
        return
    for i in t.exact.values():
        g = t.unit[i]
        assert np.all(np.isfinite(g)) and abs(np.linalg.norm(g) - 1) < 1e-9


def _image_bytes() -> list[bytes]:
    import cv2

    img = cv2.imread(str(SAMPLE / "calibration" / "view_00.jpg"))
    small = cv2.resize(img, (64, 48))
    out = []
    for ext in (".png", ".jpg", ".bmp", ".tiff", ".webp", ".pgm"):
        ok, buf = cv2.imencode(ext, small if ext != ".pgm" else small[:, :, 0])
        out.append(buf.tobytes())
    return out


IMAGES = _image_bytes()


@FUZZ
@given(which=st.integers(0, len(IMAGES) - 1), seed=st.integers(0, 2 ** 32 - 1),
       flips=st.integers(0, 20), cut=st.floats(0, 1))
def test_image_decoder(which, seed, flips, cut):
    from drovisio.images import decode_image

    data = mutate_bytes(IMAGES[which], seed, flips, cut)
    tried("image")
    try:
        img, notes = decode_image(data, "x.bin")
    except Exception as e:  # noqa: BLE001
        _check_error(e)
        return
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3


def _mesh_bytes() -> list[tuple[str, bytes]]:
    import trimesh

    box = trimesh.creation.box(extents=(0.3, 0.15, 0.12))
    out = [("m.stl", (layouts_dir() / "meshes" / "drick.stl").read_bytes())]
    for ext in ("obj", "ply", "off", "glb"):
        out.append((f"m.{ext}", box.export(file_type=ext)
                    if isinstance(box.export(file_type=ext), bytes)
                    else box.export(file_type=ext).encode()))
    return out


MESHES = _mesh_bytes()


@settings(FUZZ, max_examples=200)
@given(which=st.integers(0, len(MESHES) - 1), seed=st.integers(0, 2 ** 32 - 1),
       flips=st.integers(0, 30), cut=st.floats(0, 1))
def test_mesh_reader(which, seed, flips, cut):
    from drovisio.designer.model import DesignDocument, DesignError

    name, raw = MESHES[which]
    data = mutate_bytes(raw, seed, flips, cut)
    tried("mesh")
    try:
        DesignDocument.from_mesh_bytes(data, name)
    except DesignError:
        pass


@settings(FUZZ, max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), flips=st.integers(1, 200), cut=st.floats(0, 1))
def test_video_reader(tmp_path_factory, seed, flips, cut):
    from drovisio.sources import EndOfStream, VideoFileReader

    raw = mutate_bytes(VIDEO_BYTES, seed, flips, cut, cut_share=0.5, min_len=1)
    p = tmp_path_factory.mktemp("vid") / "v.avi"
    p.write_bytes(raw)
    tried("video")
    r = VideoFileReader(p)
    try:
        r.open()
    except OSError:
        return
    try:
        for _ in range(200):
            try:
                f = r.read()
            except EndOfStream:
                break
            assert f is not None and (f.image is None) == (f.error is not None)
    finally:
        r.close()


def _small_video() -> bytes:
    import tempfile

    import cv2

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "v.avi"
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
        for i in range(20):
            w.write(np.full((48, 64, 3), i * 10, np.uint8))
        w.release()
        return path.read_bytes()


VIDEO_BYTES = _small_video()


# ------------------------------------------------------------------ JSON routes


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    from fastapi.testclient import TestClient

    from webtool.app import create_app
    from webtool.services import close_services
    from webtool.settings import Settings

    d = tmp_path_factory.mktemp("web")
    app = create_app(Settings(calibration_dir=d / "cal", designer_layouts_dir=d,
                              replay_dir=d, mount_dir=d / "mount"))
    c = TestClient(app, base_url="http://127.0.0.1:8080", raise_server_exceptions=False)
    # a model to edit, so that the designer's edit routes do real work
    c.post("/api/designer/open", json={"example": "mesh:drick.stl"})
    yield c
    close_services(app)


JSON_ROUTES = [
    "/api/designer/open", "/api/designer/units", "/api/designer/frame", "/api/designer/mode",
    "/api/designer/click", "/api/designer/select", "/api/designer/markers/0",
    "/api/designer/defaults", "/api/designer/layout", "/api/designer/fix",
    "/api/designer/save", "/api/calibration/auto", "/api/calibration/session",
    "/api/replay/load", "/api/replay/seek", "/api/replay/speed", "/api/live/target",
    "/api/mount/preview", "/api/calibration/square", "/api/calibration/lens",
]
FIELDS = ["example", "units", "action", "angle_deg", "mode", "origin", "direction", "index",
          "size_mm", "color", "slot", "rotate_deg", "nudge_mm", "centre", "code_size_mm",
          "name", "first_id", "instances", "symmetry", "op", "marker", "overwrite", "on",
          "board", "square_m", "path", "t", "x", "spec", "angles", "height_m", "model"]
weird_numbers = st.sampled_from([float("nan"), float("inf"), -float("inf"), 1e308, -1e308,
                                 1e-300, 0.0, -0.0, 2 ** 63, -1])
field_values = json_values | weird_numbers | st.lists(weird_numbers, max_size=4)


def _encode(body) -> bytes:
    # NaN and Infinity as JavaScript's JSON.parse would refuse but Python's json accepts
    return json.dumps(body, allow_nan=True).encode()


@settings(FUZZ, max_examples=1500, deadline=None)
@given(route=st.sampled_from(JSON_ROUTES),
       body=st.dictionaries(st.sampled_from(FIELDS), field_values, max_size=4) | json_values)
def test_json_routes_never_answer_500(client, route, body):
    tried("JSON route")
    r = client.post(route, content=_encode(body), headers={"content-type": "application/json"})
    assert r.status_code < 500 or r.status_code in (503, 507), (route, body, r.status_code,
                                                               r.text)
    if r.headers.get("content-type", "").startswith("application/json"):
        r.json()


@settings(FUZZ, max_examples=30, deadline=None)
@given(route=st.sampled_from(JSON_ROUTES),
       raw=st.sampled_from([b"[" * 100000 + b"]" * 100000, b'{"a":' * 50000, b"\xff\xfe",
                            b"NaN", b'{"spec": "' + b"x" * 2_000_000 + b'"}', b""]))
def test_json_routes_survive_hostile_bodies(client, route, raw):
    tried("JSON route (hostile body)")
    r = client.post(route, content=raw, headers={"content-type": "application/json"})
    assert r.status_code < 500, (route, raw[:40], r.status_code, r.text)


def test_mutations_change_the_files():
    """The mutator is not a no-op (a fuzz test that feeds valid files proves nothing)."""
    rnd = random.Random(0)
    changed = sum(mutate(t, rnd, 2) != t for t in VALID["camera"] * 10)
    assert changed >= 70
    assert not math.isnan(1.0)
