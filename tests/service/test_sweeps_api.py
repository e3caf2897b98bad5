"""POST /v1/sweeps validation and the job endpoints' errors, in process (no job needs to run here;
the job flow over real HTTP, with a restart, is tests/e2e/test_sweeps_http.py)."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from service.app import create_app

SPEC = {"capsule_positions": [{"site": "stomach"}], "receivers": [{"site": "belt_anterior"}],
        "channel": {"rays": 1000, "max_interactions": 2}, "trials": 5}


@pytest.fixture
def client(make_settings):
    with TestClient(create_app(make_settings(sweep_workers=1, sweep_max_queue=1, max_receivers=4)),
                    raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize("changes,loc", [
    ({"channel": {"rays": 0}}, ["body", "channel", "rays"]),
    ({"channel": {"rays": 6000}}, ["body", "channel", "rays"]),  # the server's max_rays (5000 in tests)
    ({"capsule_positions": [{"site": "nowhere"}]}, ["body", "capsule_positions", 0, "site"]),
    ({"capsule_positions": [{"s_m": 9.0}]}, ["body", "capsule_positions", 0, "s_m"]),
    ({"receivers": [{"site": f"belt_{k}"} for k in range(5)]}, ["body", "receivers"]),  # max_receivers 4
    ({"frequencies_hz": [402e6, "x"]}, ["body", "frequencies_hz", 1]),
    ({"ranging": {"toa": {"methods": ["gcc", "sorcery"]}}}, ["body", "ranging", "toa", "methods", 1]),
    ({"trials": 0}, ["body", "trials"]),
    ({"surprise": 1}, ["body", "surprise"]),
])
def test_malformed_specs_get_422_naming_the_field(client, changes, loc):
    r = client.post("/v1/sweeps", json={**SPEC, **changes})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == loc, r.json()


def test_unknown_phantom_is_404_naming_it(client):
    r = client.post("/v1/sweeps", json={**SPEC, "phantom": "nope"})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["body", "phantom"]


def test_bodies_that_are_not_a_spec(client):
    r = client.post("/v1/sweeps", content=b"{not json", headers={"content-type": "application/json"})
    assert r.status_code == 400 and r.json()["detail"][0]["loc"] == ["body"]
    r = client.post("/v1/sweeps", content=b"[1, 2]", headers={"content-type": "application/json"})
    assert r.status_code == 422
    r = client.post("/v1/sweeps", content=b"{\"trials\": NaN}", headers={"content-type": "application/json"})
    assert r.status_code == 400
    r = client.post("/v1/sweeps", content=b"x" * (1 << 20 + 1), headers={"content-type": "application/json"})
    assert r.status_code == 413
    r = client.post("/v1/sweeps", content=b"capsule_positions: [{site: stomach}]\nchannel: {rays: 0}\n",
                    headers={"content-type": "application/yaml"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "channel", "rays"]


def test_unknown_sweeps_and_bad_queries(client):
    assert client.get("/v1/sweeps/sw-0000000000000000").status_code == 404
    assert client.get("/v1/sweeps/not-an-id").status_code == 422
    assert client.delete("/v1/sweeps/sw-0000000000000000").status_code == 404
    assert client.get("/v1/sweeps").json() == {"sweeps": []}


def test_queue_is_bounded_and_a_queued_job_can_be_cancelled(client):
    long = {**SPEC, "capsule_positions": {"along_tract": {"ds_m": 0.01}}, "frequencies_hz": [402e6, 2.45e9]}
    r = client.post("/v1/sweeps", content=json.dumps(long), headers={"content-type": "application/json"})
    assert r.status_code == 202, r.text
    first = r.json()
    assert r.headers["location"] == f"/v1/sweeps/{first['id']}"
    assert first["state"] in ("queued", "running") and first["total"] == 69 * 2
    r = client.post("/v1/sweeps", json=SPEC)
    assert r.status_code == 503 and r.headers["retry-after"] and r.json()["detail"][0]["loc"] == ["server"]
    r = client.get(f"/v1/sweeps/{first['id']}/results", params={"format": "xml"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["query", "format"]
    r = client.get(f"/v1/sweeps/{first['id']}/results", params={"table": "localization"})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["query", "table"]
    r = client.delete(f"/v1/sweeps/{first['id']}")
    assert r.status_code == 200 and r.json()["cancel_requested"] and r.json()["deleted"] is False
    assert [s["id"] for s in client.get("/v1/sweeps").json()["sweeps"]] == [first["id"]]
