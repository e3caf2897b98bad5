"""POST /v1/sweeps validation and the job endpoints' errors, in process (no job needs to run here;
the job flow over real HTTP, with a restart, is tests/e2e/test_sweeps_http.py)."""

from __future__ import annotations

import json
from dataclasses import replace

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


@pytest.fixture
def small_budget(make_settings):
    """A server whose traces may hold 8 MiB each (64 MiB / 8) and shoot 2e5 ray segments."""
    with TestClient(create_app(make_settings(sweep_workers=1, sweep_max_queue=1, max_compute_memory_bytes=64 << 20,
                                             max_concurrency=8, max_ray_segments=200_000)),
                    raise_server_exceptions=False) as c:
        yield c


# Estimates (raytrace.solver.footprint, docs/service.md "Memory and work model"), one belt receiver:
# 5000 rays, 3 interactions, 80 dB: 26 797 segments per trace, 3.5 MiB, plus 10.1 MiB for a 201-point band;
# 5000 rays, 10 interactions, 300 dB: 1.35e6 segments (over 2e5), 136 MiB, most of it the launch batches' trees.
@pytest.mark.parametrize("channel,field", [
    ({"rays": 5000, "max_interactions": 3, "band": {"span_hz": 20e6, "points": 201}}, "band.points"),
    ({"rays": 5000, "max_interactions": 10, "dynamic_range_db": 300}, "rays"),
])
def test_a_sweep_whose_trace_cannot_fit_is_refused_at_submission(small_budget, channel, field):
    """The channel endpoint's footprint rule, applied to each trace of a sweep before any of its work:
    a 422 naming the sweep spec field (`channel.` + the channel request's field), and no job stored."""
    r = small_budget.post("/v1/sweeps", json={**SPEC, "channel": channel})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "channel", *field.split(".")], r.json()
    assert small_budget.get("/v1/sweeps").json() == {"sweeps": []}
    # the channel endpoint refuses the same trace naming the same field: one rule
    band = channel.get("band")
    body = {"phantom": "torso", "transmitter": {"site": "stomach"}, "receivers": [{"site": "belt_anterior"}],
            **{k: v for k, v in channel.items() if k != "band"},
            **({"band": {"start_hz": 392e6, "stop_hz": 412e6, "points": band["points"]}} if band else {})}
    r = small_budget.post("/v1/channel", json=body)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", *field.split(".")], r.text


def test_a_sweep_memory_refusal_names_the_largest_term(small_budget):
    """Under the 2e5-segment cap (1.35e6 is refused at `rays`), a bigger cap leaves the memory rule:
    136 MiB over the 8 MiB share, dominated by the trees of max_interactions."""
    from sweeps.plan import make_plan
    from sweeps.spec import SweepSpec, SweepSpecError

    jobs = small_budget.app.state.sweeps
    torso = small_budget.app.state.capsule.registry.get("torso")
    limits = jobs.limits
    assert limits.max_trace_bytes == 8 << 20 and limits.max_ray_segments == 200_000
    big = SweepSpec.from_dict({**SPEC, "channel": {"rays": 5000, "max_interactions": 10, "dynamic_range_db": 300}},
                              limits)
    with pytest.raises(SweepSpecError) as err:
        make_plan(big, torso, "torso", replace(limits, max_ray_segments=10**9))
    assert err.value.field == "channel.max_interactions" and "136 MiB" in err.value.reason
    # what fits the same budget plans: 21 band points instead of 201 (3.5 + 1.1 MiB)
    fits = SweepSpec.from_dict({**SPEC, "channel": {"rays": 5000, "max_interactions": 3,
                                                    "band": {"span_hz": 20e6, "points": 21}}}, limits)
    assert make_plan(fits, torso, "torso", limits).n_positions == 1


def test_spec_bodies_that_cannot_be_parsed_are_400_not_500(client):
    """Nesting past the parsers' recursion (a 500 before) and YAML aliases that expand a few hundred bytes
    into 1e8 values (validating them took minutes of a worker thread) are refused naming the body."""
    deep = b"[" * 100_000 + b"]" * 100_000
    for body, kind in ((deep, "application/json"), (b"a: " + b"[" * 100_000, "application/yaml")):
        r = client.post("/v1/sweeps", content=body, headers={"content-type": kind})
        assert r.status_code == 400 and r.json()["detail"][0]["loc"] == ["body"], r.text
    bomb = "&b0 [x, x, x, x, x, x, x, x, x, x]"
    for i in range(1, 8):  # 10^8 strings once expanded
        bomb = f"&b{i} [{bomb}, " + ", ".join([f"*b{i - 1}"] * 9) + "]"
    r = client.post("/v1/sweeps", content=f"capsule_positions: [{{site: stomach}}]\nchannel: {{homogeneous: "
                    f"{{tissue: {bomb}}}}}\n", headers={"content-type": "application/yaml"})
    assert r.status_code == 400 and r.json()["detail"][0]["loc"] == ["body"], r.text
    assert "YAML aliases" in r.json()["detail"][0]["msg"]


@pytest.mark.parametrize("band", [{"start_hz": 400e6, "stop_hz": 420e6, "points": 10**11},
                                  {"span_hz": 20e6, "points": 10**9},
                                  {"start_hz": 400e6, "stop_hz": 420e6, "points": 202}])
def test_band_points_are_bounded_before_any_frequency_is_allocated(client, monkeypatch, band):
    """Issue 34, item 2: a sweep's channel.band.points was checked after np.linspace had allocated the band
    (1e9 points: 8.56 GB, then a 422 after 81 s; 1e11: a 500 asking for 745 GiB). Now a 422 naming the field,
    and no linspace of more than the limit's points ever runs."""
    import numpy as np

    real, asked = np.linspace, []

    def linspace(start, stop, num=50, *args, **kwargs):
        asked.append(int(num))
        if num > 10**6:
            raise MemoryError(f"a {num}-point linspace")
        return real(start, stop, num, *args, **kwargs)

    monkeypatch.setattr(np, "linspace", linspace)
    r = client.post("/v1/sweeps", json={**SPEC, "channel": {**SPEC["channel"], "band": band}})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "channel", "band", "points"], r.text
    assert "between 2 and 201" in r.json()["detail"][0]["msg"]
    assert max(asked, default=0) <= 201
