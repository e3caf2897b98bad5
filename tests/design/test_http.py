"""POST /v1/design/coverage and /v1/design/layout in process: bad inputs are 4xx naming the field and
queue nothing; a layout on a done coverage runs on the job queue and answers `sensors`,
`criterion_m` and `baseline_criterion_m`."""

from __future__ import annotations

import shutil
import time

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from tests.design.conftest import TINY_COVERAGE

COVERAGE_ID = "cv-00000000000000aa"


@pytest.fixture
def client(make_settings, tiny_coverage):
    settings = make_settings(sweep_workers=1, design_max_queue=2, max_rays=100_000)
    target = settings.data_dir / "design" / "coverage" / COVERAGE_ID
    shutil.copytree(tiny_coverage, target)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _loc(r):
    return r.json()["detail"][0]["loc"]


@pytest.mark.parametrize("changes,status,loc", [
    ({"candidates": {"region": {"min_m": [5, 5, 5], "max_m": [6, 6, 6]}}}, 422, ["body", "candidates", "region"]),
    ({"positions": {"sites": ["nowhere"]}}, 422, ["body", "positions", "sites", 0]),
    ({"positions": {"along_tract": {"ds_m": 0.02, "centreline": "colon_only"}}}, 422,
     ["body", "positions", "along_tract", "centreline"]),
    ({"channel": {"rays": 200_000}}, 422, ["body", "channel", "rays"]),
    ({"phantom": "nope"}, 404, ["body", "phantom"]),
    ({"surprise": 1}, 422, ["body", "surprise"]),
])
def test_bad_coverage_requests_are_refused_naming_the_field(client, changes, status, loc):
    r = client.post("/v1/design/coverage", json={**TINY_COVERAGE, **changes})
    assert r.status_code == status, r.text
    assert _loc(r) == loc, r.json()
    assert [j["id"] for j in client.get("/v1/design/coverage").json()["jobs"]] == [COVERAGE_ID]


@pytest.mark.parametrize("changes,status,loc", [
    ({"sensors": 60}, 422, ["body", "sensors"]),  # N above the candidates (the tiny coverage has ~54)
    ({"constraints": {"keep_out": [{"min_m": [-1, -1, -1], "max_m": [1, 1, 1]}]}}, 422,
     ["body", "constraints", "keep_out"]),
    ({"constraints": {"belts": [{"height_m": 0.9}]}}, 422, ["body", "constraints", "belts", 0]),
    ({"constraints": {"belts": [{"height_m": 0.05, "count": 3}]}}, 422, ["body", "constraints", "belts"]),
    ({"coverage": "cv-0000000000000bad"}, 404, ["body", "coverage"]),
    ({"criterion": "max"}, 422, ["body", "criterion"]),
])
def test_bad_layouts_are_refused_naming_the_field(client, changes, status, loc):
    body = {"coverage": COVERAGE_ID, "sensors": 5, "evaluate": None, **changes}
    r = client.post("/v1/design/layout", json=body)
    assert r.status_code == status, r.text
    assert _loc(r) == loc, r.json()
    assert client.get("/v1/design/layout").json() == {"jobs": []}


def test_a_layout_runs_on_the_queue_and_beats_or_ties_the_sites(client):
    r = client.post("/v1/design/layout", json={"coverage": COVERAGE_ID, "sensors": 5, "evaluate": None,
                                               "min_sensors": 4, "search": {"restarts": 2}})
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/design/layout/{job['id']}"
    deadline = time.monotonic() + 300  # a wait for the job, not a verdict on speed
    while job["state"] in ("queued", "running") and time.monotonic() < deadline:
        time.sleep(0.5)
        job = client.get(f"/v1/design/layout/{job['id']}").json()
    assert job["state"] == "done", job
    result = job["result"]
    assert len(result["sensors"]) == 5 and all(len(s["position_m"]) == 3 for s in result["sensors"])
    assert result["criterion_m"] is not None and result["baseline_criterion_m"] is not None
    # the sites are candidates of neither the search nor its constraints; the grid holds more choices, and
    # the search keeps the best it finds: here it is no worse than the best 5 of the 12 sites
    assert result["criterion_m"] <= result["baseline_criterion_m"] * (1 + 1e-9)
    md = client.get(f"/v1/design/layout/{job['id']}/report?format=md")
    assert md.status_code == 200 and "| organ |" in md.text
    m = client.get(f"/v1/design/coverage/{COVERAGE_ID}/map?metric=direct_path")
    assert m.status_code == 200 and len(m.json()["values"]) == len(m.json()["candidates_m"])
    p = client.get(f"/v1/design/coverage/{COVERAGE_ID}/plot?metric=snr_db")
    assert p.status_code == 200 and p.content[:4] == b"\x89PNG"
    assert client.delete(f"/v1/design/layout/{job['id']}").json()["deleted"] is True
