"""POST /v1/fullwave validation, export-only jobs, the files endpoint and the job endpoints' errors, in
process (the job flow over real HTTP with gprMax, cancellation and a restart is
tests/e2e/test_fullwave_http.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from fullwave.model import FdtdOptions, build_model
from raytrace.body.library import get_phantom
from raytrace.spec import ChannelSpec
from service.app import create_app
from tests.e2e.test_fullwave_http import TINY
from tests.service.test_uploads import upload


@pytest.fixture
def client(make_settings):
    with TestClient(create_app(make_settings(fullwave_max_queue=1, fullwave_max_cell_updates=10**8)),
                    raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize("changes,loc", [
    ({"cell_m": 0.05}, ["body", "cell_m"]),
    ({"cell_m": "4 mm"}, ["body", "cell_m"]),
    ({"pml_cells": 2}, ["body", "pml_cells"]),
    ({"margin_m": -0.01}, ["body", "margin_m"]),
    ({"margin_m": 0.0}, ["body", "margin_m"]),  # the antennas' box is flat: no grid
    ({"coarse_factor": 5}, ["body", "coarse_factor"]),
    ({"coarse_factor": 1}, ["body", "coarse_factor"]),  # the same run twice
    ({"coarse_factor": 0.01}, ["body", "coarse_factor"]),  # 0.04 mm cells
    ({"rays": 6000}, ["body", "rays"]),  # this server's max_rays (5000 in tests)
    ({"receivers": [{"position_m": [0.03, 0.5]}]}, ["body", "receivers", 0, "position_m"]),
    ({"outputs": {"cfr": True}}, ["body", "outputs"]),  # a channel request's field a full-wave job has not
    ({"surprise": 1}, ["body", "surprise"]),
])
def test_malformed_bodies_get_422_naming_the_field(client, changes, loc):
    r = client.post("/v1/fullwave", json={**TINY, **changes})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == loc, r.json()
    assert client.get("/v1/fullwave").json() == {"jobs": []}


def test_unknown_phantom_scenario_or_site_is_404(client):
    r = client.post("/v1/fullwave", json={**TINY, "receivers": [{"site": "nowhere"}]})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["body", "receivers", 0, "site"]
    r = client.post("/v1/fullwave", json={**TINY, "phantom": "nope"})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["body", "phantom"]
    r = client.post("/v1/fullwave", json={"scenario": "nope"})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["body", "scenario"]


def test_an_oversize_model_is_refused_before_it_is_queued(client):
    """The server's bound here is 1e8 cell updates. 1 mm cells: 66 x 37 x 36 cells x 3941 steps = 3.5e8,
    refused naming cell_m; 4 mm (8.8e6) with a second run at 1 mm (coarse_factor 0.25): the second run
    is the big one, so coarse_factor is named."""
    r = client.post("/v1/fullwave", json={**TINY, "cell_m": 0.001, "coarse_factor": 0})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "cell_m"], r.text
    msg = r.json()["detail"][0]["msg"]
    assert "cell updates" in msg and "1e+08" in msg
    r = client.post("/v1/fullwave", json={**TINY, "coarse_factor": 0.25})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "coarse_factor"], r.text
    assert client.get("/v1/fullwave").json() == {"jobs": []}


def test_export_only_is_done_at_once_with_the_librarys_inputs(client):
    r = client.post("/v1/fullwave", json={**TINY, "export_only": True})
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/fullwave/{job['id']}"
    assert job["state"] == "done" and job["export_only"] and job["runs_total"] == 2 and job["runs_done"] == 0
    assert job["files"] == ["model_40.in", "model_60.in", "report.json", "report.md"]
    # the inputs are fullwave.model's, byte for byte, for the same request and options
    spec = ChannelSpec.from_dict({k: v for k, v in TINY.items()
                                  if k not in ("cell_m", "margin_m", "pml_cells", "coarse_factor")})
    for run, h in zip(job["runs"], (0.004, 0.006)):
        model = build_model(spec, get_phantom("half-space"), FdtdOptions(cell_m=h, margin_m=0.012, pml_cells=6))
        assert run["cell_m"] == h and run["cells"] == list(model.cells) and run["iterations"] == model.iterations
        assert run["cell_updates"] == int(np.prod(model.cells)) * model.iterations
        text = client.get(f"/v1/fullwave/{job['id']}/files/{run['input']}")
        assert text.status_code == 200 and text.headers["content-type"].startswith("text/plain")
        assert text.text == model.input_text
    report = client.get(f"/v1/fullwave/{job['id']}/report").json()
    assert [r["ran"] for r in report["runs"]] == [False, False] and report["discretisation"] == []
    md = client.get(f"/v1/fullwave/{job['id']}/report", params={"format": "md"})
    assert md.headers["content-type"].startswith("text/markdown") and "(not run)" in md.text
    gone = client.delete(f"/v1/fullwave/{job['id']}").json()
    assert gone["deleted"] is True and client.get(f"/v1/fullwave/{job['id']}").status_code == 404


def test_an_uploaded_phantom_is_looked_up(client, glb_phantom):
    glb, manifest = glb_phantom()
    phantom_id = upload(client, glb, manifest).json()["id"]
    body = {"phantom": phantom_id, "transmitter": {"site": "capsule", "polarization": [0, 0, 1]},
            "receivers": [{"site": "sensor"}], "cell_m": 0.01, "margin_m": 0.02, "pml_cells": 4,
            "coarse_factor": 0, "export_only": True}
    r = client.post("/v1/fullwave", json=body)
    assert r.status_code == 202, r.text
    assert r.json()["phantom"] == phantom_id and r.json()["files"][0] == "model_100.in"


def test_files_are_the_jobs_own_only(client):
    job = client.post("/v1/fullwave", json={**TINY, "export_only": True}).json()
    for name in ("job.json", "state.json", "model_40.wall_s", "model_40.in.bak", "%2e%2e%2fjob.json", "..%2fjob.json"):
        r = client.get(f"/v1/fullwave/{job['id']}/files/{name}")
        assert r.status_code in (404, 422), (name, r.status_code)
        assert r.status_code == 404 or r.json()["detail"][0]["loc"] == ["path", "name"]
    r = client.get(f"/v1/fullwave/{job['id']}/files/model_40.h5")  # no run, no output
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["path", "name"]


def test_without_gprmax_a_run_is_501_and_export_only_works(client, monkeypatch):
    """A server without gprMax: 501 (the server lacks the tool; the request is fine and retrying will
    not help) naming export_only, which works without it."""
    monkeypatch.setattr("service.fullwave_jobs.gprmax_available", lambda: False)
    r = client.post("/v1/fullwave", json=TINY)
    assert r.status_code == 501 and r.json()["detail"][0]["loc"] == ["body", "export_only"]
    assert "export_only" in r.json()["detail"][0]["msg"]
    assert client.post("/v1/fullwave", json={**TINY, "export_only": True}).status_code == 202


def test_unknown_jobs_bad_ids_and_the_queue_bound(client):
    assert client.get("/v1/fullwave/fw-0000000000000000").status_code == 404
    assert client.get("/v1/fullwave/not-an-id").status_code == 422
    assert client.get("/v1/fullwave/sw-0000000000000000").status_code == 422  # a sweep's id is no job here
    assert client.delete("/v1/fullwave/fw-0000000000000000").status_code == 404
    first = client.post("/v1/fullwave", json=TINY)
    assert first.status_code == 202 and first.json()["state"] in ("queued", "running")
    job_id = first.json()["id"]
    r = client.post("/v1/fullwave", json=TINY)  # fullwave_max_queue 1
    assert r.status_code == 503 and r.headers["retry-after"] and r.json()["detail"][0]["loc"] == ["server"]
    r = client.get(f"/v1/fullwave/{job_id}/report", params={"format": "xml"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["query", "format"]
    cancelled = client.delete(f"/v1/fullwave/{job_id}").json()
    assert cancelled["cancel_requested"] and cancelled["deleted"] is False
    assert json.loads(client.get("/v1/fullwave").content)["jobs"][0]["id"] == job_id


def test_a_job_past_its_wall_time_fails_saying_so(make_settings):
    """The wall-time bound counts every start of a job: one whose earlier starts used it all (state.json
    says 10 s of a 5 s bound) fails at once, without starting gprMax, naming the setting. (The app's
    lifespan is not run here, so no runner takes the job before the test calls execute.)"""
    import threading

    app = create_app(make_settings(fullwave_max_wall_s=5.0))
    app.state.capsule.registry.load_builtins(True)
    client = TestClient(app, raise_server_exceptions=False)
    job = client.post("/v1/fullwave", json={**TINY, "coarse_factor": 0})
    assert job.status_code == 202 and job.json()["state"] == "queued", job.text
    jobs = app.state.fullwave
    d = jobs.job_dir(job.json()["id"])
    jobs.write_state(d, {**jobs.read_state(d), "elapsed_s": 10.0})
    assert jobs.execute(job.json()["id"], threading.Event()) == "failed"
    status = client.get(f"/v1/fullwave/{job.json()['id']}").json()
    assert status["state"] == "failed" and "fullwave_max_wall_s" in status["error"]
    assert status["elapsed_s"] >= 10.0 and not (d / "run" / "model_40.log").exists()  # gprMax never started


def test_a_model_over_the_memory_share_is_refused_before_it_is_queued(make_settings):
    """gprMax holds its whole grid: a model whose bound (GPRMAX_BYTES_PER_CELL per cell, PML included,
    plus the overhead) exceeds this server's memory share per computation is refused naming the field
    that sets its cells. The share here is the 4 mm model's bound + 1 MiB: 4 mm passes, 2 mm does not."""
    from fullwave.model import GPRMAX_BYTES_PER_CELL, GPRMAX_OVERHEAD_BYTES

    def bound(cell_m: float) -> int:
        # the grid as gprMax sees it, counted here: ceil(box / cell) per axis plus the PML both sides;
        # the box is the antennas' box grown by the margin
        lo = np.minimum(TINY["transmitter"]["position_m"], TINY["receivers"][0]["position_m"]) - TINY["margin_m"]
        hi = np.maximum(TINY["transmitter"]["position_m"], TINY["receivers"][0]["position_m"]) + TINY["margin_m"]
        cells = np.ceil((hi - lo) / cell_m - 1e-9) + 2 * TINY["pml_cells"]
        return int(np.prod(cells)) * GPRMAX_BYTES_PER_CELL + GPRMAX_OVERHEAD_BYTES

    share = bound(0.004) + 2**20
    assert bound(0.002) > share
    with TestClient(create_app(make_settings(max_compute_memory_bytes=share, max_concurrency=1)),
                    raise_server_exceptions=False) as c:
        r = c.post("/v1/fullwave", json={**TINY, "coarse_factor": 0, "export_only": True})
        assert r.status_code == 202, r.text
        r = c.post("/v1/fullwave", json={**TINY, "cell_m": 0.002, "coarse_factor": 0, "export_only": True})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "cell_m"], r.text
        assert "MiB" in r.json()["detail"][0]["msg"]
        r = c.post("/v1/fullwave", json={**TINY, "coarse_factor": 0.5, "export_only": True})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "coarse_factor"], r.text


