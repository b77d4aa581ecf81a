"""Class: limits — sizes, digits and memory estimated before work, limits that agree, origins
compared with their scheme, dictionary facts from OpenCV.

* Numbers: one helper (:mod:`drovisio.bounds`); integers of thousands of digits in JSON and
  YAML files are refused by the readers (Python's own limit is 4,300 digits).
* Sizes: an image file larger than any image Drovisio decodes is refused from its size and
  header, never read whole; an over-size Radiance ``.hdr`` leaves nothing in ``/tmp``; a
  render's memory is estimated before it starts (a 20000×20000 camera in a study protocol).
* Limits that agree: every route that takes a file upload is exempt from the JSON body limit
  (the mount page's photos as the calibration page's); the mount offset bound is one.
* Request bodies: one that does not even parse (nested 100,000 deep, not UTF-8, a number of
  5,000 digits, not JSON) is a one-line 422 naming the body, like any bad input.
* Origins: only the tool's own scheme, host and port may write (``https://`` is another site
  than the ``http://`` tool on the same port).
* ``charuco:COLSxROWS:DICT_APRILTAG_16h5``: the dictionary's size from OpenCV's object.
"""

from __future__ import annotations

import inspect
import io
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st

from drovisio.bounds import check_whole, parse_number, parse_whole
from drovisio.errors import InputError
from drovisio.images import ImageError, decode_image, read_image

LOCAL = "http://127.0.0.1:8080"


def _settings(n: int):
    from hypothesis import HealthCheck, settings

    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


# ------------------------------------------------------------------ numbers


@_settings(200)
@given(digits=st.integers(31, 6000), sign=st.sampled_from(["", "-", "+"]))
def test_numbers_of_many_digits_are_refused_by_the_one_helper(ledger, digits, sign):
    ledger.tried_one("limits: digits")
    with pytest.raises(ValueError, match="digits"):
        parse_whole(sign + "7" * digits)
    with pytest.raises(ValueError):       # no range: a float, bounded by its length
        parse_number(sign + "7" * (digits + 64))
    with pytest.raises(InputError, match="f.yaml: seed"):
        check_whole("7" * digits, "f.yaml: seed")


def test_the_helper_keeps_numbers_in_range_and_names_the_range():
    assert parse_whole("42", 1, 100) == 42 and parse_number("0.5", 0, 1) == 0.5
    with pytest.raises(ValueError, match="from 1 to 1000"):
        parse_whole("1001", 1, 1000)
    with pytest.raises(ValueError, match="not a whole number"):
        parse_whole("1e20", 1, 1000)
    with pytest.raises(ValueError, match="not a finite number"):
        parse_number("nan")


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_readers_refuse_an_integer_of_5000_digits(tmp_path, ledger, suffix):
    from drovisio.mount import MountError, load_mount

    p = tmp_path / f"mount{suffix}"
    big = "9" * 5000
    p.write_text('{"schema": "drovisio/mount@1", "camera": {"tilt_deg": ' + big + "}}")
    ledger.tried_one("limits: digits")
    with pytest.raises(MountError) as e:
        load_mount(p)
    assert str(p) in str(e.value) and "digits" in str(e.value)


