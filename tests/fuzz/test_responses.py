"""Class: numbers that are not JSON in responses.

* The one response class (:class:`webtool.responses.JSONResponse`, the app's default and the
  one every route uses) cannot emit NaN or Infinity: any structure of numbers, numpy values
  and non-finite floats renders to strict JSON (what a browser's ``JSON.parse`` reads).
* The mount page over camera files that pass the schema but are extreme (coefficients of
  1e6, a 1×1 image, a focal length of 1e-3 or 1e9 px) and mounts at 90° and 180° tilt:
  ``GET /api/mount`` and every preview answer below 500 with strict JSON; the footprint
  drops the rays that meet no ground and says so.
"""

from __future__ import annotations

import json
import math

import numpy as np
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st

from webtool.responses import JSONResponse, json_safe

LOCAL = "http://127.0.0.1:8080"


def _settings(n: int):
    from hypothesis import HealthCheck, settings

    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


def strict(text: bytes | str):
    """JSON as a browser reads it: NaN and Infinity are errors."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(),
                    st.floats(allow_nan=True, allow_infinity=True).map(np.float32),
                    st.floats(allow_nan=True, allow_infinity=True).map(np.float64),
                    st.integers(-2**31, 2**31).map(np.int64))
trees = st.recursive(numbers | st.text(max_size=5) | st.none() | st.booleans(),
                     lambda kids: st.lists(kids, max_size=4)
                     | st.dictionaries(st.text(max_size=4), kids, max_size=4)
                     | st.lists(numbers, max_size=6).map(np.array)
                     | st.tuples(kids, kids), max_leaves=30)


@_settings(300)
@given(tree=trees)
def test_the_response_class_cannot_emit_a_number_that_is_not_json(ledger, tree):
    ledger.tried_one("responses: any structure of numbers")
    body = JSONResponse(tree).body
    strict(body)
    # finite numbers come through as they were
    if isinstance(tree, float) and math.isfinite(tree):
        assert strict(body) == tree
    if isinstance(tree, float) and not math.isfinite(tree):
        assert strict(body) is None


def test_json_safe_keeps_values_and_nulls_only_what_is_not_a_number():
    got = json_safe({"a": [1.5, float("nan"), np.float32(2.5), np.inf], "b": np.arange(3),
                     "c": (1, -np.inf), "d": np.int64(7)})
    assert got == {"a": [1.5, None, 2.5, None], "b": [0, 1, 2], "c": [1, None], "d": 7}


def _camera_text(w: int, h: int, fx: float, fy: float, cx: float, cy: float,
                 dist: list[float]) -> str:
    def nums(v):
        return ", ".join(repr(float(x)) for x in v)

    return ("%YAML:1.0\n---\n"
            f"image_width: {w}\nimage_height: {h}\n"
            "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            f"   data: [ {nums([fx, 0, cx, 0, fy, cy, 0, 0, 1])} ]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n"
            f"   cols: {len(dist)}\n   dt: d\n   data: [ {nums(dist)} ]\n")


extreme = st.sampled_from([0.0, 1e-12, -1e-12, 1.0, -1.0, 1e3, -1e3, 1e6, -1e6, 1e12, -1e12])
cameras = st.builds(
    lambda wh, f, c, dist: (wh, f, c, dist),
    st.sampled_from([(1, 1), (2, 2), (640, 480), (20000, 1), (1, 20000)]),
    st.sampled_from([1e-3, 1.0, 500.0, 1e9]),
    st.sampled_from([(0.0, 0.0), (0.5, 0.5), (-1e6, 1e6)]),
    st.lists(extreme, min_size=5, max_size=5))


@_settings(40)
@given(cam=cameras, tilt=st.sampled_from([0.0, 45.0, 89.999, 90.0, 135.0, 180.0]),
       height=st.sampled_from([0.06, 1.5, 100.0]))
def test_mount_page_answers_strict_json_for_extreme_cameras(tmp_path_factory, ledger, cam,
                                                            tilt, height):
    from webtool.app import create_app
    from webtool.settings import Settings

    (w, h), f, (cx, cy), dist = cam
    d = tmp_path_factory.mktemp("mountcam")
    path = d / "camera.yaml"
    path.write_text(_camera_text(w, h, f, f, cx if cx else (w - 1) / 2,
                                 cy if cy else (h - 1) / 2, dist))
    app = create_app(Settings(camera=path, mount_dir=d / "mount", source="0"))
    with TestClient(app, base_url=LOCAL, raise_server_exceptions=False) as c:
        for method, route, body in (
                ("GET", "/api/mount", None),
                ("POST", "/api/mount/preview",
                 {"angles": {"tilt_deg": tilt, "pan_deg": 0, "roll_deg": 0,
                             "offset_m": [0, 0, 0]}, "height_m": height})):
            ledger.tried_one("responses: mount page, extreme cameras")
            r = c.request(method, route, json=body)
            if r.status_code >= 500:
                ledger.failure("HTTP 500")
            assert r.status_code < 500, (cam, tilt, r.text)
            js = strict(r.content)
            if r.status_code == 200:
                fp = js["footprint"]
                assert all(len(p) == 2 and all(isinstance(v, (int, float)) for v in p)
                           for p in fp["polygon"])
            else:
                assert r.status_code == 422 and js["detail"]
