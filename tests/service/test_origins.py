"""Writes from web pages (issue 34, item 4): the Origin guard checks an Origin against the configured origins
(CAPSULE_RT_CORS_ORIGINS and the server's own http://HOST:PORT), scheme included, never against the request's
Host header; and POST /v1/sweeps parses only JSON and YAML (a page's text/plain or form body is 415)."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from service.app import create_app

BOUND = {"shadowing_db": 4.0, "path_loss_exponent": 3.0, "distance_m": 0.1}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """An app configured as `capsule-rt serve --host 127.0.0.1 --port 8104` with one CORS origin."""
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("origins"), log_level="error", load_builtins=False,
                        host="127.0.0.1", port=8104, cors_origins=["https://lab.example:8443"])
    with TestClient(create_app(settings), raise_server_exceptions=False, base_url="http://127.0.0.1:8104") as c:
        yield c


@pytest.mark.parametrize("origin, host", [
    ("http://rebind.example:8104", "rebind.example:8104"),  # DNS rebinding: Host and Origin agree
    ("http://evil.example", "evil.example"),
    ("https://127.0.0.1:8104", "127.0.0.1:8104"),  # the scheme counts
    ("http://127.0.0.1:8105", "127.0.0.1:8104"),  # so does the port
    ("http://lab.example:8443", "127.0.0.1:8104"),  # the listed origin is https
    ("null", "127.0.0.1:8104"),  # a sandboxed page, a file:// page
])
def test_foreign_origins_are_refused_whatever_the_host_header_says(served, origin, host):
    r = served.post("/v1/bounds/rss", json=BOUND, headers={"Origin": origin, "Host": host})
    assert r.status_code == 403 and r.json()["detail"][0]["loc"] == ["header", "origin"], r.text


@pytest.mark.parametrize("origin", ["http://127.0.0.1:8104", "http://localhost:8104", "http://[::1]:8104",
                                    "HTTP://LOCALHOST:8104", "https://lab.example:8443", "https://lab.example:8443/"])
def test_configured_origins_may_write(served, origin):
    r = served.post("/v1/bounds/rss", json=BOUND, headers={"Origin": origin})
    assert r.status_code == 200, r.text


def test_the_default_port_is_the_same_origin_written_or_not(make_settings):
    from service.security import configured_origins, parse_origin

    allowed = configured_origins(make_settings(host="0.0.0.0", port=80, cors_origins=["https://lab.example"]))
    assert parse_origin("http://localhost") in allowed and parse_origin("http://localhost:80") in allowed
    assert parse_origin("https://lab.example:443") in allowed and parse_origin("http://lab.example") not in allowed
    public = configured_origins(make_settings(host="capsule.lab.example", port=8000))
    assert public == {("http", "capsule.lab.example", 8000)}


@pytest.mark.parametrize("kind", ["text/plain", "application/x-www-form-urlencoded",
                                  "multipart/form-data; boundary=x", None])
def test_sweeps_refuse_the_bodies_a_page_sends_without_preflight(served, kind):
    headers = {"content-type": kind} if kind else {}
    r = served.post("/v1/sweeps", content=b'{"capsule_positions": [{"site": "stomach"}], "phantom": "nope"}',
                    headers=headers)
    assert r.status_code == 415 and r.json()["detail"][0]["loc"] == ["header", "content-type"], r.text


JSON_SPEC = b'{"capsule_positions": [{"site": "s"}], "phantom": "nope"}'


@pytest.mark.parametrize("kind, body", [("application/json", JSON_SPEC), ("application/json; charset=utf-8", JSON_SPEC),
                                        ("application/yaml", b"capsule_positions: [{site: s}]\nphantom: nope\n")])
def test_sweeps_take_json_and_yaml(served, kind, body):
    r = served.post("/v1/sweeps", content=body, headers={"content-type": kind})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["body", "phantom"], r.text  # parsed
