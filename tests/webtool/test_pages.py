"""Web tool pages and /api/health, through FastAPI's TestClient."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"  # the Host a browser on this machine sends

PAGES = {
    "/": "Drovisio",
    "/calibration": "Camera calibration",
    "/designer": "Marker designer",
    "/live": "Live view",
}


def test_webtool_is_the_real_package():
    # Guard against tests/webtool/ shadowing the package (see tests/conftest.py).
    import webtool

    assert webtool.__file__ and webtool.__file__.endswith("webtool/__init__.py")
    assert "tests" not in Path(webtool.__file__).parts


@pytest.fixture
def client() -> TestClient:
    return TestClient(create_app(Settings()), base_url=LOCAL)


@pytest.mark.parametrize("path,title", PAGES.items())
def test_page_ok_with_title(client, path, title):
    r = client.get(path)
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/html")
    assert f"<h1>{title}</h1>" in r.text
    assert re.search(r"<title>[^<]*" + re.escape(title) + "[^<]*</title>", r.text)
    assert 'name="viewport"' in r.text


def test_start_page_has_three_sections_with_links(client):
    html = client.get("/").text
    for section, href in [("calibration", "/calibration"), ("designer", "/designer"),
                          ("live", "/live")]:
        m = re.search(rf'<section id="{section}"[^>]*>(.*?)</section>', html, re.S)
        assert m, section
        body = m.group(1)
        assert "<h2" in body
        assert f'href="{href}"' in body


def test_pages_show_the_sample_session_source(client):
    settings = client.app.state.settings
    assert settings.source is None
    assert str(settings.sample_session) in client.get("/").text
    assert str(settings.sample_session) in client.get("/live").text


def test_pages_show_a_given_source():
    client = TestClient(create_app(Settings(source="flight-03.mp4", camera="cam.yaml")), base_url=LOCAL)
    html = client.get("/").text
    assert "flight-03.mp4" in html and "cam.yaml" in html


def test_health(client):
    r = client.get("/api/health")
    assert r.status_code == 200
    data = r.json()
    assert data["status"] == "ok"
    assert re.match(r"\d+\.\d+", data["version"])
    assert data["source"] == str(client.app.state.settings.sample_session)
    assert data["sample"] is True


def test_health_with_source():
    data = TestClient(create_app(Settings(source="0")), base_url=LOCAL).get("/api/health").json()
    assert data["source"] == "0" and data["sample"] is False


def test_unknown_page_is_404(client):
    assert client.get("/nope").status_code == 404