def test_downloads_and_errors_do_not_show_the_servers_paths(client):
    """Issue 34, item 9: gprMax writes the absolute paths of its input and output into its log, and a failed
    run's error names its input file: downloads and statuses showed the server's data directory. The log
    here is what gprMax 4 writes (its lines with paths), in the job's own run directory."""
    jobs = client.app.state.fullwave
    job = client.post("/v1/fullwave", json={**TINY, "export_only": True}).json()
    run = jobs.root / job["id"] / "run"
    absolute = str(run.resolve())
    (run / "model_40.log").write_text(
        f"Constants/variables used/available for Python scripting: {{inputfile: {absolute}/model_40.in}}\n"
        f"--- Model 1/1, input file: model_40.in ----\nOutput directory: {absolute}\n")
    jobs.write_state(run.parent, {**jobs.read_state(run.parent), "state": "failed",
                                  "error": f"RuntimeError: gprMax failed on {absolute}/model_40.in (exit 1)"})
    data_dir = str(jobs.settings.data_dir.resolve())
    r = client.get(f"/v1/fullwave/{job['id']}/files/model_40.log")
    assert r.status_code == 200 and data_dir not in r.text and "/tmp" not in r.text, r.text
    assert "inputfile: ./model_40.in" in r.text and "Output directory: ." in r.text
    status = client.get(f"/v1/fullwave/{job['id']}").json()
    assert data_dir not in status["error"] and "gprMax failed on ./model_40.in" in status["error"], status["error"]
    r = client.get(f"/v1/fullwave/{job['id']}/files/model_40.in")
    assert r.status_code == 200 and r.text == (run / "model_40.in").read_text()  # nothing to redact: as written
