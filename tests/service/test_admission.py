"""The one rule "bounded before work" (service.admission, docs/service.md "Bounded before work"), over
every write operation of the API and every job kind.

* Every write operation (POST, PUT, PATCH, DELETE) declares its bound: a route without a declaration
  fails here, by name; so does an operation missing from :data:`OVER_BOUND`, the table of requests
  each operation must refuse with a 422 naming the field, before any work.
* Every write's body is capped as it streams in (413), whatever the operation: the caps come from the
  declarations, not from a list of path prefixes a new route could miss (issue 34, item 6: /v1/track and
  /v1/track/evaluate had none, and accepted 1 GB).
* A job kind that does not say what its jobs cost cannot be registered.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.admission import STRICTEST, Cost, Work, admit
from service.app import create_app
from service.errors import Unprocessable
from tests.conftest import glb_bytes, nested_phantom_meshes, phantom_manifest
from tests.service.test_api import SMALL_CHANNEL

#: Settings whose limits the probes below exceed: one computation's memory share is 256 KiB
#: (64 MiB / 256), the work budgets are tiny.
TINY_SHARE = {"max_compute_memory_bytes": 64 * 2**20, "max_concurrency": 256}
PROFILE = {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}}]}
SENSORS = ["belt_anterior", "belt_left", "belt_posterior", "upper_right", "upper_anterior_left", "upper_left"]


def _png(side: int) -> bytes:
    from vision.png import encode_png

    return encode_png((np.arange(side * side).reshape(side, side) % 251).astype(np.uint8))


def _observations(n: int) -> list[dict]:
    cov = [[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-4]]
    return [{"t_s": float(k), "rf": {"position_m": [0.0, 0.0, 0.1], "covariance_m2": cov}} for k in range(n)]


#: operation id -> (settings, request, the loc its refusal names) for every operation that does work;
#: None for an operation that does none (a delete, a closed form, the 404 of an unknown plot kind).
#: A request is a JSON body, ("files", parts) for a multipart one, or "example" for the served example; "unit"
#: marks an operation probed by a test of its own (test_a_layouts_search_goes_through_the_rule).
OVER_BOUND: dict[str, tuple[dict, object, list] | None] = {
    "compute_channel": ({"max_ray_segments": 100}, SMALL_CHANNEL, ["body", "rays"]),
    "ranging_toa": ({"max_ranging_samples": 1000}, {"profile": PROFILE, "trials": 100}, ["body", "trials"]),
    "ranging_pdoa": ({"max_ranging_samples": 10}, {"profile": PROFILE, "trials": 20, "frequencies_hz": [4e8, 4.2e8],
                                                    "method": "two_tone"}, ["body", "trials"]),
    "ranging_rss": ({"max_ranging_samples": 10}, {"profile": PROFILE, "trials": 20}, ["body", "trials"]),
    "localize": (TINY_SHARE, {"method": "model_based", "sensors": [{"site": s, "delay_s": 2e-9} for s in SENSORS]},
                 ["body", "sensors"]),
    "localize_evaluate": ({"max_ranging_samples": 100_000},
                          {"capsule": {"site": "stomach"}, "rays": 2000, "trials": 10,
                           "sensors": [{"site": s} for s in SENSORS]}, ["body", "trials"]),
    "track": (TINY_SHARE, {"tracker": "particle", "config": {"particles": 10_000}, "observations": _observations(3)},
              ["body", "config", "particles"]),
    "track_evaluate": ({"max_ray_segments": 1000}, {"journey": {"steps": 10}, "trackers": ["rf"], "rays": 2000},
                       ["body", "rays"]),
    "vision_render": (TINY_SHARE, {"pose": {"s_m": 0.3}, "camera": {"size_px": 64}}, ["body", "camera", "size_px"]),
    "vision_motion": (TINY_SHARE, ("files", {"reference": ("a.png", _png(64), "image/png"),
                                             "moving": ("b.png", _png(64), "image/png")}), ["body", "reference"]),
    "submit_sweep": ({"max_ray_segments": 10}, {"capsule_positions": [{"site": "stomach"}],
                                                "channel": {"rays": 500, "max_interactions": 1}}, ["body", "channel",
                                                                                                  "rays"]),
    "submit_fullwave": ({"fullwave_max_cell_updates": 1}, {"scenario": "thesis-fig-5-6", "export_only": True},
                        ["body", "cell_m"]),
    "upload_phantom": ({"max_triangles": 4}, ("files", {
        "mesh": ("p.glb", glb_bytes(nested_phantom_meshes()), "model/gltf-binary"),
        "manifest": ("m.json", json.dumps(phantom_manifest()), "application/json")}), ["body", "mesh"]),
    "submit_coverage": ({"design_max_links": 10, "max_rays": 20_000}, "example", ["body", "candidates", "spacing_m"]),
    # a layout needs a done coverage (409 before): its bound is probed on the kind itself, below
    "submit_layout": "unit",
    "bound_toa": None, "bound_pdoa": None, "bound_rss": None, "delete_phantom": None, "cancel_sweep": None,
    "cancel_fullwave": None, "cancel_coverage": None, "cancel_layout": None, "cancel_phantom_build": None,
    "unknown_kind": None,
}


def _plot_kinds() -> list[str]:
    from plots.registry import KINDS

    return list(KINDS)


for _kind in _plot_kinds():  # a figure over the share: its canvas at the example's size
    OVER_BOUND[f"plot_{_kind}"] = (TINY_SHARE, "example", ["body", "dpi"])


def _concrete(template: str) -> str:
    return re.sub(r"\{[^}]+\}", "x0", template)


def _app(data_dir: str = "/nonexistent-capsule-rt-data"):
    """An app to read the contract and the declarations of (never started: nothing is written)."""
    from service.settings import Settings

    return create_app(Settings(data_dir=data_dir, log_level="error", load_builtins=False))


@pytest.fixture(scope="module")
def app():
    return _app()


def _write_operations(app) -> list[tuple[str, str, str]]:
    out = []
    for path, item in app.openapi()["paths"].items():
        for method, op in item.items():
            if method.upper() in ("POST", "PUT", "PATCH", "DELETE"):
                out.append((method.upper(), path, op["operationId"]))
    return out


def _media_type(app, op_id: str) -> str:
    """The content type the operation takes (multipart with a boundary), JSON when it takes none."""
    for item in app.openapi()["paths"].values():
        for op in item.values():
            if op.get("operationId") == op_id:
                kind = next(iter(op.get("requestBody", {}).get("content", {})), "application/json")
                return kind + ("; boundary=b0" if kind.startswith("multipart/") else "")
    raise KeyError(op_id)


def test_every_write_operation_declares_its_bound(app):
    table = app.state.declarations
    assert table.undeclared() == [], "write routes without service.admission.declare"
    for method, path, op in _write_operations(app):
        declared = table.find(method, _concrete(path))
        assert declared is not None, f"{method} {path} ({op}) is not in the gate's table of the app's routes"
        assert declared is not STRICTEST, f"{method} {path} ({op}) is undeclared"
    operations = {op for _, _, op in _write_operations(app)} | {row[2] for row in table.rows}
    missing = sorted(operations - set(OVER_BOUND))
    assert missing == [], f"operations without a request their bound refuses in OVER_BOUND: {missing}"


@pytest.mark.parametrize("method, path, op", [pytest.param(*w, id=w[2]) for w in _write_operations(_app())])
def test_every_write_body_is_capped(make_settings, method, path, op):
    """A declared Content-Length over the operation's cap is refused before it is read, and so is a
    body without one that grows past it (the cap bites while it streams in; a DELETE reads none)."""
    settings = make_settings(load_builtins=False, max_json_body_bytes=1024, max_ranging_body_bytes=4096,
                             max_upload_bytes=2048, max_manifest_bytes=1024)
    app = create_app(settings)
    cap = app.state.declarations.find(method, _concrete(path)).body(settings)  # every route has one (above)
    headers = {"content-type": _media_type(app, op)}
    with TestClient(app, raise_server_exceptions=False) as client:
        r = client.request(method, _concrete(path), content=b" " * (cap + 1), headers=headers)
        assert r.status_code == 413 and r.json()["detail"][0]["type"] == "too_large", (op, r.text)

        if method == "DELETE":
            return  # a DELETE never reads its body: nothing streams in

        def chunks():
            for _ in range(cap // 1000 + 2):
                yield b" " * 1000

        r = client.request(method, _concrete(path), content=chunks(), headers=headers)
        assert r.status_code == 413, (op, r.text)


def test_track_bodies_are_capped_as_they_stream_in(make_settings):
    """Issue 34, item 6: /v1/track and /v1/track/evaluate had no cap (1 GB accepted, 2.5 GB peak)."""
    settings = make_settings(load_builtins=False)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        for path, cap in (("/v1/track", settings.max_ranging_body_bytes),
                          ("/v1/track/evaluate", settings.max_json_body_bytes)):
            big = b'{"observations": [' + b" " * cap + b"]}"
            r = client.post(path, content=big, headers={"content-type": "application/json"})
            assert r.status_code == 413, (path, r.text)


def _example(app, op_id: str) -> dict:
    schema = app.openapi()
    for item in schema["paths"].values():
        for op in item.values():
            if op.get("operationId") == op_id:
                ref = op["requestBody"]["content"]["application/json"]["schema"]["$ref"]
                return schema["components"]["schemas"][ref.rsplit("/", 1)[1]]["examples"][0]
    raise KeyError(op_id)


PROBED = sorted(op for op, probe in OVER_BOUND.items() if isinstance(probe, tuple))


@pytest.mark.parametrize("op", PROBED)
def test_each_operation_refuses_a_request_over_its_bound_naming_the_field(make_settings, op):
    overrides, body, loc = OVER_BOUND[op]
    app = create_app(make_settings(**overrides))
    path = next(p for _, p, o in _write_operations(app) if o == op)
    with TestClient(app, raise_server_exceptions=False) as client:
        if body == "example":
            body = _example(app, op)
        r = client.post(path, files=body[1]) if isinstance(body, tuple) else client.post(path, json=body)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == loc, r.text


def test_admit_names_the_work_furthest_over_then_the_largest_memory_term(make_settings):
    settings = make_settings(**TINY_SHARE)
    work = (Work(("a",), 30, 10, "units", "cap_a", "a"), Work(("b",), 50, 10, "units", "cap_b", "b"))
    with pytest.raises(Unprocessable) as info:
        admit(Cost(work=work, memory=((("m",), 1e12),)), settings)
    assert info.value.loc == ["body", "b"] and "work budget" in info.value.reason
    with pytest.raises(Unprocessable) as info:
        admit(Cost(memory=((("small",), 1e5), (("big",), 1e6))), settings)
    assert info.value.loc == ["body", "big"] and "MiB" in info.value.reason and "small" in info.value.reason
    admit(Cost(work=(Work(("a",), 10, 10, "units", "cap", "a"),), memory=((("m",), 256 * 1024),)), settings)


def test_a_job_kind_without_an_estimate_cannot_be_registered(make_settings, tmp_path):
    from service.jobs import JobKind, JobRunner

    class Unbounded(JobKind):
        kind, prefix = "unbounded", "ub-"

    with pytest.raises(TypeError, match="estimate"):
        Unbounded(JobRunner(tmp_path), make_settings(), tmp_path / "ub", 1)


def test_the_audits_localization_evaluation_is_refused_before_any_work(make_settings, monkeypatch):
    """Issue 34, item 1: 5e5 rays x 10 interactions x 64 sensors x 200 trials passed every per-field limit and
    ran past 10 GB and its deadline. Its estimate: 2.7e7 ray segments (within the budget), 64 sensors x 200
    trials x 5503 samples (the latest delay's envelope at 10 interactions on the torso) = 7e7 TOA samples, over
    the 2e7 budget: a 422 naming trials; at 20 trials, the trace's memory (rays x sensors candidates, about
    9 GB) is over the 4 GiB share: a 422 naming rays. The evaluation never starts; the documented request
    (6 sensors, 10 trials, 20 000 rays) still does."""
    import evaluation.localization

    started = []
    monkeypatch.setattr(evaluation.localization, "evaluate_localization",
                        lambda *a, **k: started.append(k) or (_ for _ in ()).throw(RuntimeError("work started")))
    audit = {"capsule": {"site": "stomach"}, "sensors": [{"site": SENSORS[i % 6]} for i in range(64)],
             "rays": 500_000, "max_interactions": 10, "trials": 200, "ranging": "gcc"}
    with TestClient(create_app(make_settings(max_rays=1_000_000)), raise_server_exceptions=False) as client:
        r = client.post("/v1/localize/evaluate", json=audit)
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "trials"], r.text
        assert "work budget" in r.json()["detail"][0]["msg"]
        r = client.post("/v1/localize/evaluate", json={**audit, "trials": 20})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "rays"], r.text
        assert "MiB" in r.json()["detail"][0]["msg"]
        assert started == []
        documented = _example(client.app, "localize_evaluate")
        r = client.post("/v1/localize/evaluate", json=documented)
        assert r.status_code == 500 and len(started) == 1  # admitted: the spy ran (and raised)


def test_an_evaluations_carrier_its_ranging_cannot_sample_is_refused_naming_the_frequency(make_settings):
    """Found by the fuzzing of this rule's first version: at 20 GHz the TOA ranging's default waveform (20 GS/s)
    is below Nyquist, and its estimate named a field the request does not have (waveform.sample_rate_hz)."""
    with TestClient(create_app(make_settings()), raise_server_exceptions=False) as client:
        r = client.post("/v1/localize/evaluate", json={"capsule": {"site": "stomach"}, "frequency_hz": 19.99e9,
                                                       "sensors": [{"site": s} for s in SENSORS], "rays": 2000})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "frequency_hz"], r.text


def test_a_layouts_search_goes_through_the_rule(make_settings):
    """A layout's search work (design.layout.search_work) over MAX_SEARCH_WORK is refused by the one rule,
    naming search.restarts (over HTTP a layout first needs a done coverage)."""
    from design.layout import MAX_SEARCH_WORK

    app = create_app(make_settings(load_builtins=False))
    with pytest.raises(Unprocessable) as info:
        admit(app.state.layout.estimate(2 * MAX_SEARCH_WORK), app.state.capsule.settings)
    assert info.value.loc == ["body", "search", "restarts"] and "work budget" in info.value.reason
    admit(app.state.layout.estimate(MAX_SEARCH_WORK), app.state.capsule.settings)
