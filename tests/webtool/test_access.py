"""Token access (webtool.access) and the host rules of webtool.settings."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from webtool.access import COOKIE_NAME
from webtool.app import create_app
from webtool.serve import open_lines
from webtool.settings import Settings, is_loopback

LOCAL = "http://127.0.0.1:8080"  # the Host a browser on this machine sends

TOKEN = "s3cret-token"


@pytest.mark.parametrize("host", ["127.0.0.1", "127.8.9.1", "::1", "[::1]", "localhost",
                                  "LOCALHOST", "::ffff:127.0.0.1"])
def test_loopback_hosts(host):
    assert is_loopback(host)


@pytest.mark.parametrize("host", ["testclient", "0.0.0.0", "::", "192.168.1.20", "10.0.0.1",
                                  "example.org", "", None])
def test_non_loopback_hosts(host):
    assert not is_loopback(host)


def test_token_only_when_exposed():
    assert Settings().token is None and not Settings().token_required
    assert Settings(host="localhost").token is None
    exposed = Settings(host="0.0.0.0")
    assert exposed.token_required and len(exposed.token) >= 16
    assert Settings(host="0.0.0.0").token != exposed.token
    assert Settings(host="0.0.0.0", token=TOKEN).token == TOKEN


def test_loopback_binding_needs_no_token_even_for_remote_client():
    # Token mode off (default host): everything passes, whatever the client.
    client = TestClient(create_app(Settings()), base_url=LOCAL)  # client host is "testclient"
    assert client.get("/").status_code == 200
    assert client.get("/api/health").status_code == 200


@pytest.fixture
def exposed_app():
    return create_app(Settings(host="0.0.0.0", token=TOKEN))


def test_loopback_client_passes_in_token_mode(exposed_app):
    client = TestClient(exposed_app, base_url=LOCAL, client=("127.0.0.1", 50000))
    assert client.get("/").status_code == 200
    assert TestClient(exposed_app, base_url=LOCAL, client=("::1", 50000)).get("/api/health").status_code == 200


def test_remote_client_without_token_is_refused(exposed_app):
    client = TestClient(exposed_app, base_url=LOCAL)  # client host "testclient": not loopback
    r = client.get("/api/health")
    assert r.status_code == 401
    assert r.json()["detail"] == "access token required"
    assert "token" in r.json()["help"]
    r = client.get("/", headers={"accept": "text/html"})
    assert r.status_code == 401
    assert r.headers["content-type"].startswith("text/html")
    assert "Access token required" in r.text
    assert TOKEN not in r.text


def test_remote_client_with_wrong_token_is_refused(exposed_app):
    client = TestClient(exposed_app, base_url=LOCAL)
    assert client.get("/?token=wrong").status_code == 401
    assert client.get("/", headers={"authorization": "Bearer wrong"}).status_code == 401
    client.cookies.set(COOKIE_NAME, "wrong")
    assert client.get("/").status_code == 401


def test_token_in_query_is_accepted_and_sets_cookie(exposed_app):
    client = TestClient(exposed_app, base_url=LOCAL)
    r = client.get(f"/?token={TOKEN}")
    assert r.status_code == 200
    assert COOKIE_NAME in r.headers["set-cookie"] and "HttpOnly" in r.headers["set-cookie"]
    # Following links afterwards works through the cookie alone.
    assert client.get("/live").status_code == 200
    assert client.get("/api/health").status_code == 200


def test_bearer_token_is_accepted(exposed_app):
    client = TestClient(exposed_app, base_url=LOCAL)
    r = client.get("/api/health", headers={"authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 200 and r.json()["status"] == "ok"


def test_printed_urls_carry_the_token_when_exposed():
    assert open_lines(Settings()) == ["Drovisio web tool: open http://127.0.0.1:8080/"]
    lines = open_lines(Settings(host="0.0.0.0", port=9000, token=TOKEN))
    assert lines[0].startswith("Drovisio web tool: open http://127.0.0.1:9000/")
    assert any(f":9000/?token={TOKEN}" in line for line in lines[1:])
    lines = open_lines(Settings(host="192.168.1.20", token=TOKEN))
    assert lines[0] == f"Drovisio web tool: open http://192.168.1.20:8080/?token={TOKEN}"


def test_exposed_server_prints_full_and_view_only_links_with_qr_codes():
    s = Settings(host="192.168.1.20", token=TOKEN)
    text = "\n".join(open_lines(s))
    assert f"full access (calibrate, design, control): http://192.168.1.20:8080/?token={TOKEN}" \
        in text
    assert f"view only (watch the live view): http://192.168.1.20:8080/live?token=" \
        f"{s.viewer_token}" in text
    assert text.count("▀▀▀▀▀▀▀▀▀▀") >= 2  # one QR code per link, for phones
    assert "token" not in "\n".join(open_lines(Settings()))
