"""Jobs under the API keys (issue 34, item 3): with CAPSULE_RT_API_KEYS set, submitting a sweep or a
full-wave job and cancelling or deleting one need a key, as uploads do, and only the key that submitted a
job cancels or deletes it. Before, anyone could start hours of gprMax or delete another client's results."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from service.app import create_app

KEY_A = "key-a-0123456789abcdef"
KEY_B = "key-b-0123456789abcdef"
JOBS = {
    "/v1/sweeps": {"capsule_positions": [{"site": "stomach"}], "receivers": [{"site": "belt_anterior"}],
                   "channel": {"rays": 500, "max_interactions": 1}, "trials": 2},
    "/v1/fullwave": {"scenario": "thesis-fig-5-6", "export_only": True, "coarse_factor": 0},
}


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("keyed"), log_level="error", api_keys=[KEY_A, KEY_B],
                        sweep_workers=1, max_rays=5000)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


def _loc(r) -> list:
    return r.json()["detail"][0]["loc"]


@pytest.mark.parametrize("path", list(JOBS))
def test_jobs_need_a_key_and_only_their_submitter_deletes_them(keyed, path):
    r = keyed.post(path, json=JOBS[path])
    assert r.status_code == 401 and _loc(r) == ["header", "x-api-key"], r.text
    assert keyed.post(path, json=JOBS[path], headers={"X-API-Key": "not-a-key-but-long-enough"}).status_code == 401
    r = keyed.post(path, json=JOBS[path], headers={"X-API-Key": KEY_A})
    assert r.status_code == 202, r.text
    job = r.json()["id"]
    assert keyed.get(f"{path}/{job}").status_code == 200  # reads stay open
    assert keyed.delete(f"{path}/{job}").status_code == 401
    r = keyed.delete(f"{path}/{job}", headers={"X-API-Key": KEY_B})
    assert r.status_code == 403 and "another API key" in r.json()["detail"][0]["msg"], r.text
    r = keyed.delete(f"{path}/{job}", headers={"X-API-Key": KEY_A})  # cancels (sweep) or deletes (done)
    assert r.status_code == 200, r.text
    if not r.json()["deleted"]:
        assert keyed.delete(f"{path}/{job}", headers={"X-API-Key": KEY_B}).status_code == 403
    # the key is never written to disk, only an id derived from it
    jobs = keyed.app.state.sweeps if path == "/v1/sweeps" else keyed.app.state.fullwave
    if (jobs.root / job).exists():
        assert all(KEY_A.encode() not in p.read_bytes() for p in (jobs.root / job).rglob("*") if p.is_file())


def test_a_refused_submission_reads_no_body_and_stores_nothing(keyed):
    """The key is checked before the body is read: an unkeyed 300 kB body is 401, not 413."""
    before = keyed.get("/v1/sweeps").json()
    r = keyed.post("/v1/sweeps", content=b" " * 300_000, headers={"content-type": "application/json"})
    assert r.status_code == 401, r.text
    assert keyed.get("/v1/sweeps").json() == before


def test_the_served_contract_declares_the_key_on_every_keyed_write(keyed):
    paths = keyed.get("/openapi.json").json()["paths"]
    for path, method in (("/v1/sweeps", "post"), ("/v1/sweeps/{sweep_id}", "delete"), ("/v1/fullwave", "post"),
                         ("/v1/fullwave/{job_id}", "delete"), ("/v1/phantoms", "post"),
                         ("/v1/phantoms/{phantom_id}", "delete")):
        assert paths[path][method]["security"] == [{"ApiKey": []}], (path, method)
        assert "401" in paths[path][method]["responses"], (path, method)
    assert "security" not in paths["/v1/sweeps"]["get"] and "security" not in paths["/v1/channel"]["post"]


def test_a_method_no_route_serves_is_405_with_or_without_a_key(keyed):
    """The key guards the declared writes only: a write no route serves is the router's 405 (or 404)."""
    r = keyed.put("/v1/sweeps", json={})
    assert r.status_code == 405 and "POST" in r.headers["allow"], r.text
    assert keyed.post("/v1/nowhere", json={}).status_code == 404