def test_a_protocol_seed_of_5000_digits_and_a_nul_path_are_refused(cli, tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text("schema: drovisio/study-protocol@1\nname: x\nseed: " + "9" * 5000 + "\n"
                 "layouts: [{name: c, layout: drick-aruco-centre}]\n"
                 "steps: [{figure: '6.7', layout: c, vary: distance, value: 1.0}]\n")
    rc, _, err = cli("study", "run", "--protocol", p, "--out", tmp_path / "o",
                     cls="limits: files")
    assert rc == 2 and str(p) in err and "digits" in err, err
    p.write_text("schema: drovisio/study-protocol@1\nname: x\ncamera: \"a\\0b.yaml\"\n"
                 "layouts: [{name: c, layout: drick-aruco-centre}]\n"
                 "steps: [{figure: '6.7', layout: c, vary: distance, value: 1.0}]\n")
    rc, _, err = cli("study", "run", "--protocol", p, "--out", tmp_path / "o",
                     cls="limits: files")
    assert rc == 2 and "camera" in err and "NUL" in err, err


# ------------------------------------------------------------------ sizes


def test_an_image_file_larger_than_any_image_is_refused_unread(tmp_path, monkeypatch, ledger):
    p = tmp_path / "huge.png"
    ok, png = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    with open(p, "wb") as f:
        f.write(png.tobytes())
        f.truncate(20 * 2**30)               # 20 GB, sparse: a real read would take minutes
    read = []
    real_open = open

    def counting_open(path, mode="r", *a, **kw):
        fh = real_open(path, mode, *a, **kw)
        if "b" in mode:
            inner = fh.read

            def rd(n=-1):
                data = inner(n)
                read.append(len(data))
                return data

            fh.read = rd
        return fh

    monkeypatch.setattr("builtins.open", counting_open)
    ledger.tried_one("limits: image sizes")
    with pytest.raises(ImageError, match="MiB"):
        read_image(p)
    assert sum(read) <= 64 * 1024, "only the header was read"


def _hdr(w: int, h: int) -> bytes:
    ok, buf = cv2.imencode(".hdr", np.random.default_rng(0).random((64, 80, 3), np.float32))
    return bytes(buf).replace(b"-Y 64 +X 80", f"-Y {h} +X {w}".encode())


def _opencv_temp_files() -> set[str]:
    return {n for n in os.listdir(tempfile.gettempdir())
            if n.startswith(("__opencv_temp", "drovisio-decode-"))}


def test_an_over_size_radiance_image_leaves_nothing_in_tmp(ledger):
    before = _opencv_temp_files()
    for w, h in ((60000, 60000), (20001, 10), (0, 5)):
        ledger.tried_one("limits: image sizes")
        with pytest.raises(ImageError):
            decode_image(_hdr(w, h), "x.hdr")
    img, _ = decode_image(_hdr(80, 64), "x.hdr")      # a sound one still decodes
    assert img.shape == (64, 80, 3)
    assert _opencv_temp_files() == before


def test_an_over_size_radiance_upload_leaves_nothing_in_tmp(tmp_path, ledger):
    from webtool.app import create_app
    from webtool.settings import Settings

    before = _opencv_temp_files()
    data = _hdr(60000, 60000) + os.urandom(9 * 2**20)
    with TestClient(create_app(Settings(calibration_dir=tmp_path)), base_url=LOCAL,
                    raise_server_exceptions=False) as c:
        for _ in range(3):
            ledger.tried_one("limits: uploads")
            r = c.post("/api/calibration/upload", files={"files": ("big.hdr", data)})
            assert r.status_code < 500, r.text
    assert _opencv_temp_files() == before


def test_a_render_too_large_for_memory_is_refused_before_it_starts(cli, tmp_path, ledger):
    cam = tmp_path / "cam.yaml"
    cam.write_text("%YAML:1.0\n---\nimage_width: 20000\nimage_height: 20000\n"
                   "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                   "   data: [ 15000., 0., 9999.5, 0., 15000., 9999.5, 0., 0., 1. ]\n"
                   "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n"
                   "   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n")
    p = tmp_path / "p.yaml"
    p.write_text("schema: drovisio/study-protocol@1\nname: big\ncamera: cam.yaml\n"
                 "layouts: [{name: c, layout: drick-aruco-centre}]\n"
                 "steps: [{figure: '6.7', layout: c, vary: distance, value: 1.0, frames: 1}]\n")
    ledger.tried_one("limits: render memory")
    rc, _, err = cli("study", "run", "--protocol", p, "--out", tmp_path / "o",
                     "--memory-seconds", "0", cls="limits: files", seconds=180)
    assert rc == 2 and "20000x20000" in err and "GiB" in err, err


# ------------------------------------------------------------------ limits that agree


def test_every_upload_route_is_exempt_from_the_json_body_limit():
    import importlib
    import pkgutil

    from fastapi import UploadFile

    import webtool.app as webapp
    from webtool import routes

    uploads = set()
    every = []
    for m in pkgutil.iter_modules(routes.__path__):
        router = getattr(importlib.import_module(f"webtool.routes.{m.name}"), "router", None)
        every += list(router.routes) if router is not None else []
    for route in every:
        endpoint = getattr(route, "endpoint", None)
        if endpoint is None:
            continue
        for param in inspect.signature(endpoint).parameters.values():
            if "UploadFile" in str(param.annotation) or param.annotation is UploadFile:
                uploads.add(route.path)
    assert uploads and "/api/mount/measure" in uploads
    assert all(path in webapp._UPLOADS for path in uploads), uploads


def test_mount_photos_above_a_mebibyte_reach_the_service(tmp_path, ledger):
    from webtool.app import create_app
    from webtool.settings import Settings

    big = np.random.default_rng(1).integers(0, 255, (900, 1200, 3), np.uint8)
    ok, png = cv2.imencode(".png", big)
    assert len(png) > 2**20
    with TestClient(create_app(Settings(mount_dir=tmp_path)), base_url=LOCAL,
                    raise_server_exceptions=False) as c:
        ledger.tried_one("limits: uploads")
        r = c.post("/api/mount/measure", files=[("files", ("a.png", png.tobytes())),
                                                ("files", ("b.png", png.tobytes()))])
    assert r.status_code != 413, r.text
    assert r.status_code < 500, r.text


def test_every_route_other_than_an_upload_keeps_the_json_limit(tmp_path, ledger,
                                                                monkeypatch):
    from webtool import app as webapp
    from webtool.app import create_app
    from webtool.settings import Settings

    big = b'{"aligned": true, "x": "' + b"a" * (2 * 2**20) + b'"}'

    def chunked():   # no Content-Length: counted while it streams
        for k in range(0, len(big), 65536):
            yield big[k:k + 65536]

    monkeypatch.setitem(webapp._UPLOADS, "/api/calibration/upload", 2**20)
    with TestClient(create_app(Settings(mount_dir=tmp_path, replay_dir=tmp_path)),
                    base_url=LOCAL, raise_server_exceptions=False) as c:
        ledger.tried["limits: body"] += 4
        # a route whose path begins like an upload's is not one
        r = c.post("/api/mount/measure-live", content=big,
                   headers={"Content-Type": "application/json"})
        assert r.status_code == 413 and "over 1 MiB" in r.json()["detail"], r.text
        r = c.post("/api/mount/measure-live", content=chunked(),
                   headers={"Content-Type": "application/json"})
        assert r.status_code == 413 and "over 1 MiB" in r.json()["detail"], r.text
        r = c.post("/api/designer/mode", content=chunked(),
                   headers={"Content-Type": "application/json"})
        assert r.status_code == 413, r.text
        # an upload's request in all: here cut to 1 MiB, two 0.6 MiB pictures are over it
        pic = b"\x89PNG" + b"\0" * (600 * 1024)
        r = c.post("/api/calibration/upload", files=[("files", ("a.png", pic)),
                                                     ("files", ("b.png", pic))])
        assert r.status_code == 413 and "over 1 MiB" in r.json()["detail"], r.text


_UNPARSED = [
    (b'{"on": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
     "body: nested too deeply; send a plain JSON object"),
    (b'{"on": "\xff\xfe"}', "body: not UTF-8 text (byte 8); send JSON in UTF-8"),
    (b'{"on": ' + b"9" * 5000 + b"}",
     "body: a number has thousands of digits; give a number of at most 30 digits"),
    (b'{"on": tru', "body: not valid JSON at character 7: Expecting value"),
]


@pytest.mark.parametrize(("body", "detail"), _UNPARSED)
def test_a_body_that_does_not_parse_is_a_one_line_422(tmp_path, ledger, body, detail):
    from webtool.app import create_app
    from webtool.settings import Settings

    app = create_app(Settings(calibration_dir=tmp_path, designer_layouts_dir=tmp_path))
    with TestClient(app, base_url=LOCAL, raise_server_exceptions=False) as c:
        for path in ("/api/calibration/auto", "/api/live/target", "/api/designer/defaults"):
            ledger.tried["limits: body"] += 1
            r = c.post(path, content=body, headers={"Content-Type": "application/json"})
            assert r.status_code == 422 and r.json() == {"detail": detail}, (path, r.text)
        # what is not about the body keeps its own answer
        assert c.get("/api/nothing-here").status_code == 404
        assert c.put("/api/calibration/auto").status_code == 405


# ------------------------------------------------------------------ origins


origins = st.builds(
    lambda scheme, host, port: f"{scheme}://{host}{port}",
    st.sampled_from(["http", "https", "HTTP", "ws", "wss", "ftp", "file", "null", "",
                     "javascript", "http2"]),
    st.sampled_from(["127.0.0.1", "localhost", "127.0.0.1.", "evil.example", "[::1]",
                     "127.0.0.2", "user@127.0.0.1", "127.0.0.1@evil.example"]),
    st.sampled_from([":8080", "", ":80", ":443", ":08080", ":8081", ":99999", ":"]))


@_settings(300)
@given(origin=origins | st.text(max_size=40))
def test_only_the_tools_own_origin_may_write(tmp_path_factory, ledger, origin):
    from webtool.app import create_app
    from webtool.settings import Settings

    global _ORIGIN_CLIENT
    if _ORIGIN_CLIENT is None:
        app = create_app(Settings(replay_dir=tmp_path_factory.mktemp("o")))
        _ORIGIN_CLIENT = TestClient(app, base_url=LOCAL, raise_server_exceptions=False)
    if not origin.isascii() or any(ord(ch) < 32 or ord(ch) == 127 for ch in origin):
        return                            # no HTTP client sends such a header
    ledger.tried_one("origins: writes")
    r = _ORIGIN_CLIENT.post("/api/replay/speed", json={"speed": 2},
                            headers={"Origin": origin})
    own = origin.lower() in ("http://127.0.0.1:8080",)
    if r.status_code != 403 and not own:
        ledger.failure("cross-origin writes")
    assert (r.status_code == 403) is (not own), (origin, r.status_code, r.text)


_ORIGIN_CLIENT = None


def test_https_origin_is_another_site_than_the_http_tool(ledger):
    from webtool.access import _same_origin as same
    assert same("http://127.0.0.1:8391", "127.0.0.1:8391", "http")
    assert not same("https://127.0.0.1:8391", "127.0.0.1:8391", "http")
    assert same("https://127.0.0.1:8391", "127.0.0.1:8391", "https")
    assert not same("http://127.0.0.1:8391", "127.0.0.1:8391", "wss")
    assert same("http://127.0.0.1:8391", "127.0.0.1:8391", "ws")


# ------------------------------------------------------------------ dictionaries


def test_charuco_boards_of_apriltag_families_print_and_are_bounded(cli, tmp_path):
    pdf = tmp_path / "b.pdf"
    rc, _, err = cli("calibrate", "board", "--board", "charuco:5x4:DICT_APRILTAG_16h5",
                     "--pdf", pdf, cls="limits: dictionaries")
    assert rc == 0, err
    assert pdf.read_bytes()[:5] == b"%PDF-"
    rc, _, err = cli("calibrate", "board", "--board", "charuco:9x6:DICT_APRILTAG_16h5",
                     "--pdf", tmp_path / "c.pdf", cls="limits: dictionaries")
    assert rc == 2 and "35 markers" in err and "has 30" in err, err
    rc, _, err = cli("calibrate", "board", "--board", "charuco:9x6:DICT_NOPE",
                     "--pdf", tmp_path / "d.pdf", cls="limits: dictionaries")
    assert rc == 2 and "unknown ArUco dictionary" in err


def test_the_calibration_page_prints_an_apriltag_charuco_board(tmp_path):
    from webtool.app import create_app
    from webtool.settings import Settings

    with TestClient(create_app(Settings(calibration_dir=tmp_path,
                                        calibration_board="charuco:5x4:DICT_APRILTAG_16h5",
                                        source="0")),
                    base_url=LOCAL, raise_server_exceptions=False) as c:
        r = c.get("/api/calibration/board.pdf")
    assert r.status_code == 200, r.text
    assert r.content[:5] == b"%PDF-"
    assert "charuco-5x4" in r.headers["content-disposition"]


_ = (io, Path)
