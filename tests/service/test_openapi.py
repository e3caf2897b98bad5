"""openapi.json at the repo root is generated from the app and must equal it."""

from __future__ import annotations

import json
from pathlib import Path

from service.app import create_app
from service.cli import main, openapi_text
from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]

OPERATIONS = {
    ("post", "/v1/channel"): "compute_channel",
    ("post", "/v1/ranging/toa"): "ranging_toa",
    ("post", "/v1/ranging/pdoa"): "ranging_pdoa",
    ("post", "/v1/ranging/rss"): "ranging_rss",
    ("post", "/v1/localize"): "localize",
    ("post", "/v1/localize/evaluate"): "localize_evaluate",
    ("post", "/v1/bounds/toa"): "bound_toa",
    ("post", "/v1/bounds/pdoa"): "bound_pdoa",
    ("post", "/v1/bounds/rss"): "bound_rss",
    ("get", "/v1/tissues"): "list_tissues",
    ("get", "/v1/scenarios"): "list_scenarios",
    ("get", "/v1/phantoms"): "list_phantoms",
    ("post", "/v1/phantoms"): "upload_phantom",
    ("get", "/v1/phantoms/{phantom_id}"): "get_phantom",
    ("delete", "/v1/phantoms/{phantom_id}"): "delete_phantom",
    ("get", "/v1/phantoms/{phantom_id}/mesh"): "get_phantom_mesh",
    ("get", "/v1/phantoms/{phantom_id}/manifest"): "get_phantom_manifest",
    ("get", "/v1/phantoms/builds"): "list_phantom_builds",
    ("get", "/v1/phantoms/builds/{build_id}"): "get_phantom_build",
    ("delete", "/v1/phantoms/builds/{build_id}"): "cancel_phantom_build",
    ("post", "/v1/sweeps"): "submit_sweep",
    ("get", "/v1/sweeps"): "list_sweeps",
    ("get", "/v1/sweeps/{sweep_id}"): "get_sweep",
    ("delete", "/v1/sweeps/{sweep_id}"): "cancel_sweep",
    ("get", "/v1/sweeps/{sweep_id}/results"): "get_sweep_results",
    ("post", "/v1/fullwave"): "submit_fullwave",
    ("get", "/v1/fullwave"): "list_fullwave",
    ("get", "/v1/fullwave/{job_id}"): "get_fullwave",
    ("delete", "/v1/fullwave/{job_id}"): "cancel_fullwave",
    ("get", "/v1/fullwave/{job_id}/report"): "get_fullwave_report",
    ("get", "/v1/fullwave/{job_id}/files/{name}"): "get_fullwave_file",
    ("post", "/v1/design/coverage"): "submit_coverage",
    ("get", "/v1/design/coverage"): "list_coverage",
    ("get", "/v1/design/coverage/{job_id}"): "get_coverage",
    ("delete", "/v1/design/coverage/{job_id}"): "cancel_coverage",
    ("get", "/v1/design/coverage/{job_id}/results"): "get_coverage_results",
    ("get", "/v1/design/coverage/{job_id}/map"): "get_coverage_map",
    ("get", "/v1/design/coverage/{job_id}/plot"): "get_coverage_plot",
    ("post", "/v1/design/layout"): "submit_layout",
    ("get", "/v1/design/layout"): "list_layout",
    ("get", "/v1/design/layout/{job_id}"): "get_layout",
    ("delete", "/v1/design/layout/{job_id}"): "cancel_layout",
    ("get", "/v1/design/layout/{job_id}/report"): "get_layout_report",
    ("get", "/healthz"): "healthz",
    ("get", "/readyz"): "readyz",
    ("get", "/metrics"): "metrics",
    ("post", "/v1/plots/pdp"): "plot_pdp",
    ("post", "/v1/plots/cfr"): "plot_cfr",
    ("post", "/v1/plots/crlb"): "plot_crlb",
    ("post", "/v1/plots/ranging_errors"): "plot_ranging_errors",
    ("post", "/v1/vision/render"): "vision_render",
    ("post", "/v1/vision/motion"): "vision_motion",
    ("post", "/v1/plots/localization_cdf"): "plot_localization_cdf",
    ("post", "/v1/plots/tract_errors"): "plot_tract_errors",
    ("post", "/v1/plots/path_loss"): "plot_path_loss",
    ("post", "/v1/plots/tracking"): "plot_tracking",
    ("post", "/v1/track"): "track",
    ("post", "/v1/track/evaluate"): "track_evaluate",
}


def test_committed_openapi_json_equals_the_app_schema():
    committed = (ROOT / "openapi.json").read_text()
    assert committed == openapi_text(), "openapi.json is stale: run `capsule-rt openapi`"
    app_schema = create_app(Settings(load_builtins=False)).openapi()
    assert json.loads(committed) == json.loads(json.dumps(app_schema))
    assert committed.endswith("}\n")


