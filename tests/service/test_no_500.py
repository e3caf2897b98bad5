"""The 500s of issue 34, item 8, each now a 4xx naming the field: a localization whose every sigma_m is
~1e-160 m (its 1 / sigma^2 weights overflow: a singular matrix), a YAML sweep spec whose seed has 5000
digits (the parser, then the message, turned it into a string), and the contract slip of a YAML seed of
2^53 accepted above the schema's maximum."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from service.app import create_app

SENSORS = [[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, -0.1, 0.0], [0.0, 0.0, 0.1]]


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("no500"), log_level="error", max_rays=5000)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize("method, measured", [("nonlinear", "range_m"), ("linear", "range_m"),
                                              ("joint_velocity", "delay_s"), ("nonlinear", "delay_s")])
def test_sigmas_too_small_to_weigh_by_are_refused_naming_them(client, method, measured):
    value = 0.1 if measured == "range_m" else 2e-9
    body = {"method": method, "sensors": [{"position_m": p, measured: value, "sigma_m": 1e-160} for p in SENSORS]}
    r = client.post("/v1/localize", json=body)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "sensors", 0, "sigma_m"], r.text


@pytest.mark.parametrize("sigmas", [[1e-12] * 5, [1e-12] * 4 + [100.0]])
def test_the_smallest_sigma_allowed_is_answered_not_a_500(client, sigmas):
    for method in ("nonlinear", "linear"):
        body = {"method": method, "sensors": [{"position_m": p, "range_m": 0.1 + 0.01 * k, "sigma_m": s}
                                              for k, (p, s) in enumerate(zip(SENSORS, sigmas))]}
        r = client.post("/v1/localize", json=body)
        assert r.status_code in (200, 422), r.text


def test_a_yaml_seed_of_5000_digits_is_400_naming_the_body(client):
    spec = "capsule_positions: [{site: stomach}]\nseed: " + "7" * 5000 + "\n"
    r = client.post("/v1/sweeps", content=spec, headers={"content-type": "application/yaml"})
    assert r.status_code == 400 and r.json()["detail"][0]["loc"] == ["body"], r.text


@pytest.mark.parametrize("seed", [2**53, 2**63 - 1, 10**30])
def test_seeds_above_the_schemas_maximum_are_refused(client, seed):
    spec = f"capsule_positions: [{{site: stomach}}]\nchannel: {{rays: 300, max_interactions: 1}}\nseed: {seed}\n"
    r = client.post("/v1/sweeps", content=spec, headers={"content-type": "application/yaml"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "seed"], r.text
    assert "2^53" in r.json()["detail"][0]["msg"]
    schema = client.get("/openapi.json").json()["paths"]["/v1/sweeps"]["post"]["requestBody"]["content"]
    assert schema["application/yaml"]["schema"]["properties"]["seed"]["maximum"] == 2**53 - 1 < seed


def test_the_largest_seed_is_accepted():
    from sweeps.spec import SweepSpec

    spec = SweepSpec.from_dict({"capsule_positions": [{"site": "stomach"}], "seed": 2**53 - 1})
    assert spec["seed"] == 2**53 - 1
