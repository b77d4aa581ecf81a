"""Class: every route of the web tool with requests no page sends.

Each route (read from the app's own OpenAPI paths) is asked with odd methods (its own and
``PUT``, ``PATCH``, ``OPTIONS``, ``TRACE``, ``PROPFIND``), odd path parameters (``..``,
percent-encoded NUL and invalid UTF-8, 300-byte names), odd query strings (repeated keys,
keys without values, 4,000-character values, ``%00``/``%ff``, 5,000-digit numbers) and odd
headers (a ``Content-Type`` of nothing or of garbage, ``Range`` of 20 digits, a huge cookie,
``Origin: null``, another scheme or port, ``Sec-Fetch-Site: cross-site``). Whatever the
request: a status below 500 with a body a browser can read (or the documented 503 "not
available" / 507 "disk full" with its one-line reason: a camera that is still starting after
the long poll's wait is a real answer on a loaded machine, a crash never is); a write (any method but GET,
HEAD, OPTIONS) from another origin never succeeds and changes nothing in the data folder.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

LOCAL = "http://127.0.0.1:8080"
SETTINGS = settings(max_examples=250, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])
#: routes that start work a request must not start here (a camera, a study of minutes)
SKIP = {("post", "/api/study/start")}


@pytest.fixture(scope="module")
def app_and_data(tmp_path_factory):
    from webtool.app import create_app
    from webtool.settings import Settings

    data = tmp_path_factory.mktemp("data")
    app = create_app(Settings(data_dir=data, calibration_dir=data / "calibration",
                              mount_dir=data / "mount", designer_layouts_dir=data / "designs"))
    paths = app.openapi()["paths"]
    routes = sorted((m, p) for p, ms in paths.items() for m in ms if (m, p) not in SKIP)
    with TestClient(app, base_url=LOCAL, raise_server_exceptions=False) as client:
        yield client, routes, data


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _changed(before: dict[str, str], after: dict[str, str]) -> list[str]:
    """Files that were there before and are now different or gone. New files are not
    counted, nor a calibration session's own files: an auto-capture started earlier by a
    same-origin request keeps adding its pictures in the background and rewrites its session
    (its views, its solve) as it goes (a cross-origin request that made one would have
    answered 2xx, which is checked on its own)."""
    return [k for k, v in before.items() if after.get(k) != v and not _session_file(k)]


def _session_file(name: str) -> bool:
    parts = Path(name).parts
    return len(parts) >= 3 and parts[0] == "calibration"


segments = st.sampled_from(["..", "%2e%2e", "%00", "%ff%fe", "a%2fb", "n" * 300, "-1",
                            "9" * 400, "%20", "x.json", "index.html", "%0d%0aSet-Cookie:%20a=b",
                            "0", "nan"])
query_keys = st.sampled_from(["token", "name", "n", "index", "t", "seq", "after", "view",
                              "file", "path", "format", "%00", "%ff", "a[]", ""])
query_values = st.sampled_from(["", "1", "-1", "nan", "inf", "1e400", "9" * 5000, "%00",
                                "%ff", "a" * 4000, "../../etc/passwd", "%22%3E%3Cscript%3E",
                                "true", "null", "[]", "{}"])
odd_headers = st.dictionaries(
    st.sampled_from(["content-type", "accept", "range", "cookie", "origin",
                     "sec-fetch-site", "if-none-match", "accept-encoding", "x-forwarded-for",
                     "authorization"]),
    st.sampled_from(["", "garbage", "application/json; charset=ebcdic", "multipart/form-data",
                     "bytes=99999999999999999999-", "bytes=-0", "*/*;q=nan",
                     "drovisio_token=" + "x" * 4000, "null", "https://127.0.0.1:8080",
                     "http://127.0.0.1:8081", "http://evil.example", "cross-site",
                     "Bearer \x7f", "gzip;q=2"]),
    max_size=4)


def _designed(r) -> bool:
    """A 503 or 507 the tool answers on purpose: its JSON ``detail`` is one line of words."""
    if r.status_code not in (503, 507) or not r.headers.get("content-type", "").startswith(
            "application/json"):
        return False
    detail = json.loads(r.content).get("detail")
    return isinstance(detail, str) and 0 < len(detail) < 300 and "\n" not in detail


def _is_cross_origin(headers: dict[str, str]) -> bool:
    return (("origin" in headers and headers["origin"] != LOCAL)
            or headers.get("sec-fetch-site") == "cross-site")


@SETTINGS
@given(data=st.data())
def test_every_route_answers_odd_requests_below_500(app_and_data, ledger, data):
    client, routes, folder = app_and_data
    method, path = data.draw(st.sampled_from(routes))
    if data.draw(st.booleans()):
        method = data.draw(st.sampled_from(["put", "patch", "options", "trace", "propfind",
                                            "delete", "post", "head"]))
    url = re.sub(r"\{[^}]+\}", lambda _m: data.draw(segments), path)
    pairs = data.draw(st.lists(st.tuples(query_keys, query_values), max_size=4))
    if pairs:
        url += "?" + "&".join(f"{k}={v}" if data.draw(st.booleans()) else k for k, v in pairs)
    headers = data.draw(odd_headers)
    before = _digest(folder)
    ledger.tried_one("web: odd requests")
    r = client.request(method.upper(), url, headers=headers)
    if r.status_code >= 500 and not _designed(r):
        ledger.failure("HTTP 500")
    assert r.status_code < 500 or _designed(r), (method, url, headers, r.status_code,
                                                 r.text[:300])
    if r.headers.get("content-type", "").startswith("application/json") and r.content:
        json.loads(r.content, parse_constant=lambda c: pytest.fail(f"{c} in {url}"))
    if method.upper() not in ("GET", "HEAD", "OPTIONS") and _is_cross_origin(headers):
        ok = r.status_code < 300
        changed = _changed(before, _digest(folder))
        if ok or changed:
            ledger.failure("cross-origin writes")
        assert not ok and not changed, (method, url, headers, r.status_code,
                                        f"files changed: {changed}")


@pytest.mark.parametrize("origin", ["https://127.0.0.1:8080", "null", "http://127.0.0.1:8081",
                                    "http://evil.example"])
def test_a_write_that_succeeds_from_the_page_fails_from_another_origin(app_and_data, origin,
                                                                       ledger):
    client, _, folder = app_and_data
    ledger.tried_one("web: odd requests")
    assert client.post("/api/designer/undo", headers={"origin": LOCAL}).status_code == 200
    before = _digest(folder)
    for path in ("/api/designer/undo", "/api/calibration/session", "/api/designer/save"):
        r = client.post(path, headers={"origin": origin}, json={"name": "x"})
        assert r.status_code == 403, (path, origin, r.status_code)
        assert "another site" in r.text
    assert not _changed(before, _digest(folder))