def test_every_schema_has_a_name_of_its_own():
    """Two models of one class name get module-qualified keys (``service__schemas__x__Name``) with the
    same title, and a generator then drops one of them and every operation that refers to it (the
    CI run where the design's and the ranging's ``Waveform`` removed POST /v1/ranging/toa)."""
    schemas = json.loads((ROOT / "openapi.json").read_text())["components"]["schemas"]
    assert [k for k in schemas if "__" in k] == []
    titles = [s.get("title", k) for k, s in schemas.items()]
    assert sorted(t for t in set(titles) if titles.count(t) > 1) == []


def test_openapi_command_writes_and_checks(tmp_path, capsys):
    out = tmp_path / "openapi.json"
    assert main(["openapi", "--output", str(out)]) == 0
    assert out.read_text() == openapi_text()
    assert main(["openapi", "--output", str(out), "--check"]) == 0
    out.write_text("{}\n")
    assert main(["openapi", "--output", str(out), "--check"]) == 1


def test_operation_ids_are_stable_and_errors_declared():
    schema = json.loads((ROOT / "openapi.json").read_text())
    found = {(m, p): op["operationId"] for p, item in schema["paths"].items() for m, op in item.items()}
    assert found == OPERATIONS
    for (method, path), op_id in OPERATIONS.items():
        op = schema["paths"][path][method]
        codes = set(op["responses"])
        if method == "post":
            assert {"400", "422"} <= codes, op_id
        if path.startswith("/v1/phantoms/") and "{" in path:  # an id in the path: 404 and 422 declared
            assert {"404", "422"} <= codes, op_id
        if op_id in ("compute_channel", "ranging_toa", "ranging_pdoa", "ranging_rss", "upload_phantom", "localize",
                     "localize_evaluate"):
            assert {"503", "504"} <= codes, op_id
    assert "413" in schema["paths"]["/v1/phantoms"]["post"]["responses"]


def test_request_models_are_strict_documented_and_have_examples():
    schema = json.loads((ROOT / "openapi.json").read_text())["components"]["schemas"]
    for name in ("ChannelRequest", "ToaRequest", "PdoaRequest", "RssRequest", "ToaBoundRequest", "PdoaBoundRequest",
                 "RssBoundRequest", "LocalizeRequest", "LocalizeEvaluateRequest", "FullwaveRequest"):
        model = schema[name]
        assert model["additionalProperties"] is False, name
        assert model.get("examples"), name
        for field, prop in model["properties"].items():
            if field.endswith(("_hz", "_s", "_m", "_db", "_s_per_m", "_dbm")):
                assert "[" in prop.get("description", ""), (name, field)  # unit in brackets
    channel = schema["ChannelRequest"]["properties"]
    assert channel["rays"]["anyOf"][0]["maximum"] == 1_000_000
    assert channel["max_interactions"]["anyOf"][0]["maximum"] == 10
    assert channel["receivers"]["anyOf"][0]["maxItems"] == 64


def test_request_examples_validate_against_their_models():
    from service.schemas import channel as sc
    from service.schemas import ranging as sr
    from service.schemas.fullwave import FullwaveRequest

    for model in (sc.ChannelRequest, sr.ToaRequest, sr.PdoaRequest, sr.RssRequest, sr.ToaBoundRequest,
                  sr.PdoaBoundRequest, sr.RssBoundRequest, FullwaveRequest):
        for example in model.model_config["json_schema_extra"]["examples"]:
            model.model_validate(example)


def test_upload_manifest_schema_is_documented():
    schema = json.loads((ROOT / "openapi.json").read_text())
    manifest = schema["components"]["schemas"]["Manifest"]
    assert set(manifest["required"]) == {"name", "units", "organs"}
    assert manifest["additionalProperties"] is False and manifest["examples"]
    assert {"ManifestTissue", "ManifestMedium", "ManifestSite"} <= set(schema["components"]["schemas"])
    body = schema["paths"]["/v1/phantoms"]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
    assert [branch["required"] for branch in body["oneOf"]] == [["mesh", "manifest"], ["archive"]]


def test_docs_settings_table_is_current():
    from service.settings import settings_table_markdown

    assert settings_table_markdown() in (ROOT / "README.md").read_text(), \
        "regenerate the settings table in README.md (Configuration)"


def test_schema_uses_only_json_schema_keywords_for_bounds():
    """pydantic writes its internal `ge`/`le`/`gt`/`lt` into the schema for some optional fields;
    no schema tool reads them, so a client (or the fuzzer) would send values the server refuses."""
    found = []

    def walk(node, where):
        if isinstance(node, dict):
            found.extend(f"{where}/{k}" for k in ("ge", "le", "gt", "lt") if k in node)
            for key, value in node.items():
                walk(value, f"{where}/{key}")
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{where}/{i}")

    walk(json.loads((ROOT / "openapi.json").read_text()), "")
    assert not found, found
