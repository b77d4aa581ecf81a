"""The Help page: the field guide rendered from docs/field-guide.md, its pictures served (and
nothing else), every page of the tool pictured at both sizes."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient

from drovisio.resources import docs_dir
from webtool.app import create_app
from webtool.pages.routes import PAGES
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"
GUIDE = (docs_dir() / "field-guide.md").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def client():
    return TestClient(create_app(Settings()), base_url=LOCAL)


def test_the_guide_walks_every_step_with_pictures_of_every_page(client):
    r = client.get("/help")
    assert r.status_code == 200
    steps = re.findall(r"<h2>(\d)\. ([^<]+)</h2>", r.text)
    assert [int(n) for n, _ in steps] == list(range(1, 8))
    assert [t for _, t in steps][1:6] == ["Print the calibration board", "Calibrate the camera",
                                          "Set the camera mount", "Design and print the markers",
                                          "Fly"]
    srcs = re.findall(r'<img src="([^"]+)"', r.text)
    pictured = {"start" if p == "/" else p.strip("/") for p in PAGES if p != "/help"}
    assert sorted(srcs) == sorted(f"/help/images/{p}-{s}.jpg" for p in pictured
                                  for s in ("phone", "laptop"))
    for src in srcs:       # committed with the code; the browser tests rewrite them
        img = client.get(src)
        assert img.status_code == 200 and img.content[:3] == b"\xff\xd8\xff", src


def test_the_guide_names_buttons_that_exist(client):
    pages = {p: client.get(p).text for p in PAGES if p != "/help"}
    scripts = "".join(client.get(f"/static/{n}.js").text for n in ("live", "calibration"))
    steps = GUIDE.split("## When something is wrong")[0]     # (then messages, not buttons)
    for label in (" ".join(x.split()) for x in re.findall(r"\*\*([^*]+)\*\*", steps)):
        assert any(label in html for html in pages.values()) or label in scripts, label


@pytest.mark.parametrize("name", ["../field-guide.md", "..%2F__init__.py", "x.gif",
                                  "start-phone.JPG", "nothing.jpg"])
def test_only_the_guides_pictures_are_served(client, name):
    assert client.get(f"/help/images/{name}").status_code == 404
