"""The sweep job flow over real HTTP against ``capsule-rt serve`` subprocesses sharing one data dir:
submit (202), progress, results as Parquet / CSV / JSON, a malformed spec's 422, cancel, and a
restart of the service in the middle of a running job, which then finishes with every row once and
without recomputing the tasks stored before the restart."""

from __future__ import annotations

import io
import json

import httpx
import pyarrow.parquet as pq
import pytest

from tests.e2e.jobs import JobServer, wait_for_job

pytestmark = pytest.mark.e2e

SMALL = {"name": "small", "capsule_positions": [{"site": "small_intestine_1"}, {"s_m": 0.3}],
         "receivers": [{"site": "belt_anterior"}, {"site": "belt_anterior_left"}], "frequencies_hz": [402e6],
         "channel": {"rays": 1000, "max_interactions": 2}, "ranging": {"toa": {"methods": ["gcc"]}}, "trials": 5}
LONG = {**SMALL, "name": "long", "capsule_positions": {"along_tract": {"ds_m": 0.06}}, "chunk_positions": 1,
        "channel": {"rays": 4000, "max_interactions": 3}}


#: The server's settings for these tests.
SERVER_ENV = {"CAPSULE_RT_SWEEP_WORKERS": "1"}


def _wait(http: httpx.Client, sweep_id: str, until) -> dict:
    return wait_for_job(http, f"/v1/sweeps/{sweep_id}", until)


def test_sweep_jobs_over_http_survive_a_restart(tmp_path):
    data, log = tmp_path / "data", tmp_path / "server.log"
    server = JobServer(data, log, SERVER_ENV)
    try:
        http = server.http
        r = http.post("/v1/sweeps", json={**SMALL, "channel": {"rays": 0}})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "channel", "rays"]

        small = http.post("/v1/sweeps", json=SMALL)
        assert small.status_code == 202, small.text
        small_id = small.json()["id"]
        done = _wait(http, small_id, lambda s: s["state"] not in ("queued", "running"))
        assert done["state"] == "done" and done["done"] == done["total"] == 2 and done["eta_s"] == 0
        assert done["elapsed_s"] > 0 and done["failures"] == []

        r = http.get(f"/v1/sweeps/{small_id}/results", params={"format": "parquet"})
        assert r.status_code == 200 and r.headers["x-sweep-complete"] == "true"
        table = pq.read_table(io.BytesIO(r.content))
        assert table.num_rows == 4
        for key in ("capsule", "receiver", "frequency_hz", "first_delay_s", "path_gain_db", "paths",
                    "toa_gcc_distance_m", "toa_gcc_error_m"):
            assert key in table.column_names
        csv_text = http.get(f"/v1/sweeps/{small_id}/results", params={"format": "csv"}).text
        assert csv_text.splitlines()[0].split(",")[:3] == ['"position_index"', '"capsule"', '"capsule_x_m"']
        assert len(csv_text.strip().splitlines()) == 5
        as_json = http.get(f"/v1/sweeps/{small_id}/results", params={"format": "json"}).json()
        assert as_json["rows"] == json.loads(json.dumps(table.to_pylist()))

        long = http.post("/v1/sweeps", json=LONG).json()
        queued = http.post("/v1/sweeps", json={**SMALL, "name": "to cancel"}).json()
        cancelled = http.delete(f"/v1/sweeps/{queued['id']}").json()
        assert cancelled["state"] == "cancelled" and cancelled["deleted"] is False
        running = _wait(http, long["id"], lambda s: s["tasks_done"] >= 2)
        assert running["state"] == "running" and 0 < running["eta_s"] and running["total"] == 12
        partial = http.get(f"/v1/sweeps/{long['id']}/results", params={"format": "json"})
        assert partial.headers["x-sweep-complete"] == "false" and len(partial.json()["rows"]) >= 4
    finally:
        server.stop()  # mid-job: the running sweep is interrupted and left queued
    parts = data / "sweeps" / long["id"] / "parts"
    before = {p.name: p.stat().st_mtime_ns for p in parts.glob("task-*.parquet")}
    assert 2 <= len(before) < 12

    server = JobServer(data, log, SERVER_ENV)
    try:
        http = server.http
        assert http.get(f"/v1/sweeps/{small_id}").json()["state"] == "done"
        assert http.get(f"/v1/sweeps/{queued['id']}").json()["state"] == "cancelled"
        final = _wait(http, long["id"], lambda s: s["state"] not in ("queued", "running"))
        assert final["state"] == "done" and final["done"] == 12, final
        rows = pq.read_table(io.BytesIO(http.get(f"/v1/sweeps/{long['id']}/results").content)).to_pylist()
        keys = [(r["position_index"], r["receiver_index"]) for r in rows]
        assert len(keys) == len(set(keys)) == 12 * 2
        for name, mtime in before.items():  # stored before the restart: not recomputed
            assert (parts / name).stat().st_mtime_ns == mtime, name
        gone = http.delete(f"/v1/sweeps/{small_id}").json()
        assert gone["deleted"] is True and http.get(f"/v1/sweeps/{small_id}").status_code == 404
    finally:
        server.stop()
