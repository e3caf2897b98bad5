"""POST /v1/plots/{kind} (in-process app) and ``capsule-rt plot``: content negotiation, the same
figures as the Python functions, and bad data answered 4xx naming the field."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from plots import KINDS, render
from service.app import create_app
from service.cli import main
from service.routes.plots import NotAcceptable, negotiate

PROFILE = {"receiver": "rx", "paths": [{"delay_s": 1.339e-9, "gain": {"re": 0.02, "im": 0.0}, "interactions": []},
                                       {"delay_s": 2.2e-9, "gain": {"re": -4e-3, "im": 2e-3},
                                        "interactions": [{"kind": "reflection"}]}]}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("data"), load_builtins=False, log_level="warning")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize(
    "accept, fmt",
    [
        (None, "png"), ("", "png"), ("*/*", "png"), ("image/*", "png"), ("image/png", "png"),
        ("image/svg+xml", "svg"), ("application/pdf", "pdf"),
        ("image/svg+xml;q=0.5, image/png", "png"), ("image/png;q=0.2, image/svg+xml;q=0.9", "svg"),
        ("text/html, image/*;q=0.8, image/svg+xml;q=0.8", "svg"),  # exact type before a wildcard at equal q
        ("image/avif,image/webp,image/apng,image/svg+xml,image/*,*/*;q=0.8", "svg"),  # a browser's <img>
        ("image/png;q=0, */*", "png"),
    ],
)
def test_negotiate(accept, fmt):
    assert negotiate(accept) == fmt


@pytest.mark.parametrize("accept", ["text/html", "image/png;q=0", "application/json, text/*"])
def test_negotiate_refuses(accept):
    with pytest.raises(NotAcceptable):
        negotiate(accept)


def test_every_kind_is_a_documented_route(client):
    spec = client.get("/openapi.json").json()
    for name in KINDS:
        op = spec["paths"][f"/v1/plots/{name}"]["post"]
        assert op["operationId"] == f"plot_{name}"
        assert {"image/png", "image/svg+xml", "application/pdf"} <= set(op["responses"]["200"]["content"])
        body = op["requestBody"]["content"]["application/json"]["schema"]["$ref"].rsplit("/", 1)[1]
        model = spec["components"]["schemas"][body]
        assert model.get("examples") and model["additionalProperties"] is False, name
    for kind in KINDS.values():  # every field with a unit says it in brackets, nested models included
        schema = kind.request.model_json_schema()
        for name, model in [(kind.name, schema), *schema.get("$defs", {}).items()]:
            for field, prop in model.get("properties", {}).items():
                if field.endswith(("_hz", "_s", "_m", "_db", "_in")):
                    assert "[" in prop.get("description", ""), (name, field)

@pytest.mark.parametrize("name", list(KINDS))
def test_each_kind_renders_its_documented_example(client, name):
    example = KINDS[name].request.model_config["json_schema_extra"]["examples"][0]
    r = client.post(f"/v1/plots/{name}", json=example)
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content == render(name, example, "png")  # the same figure as the Python function
    assert "accept" in r.headers["vary"].lower()
    r = client.post(f"/v1/plots/{name}", json=example, headers={"Accept": "image/svg+xml"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/svg+xml"
    assert b"<svg" in r.content[:2000]


def test_pdf_on_request_and_406_otherwise(client):
    r = client.post("/v1/plots/pdp", json={"profile": PROFILE}, headers={"Accept": "application/pdf"})
    assert r.status_code == 200 and r.content.startswith(b"%PDF")
    r = client.post("/v1/plots/pdp", json={"profile": PROFILE}, headers={"Accept": "text/html"})
    assert r.status_code == 406
    assert r.json()["detail"][0]["loc"] == ["header", "accept"]


@pytest.mark.parametrize(
    "kind, body, loc",
    [
        ("pdp", {"profile": {"paths": [{"delay_s": -1e-9, "gain": {"re": 1, "im": 0}}]}},
         ["body", "profile", "paths", 0, "delay_s"]),
        ("pdp", {"profile": PROFILE, "dpi": 1000}, ["body", "dpi"]),
        ("pdp", {}, ["body", "profile"]),
        ("cfr", {"profile": PROFILE}, ["body", "profile", "paths", 0, "band_gains"]),
        ("crlb", {"carrier": {"start_hz": 5e6, "stop_hz": 1e9}, "pdoa": [{"tone_spacing_hz": 20e6, "snr_db": 30}]},
         ["body", "pdoa", 0, "tone_spacing_hz"]),
        ("ranging_errors", {"methods": [{"method": "a", "errors_m": [0.0]}, {"method": "a", "errors_m": [1.0]}]},
         ["body", "methods", 1, "method"]),
        ("ranging_errors", {"methods": [{"method": "a", "errors_m": [0.0] * 100_001}]},
         ["body", "methods", 0, "errors_m"]),
    ],
)
def test_bad_data_is_422_naming_the_field(client, kind, body, loc):
    r = client.post(f"/v1/plots/{kind}", json=body)
    assert r.status_code == 422, r.text
    assert loc in [d["loc"] for d in r.json()["detail"]], r.json()
    assert all(d["msg"] for d in r.json()["detail"])


def test_unknown_kind_and_malformed_body(client):
    r = client.post("/v1/plots/heatmap", json={})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["path", "kind"]
    assert "pdp" in r.json()["detail"][0]["msg"]
    r = client.post("/v1/plots/pdp", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code in (400, 422) and r.json()["detail"][0]["loc"][0] == "body"


# ------------------------------------------------------------------ CLI
def test_cli_plots_a_body_and_a_channel_response(tmp_path, capsys):
    body = tmp_path / "pdp.json"
    body.write_text(json.dumps({"profile": PROFILE}))
    out = tmp_path / "pdp.svg"
    assert main(["plot", "pdp", str(body), "-o", str(out)]) == 0
    assert out.read_bytes() == render("pdp", {"profile": PROFILE}, "svg")
    second = dict(PROFILE, receiver="s2", paths=PROFILE["paths"][1:])
    channel = tmp_path / "channel.json"
    channel.write_text(json.dumps({"phantom": "x", "profiles": [PROFILE, second]}))
    png = tmp_path / "s2.png"
    assert main(["plot", "pdp", str(channel), "--receiver", "s2", "-o", str(png)]) == 0
    assert png.read_bytes() == render("pdp", {"profile": second}, "png")
    assert main(["plot", "pdp", str(channel), "--receiver", "1", "-o", str(png)]) == 0
    assert png.read_bytes() == render("pdp", {"profile": second}, "png")
    assert "wrote" in capsys.readouterr().out


@pytest.mark.parametrize(
    "kind, content, args, loc",
    [
        ("pdp", {"profile": {"paths": []}}, [], ["body", "profile", "paths"]),
        ("cfr", {"profile": PROFILE}, [], ["body", "profile", "paths", 0, "band_gains"]),
        ("pdp", {"profiles": [PROFILE]}, ["--receiver", "nobody"], ["receiver"]),
        ("crlb", {"profiles": [PROFILE]}, [], ["receiver"]),
        ("pdp", "{broken", [], ["input"]),
        ("pdp", {"profile": PROFILE}, ["-o", "x.jpg"], ["output"]),
    ],
)
def test_cli_bad_input_exits_2_naming_the_field(tmp_path, capsys, kind, content, args, loc):
    src = tmp_path / "in.json"
    src.write_text(content if isinstance(content, str) else json.dumps(content))
    out = ["-o", str(tmp_path / "out.png")] if "-o" not in args else ["-o", str(tmp_path / args[-1])]
    rest = [a for a in args if a not in ("-o", "x.jpg")]
    assert main(["plot", kind, str(src), *rest, *out]) == 2
    detail = json.loads(capsys.readouterr().err)["detail"]
    assert loc in [d["loc"] for d in detail]
    assert not (tmp_path / "out.png").exists()
