"""The full-wave job flow over real HTTP against ``capsule-rt serve`` subprocesses sharing one data
dir, with gprMax: a tiny two-cell-size job followed to done across a restart of the service (its
first, finished gprMax run is re-used, not re-run), its report in both formats against the library's
``compare()`` on the same gprMax outputs, its files; a running job cancelled (its gprMax process is
gone); a crash of the service while gprMax runs (the next start kills the orphaned gprMax and finishes
the job); malformed, oversize and export-only submissions.

Determinism without timing: the test finds a job's gprMax process by its command line and working
directory (``/proc``) and stops it (SIGSTOP), so the job cannot finish while the test restarts the
service or cancels it; the service must then kill the stopped process itself."""

from __future__ import annotations

import json
import os
import shutil
import signal
import time
from pathlib import Path

import httpx
import pytest

from fullwave.model import FdtdOptions
from fullwave.run import compare
from raytrace.body.library import get_phantom
from raytrace.spec import ChannelSpec
from tests.conftest import HANG_GUARD_S
from tests.e2e.jobs import JobServer, wait_for_job

pytestmark = pytest.mark.e2e

#: A z dipole in the half-space's muscle, 0.5 m from any surface, and one receiver 3 cm away: at 4 mm
#: cells and a 12 mm margin a 26 x 19 x 18-cell model (6 PML cells), 985 steps.
TINY = {"phantom": "half-space",
        "transmitter": {"position_m": [0.0, 0.5, 0.0], "polarization": [0, 0, 1], "pattern": "dipole"},
        "receivers": [{"name": "r3", "position_m": [0.03, 0.5, 0.0], "pattern": "dipole"}], "rays": 2000,
        "cell_m": 0.004, "margin_m": 0.012, "pml_cells": 6, "coarse_factor": 1.5}
FDTD = ("cell_m", "margin_m", "pml_cells", "coarse_factor", "export_only")


#: The server's settings for these tests.
SERVER_ENV = {"CAPSULE_RT_FULLWAVE_THREADS": "1", "CAPSULE_RT_FULLWAVE_MAX_CELL_UPDATES": "100000000"}


def _gprmax(run_dir: Path, input_name: str) -> int | None:
    """The pid of the gprMax process running ``input_name`` in ``run_dir``, if any (Linux /proc)."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
            cwd = os.readlink(entry / "cwd")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if b"gprMax" in argv and input_name.encode() in argv and cwd == str(run_dir) and state != "Z":
            return int(entry.name)
    return None


def _catch_gprmax(http: httpx.Client, job_id: str, run_dir: Path, input_name: str,
                  timeout_s: float = HANG_GUARD_S) -> int:
    """Wait for the job's gprMax on ``input_name`` and stop it (SIGSTOP): the job now waits for the test."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pid = _gprmax(run_dir, input_name)
        if pid is not None:
            os.kill(pid, signal.SIGSTOP)
            return pid
        status = http.get(f"/v1/fullwave/{job_id}").json()
        assert status["state"] in ("queued", "running"), status
        time.sleep(0.02)
    raise AssertionError(f"no gprMax process on {input_name} for {job_id}")


def _wait(http: httpx.Client, job_id: str, until) -> dict:
    return wait_for_job(http, f"/v1/fullwave/{job_id}", until)


def _gone(pid: int) -> bool:
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes()
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return b"gprMax" not in argv or state == "Z"


def test_fullwave_jobs_over_http_survive_a_restart_and_cancel(tmp_path):
    data, log = tmp_path / "data", tmp_path / "server.log"
    server = JobServer(data, log, SERVER_ENV)
    try:
        http = server.http
        r = http.post("/v1/fullwave", json={**TINY, "pml_cells": 1})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "pml_cells"]
        r = http.post("/v1/fullwave", json={**TINY, "cell_m": 0.001})  # 3.5e8 cell updates > 1e8
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "cell_m"]
        exported = server.api.fullwave_submit({**TINY, "export_only": True})
        assert exported.state == "done" and "model_40.in" in exported.files

        job = server.api.fullwave_submit(TINY)  # 4 mm, then 6 mm cells
        assert job.state in ("queued", "running") and job.runs_total == 2
        run_dir = data / "fullwave" / job.id / "run"
        assert http.get(f"/v1/fullwave/{job.id}/files/model_40.in").text == (run_dir / "model_40.in").read_text()
        pid = _catch_gprmax(http, job.id, run_dir, "model_60.in")  # the second run: the first has finished
        status = http.get(f"/v1/fullwave/{job.id}").json()
        assert status["state"] == "running" and status["runs_done"] == 1 and status["run"] == 1
        assert 0 < status["progress"] < 1 and "model_40.h5" in status["files"] and "model_60.h5" not in status["files"]
        r = http.get(f"/v1/fullwave/{job.id}/report")
        assert r.status_code == 409 and r.json()["detail"][0]["loc"] == ["path", "job_id"]
    finally:
        server.stop()  # mid-job: gprMax (stopped) is killed, the job left queued
    assert _gone(pid)
    assert json.loads((data / "fullwave" / job.id / "state.json").read_text())["state"] == "queued"
    first_h5 = (run_dir / "model_40.h5").stat().st_mtime_ns
    assert not (run_dir / "model_60.wall_s").exists()

    server = JobServer(data, log, SERVER_ENV)
    try:
        http = server.http
        final = server.api.fullwave_wait(job.id, poll_s=0.2, timeout_s=HANG_GUARD_S)
        assert final.state == "done" and final.runs_done == 2 and final.progress == 1.0 and final.eta_s == 0
        assert final.elapsed_s > 0 and final.error is None
        assert (run_dir / "model_40.h5").stat().st_mtime_ns == first_h5  # not run again after the restart
        report = server.api.fullwave_report(job.id)
        assert [r["reused"] for r in report["runs"]] == [True, False]
        md = server.api.fullwave_report(job.id, "md")
        assert "### 4 mm cells" in md and "### 6 mm cells" in md and "FDTD discretisation" in md
        log_text = http.get(f"/v1/fullwave/{job.id}/files/model_60.log").text  # gprMax's own log
        assert "Output directory" in log_text and str(data.resolve()) not in log_text  # no server path (item 9)

        # the library on the same inputs and the same gprMax outputs (downloaded) writes the same numbers
        mine = tmp_path / "library"
        mine.mkdir()
        for name in ("model_40.in", "model_40.h5", "model_60.in", "model_60.h5"):
            (mine / name).write_bytes(server.api.fullwave_file(job.id, name))
        for stem in ("model_40", "model_60"):
            (mine / f"{stem}.wall_s").write_text("1.0\n")
        spec = ChannelSpec.from_dict({k: v for k, v in TINY.items() if k not in FDTD})
        ours = compare(spec, get_phantom("half-space"), FdtdOptions(cell_m=0.004, margin_m=0.012, pml_cells=6),
                       mine, coarse_factor=1.5, reuse=True)
        for a, b in zip(report["runs"], ours["runs"]):
            for key in ("cells", "iterations", "transmitter_m", "receivers_m", "receivers", "tail_energy_fraction"):
                assert a[key] == b[key], key
        assert report["discretisation"] == ours["discretisation"]

        # cancel a running job: its gprMax process is killed
        second = server.api.fullwave_submit({**TINY, "coarse_factor": 0})
        run_dir = data / "fullwave" / second.id / "run"
        pid = _catch_gprmax(http, second.id, run_dir, "model_40.in")
        cancelling = server.api.fullwave_cancel(second.id)
        assert cancelling.cancel_requested and cancelling.deleted is False
        cancelled = _wait(http, second.id, lambda s: s["state"] not in ("queued", "running"))
        assert cancelled["state"] == "cancelled" and cancelled["error"] is None
        assert _gone(pid)
        assert http.get(f"/v1/fullwave/{second.id}/report").status_code == 409
        gone = server.api.fullwave_cancel(second.id)
        assert gone.deleted is True and http.get(f"/v1/fullwave/{second.id}").status_code == 404
        assert [j.id for j in server.api.fullwave_jobs().jobs] == [exported.id, job.id]

        # a crash (SIGKILL) while gprMax runs: gprMax, in a session of its own, outlives the service; the next
        # start kills it before it runs the job again, which then finishes
        third = server.api.fullwave_submit({**TINY, "coarse_factor": 0})
        run_dir = data / "fullwave" / third.id / "run"
        pid = _catch_gprmax(http, third.id, run_dir, "model_40.in")
    finally:
        server.http.close()
        server.api.close()
        server.proc.kill()
        server.proc.wait()
    assert not _gone(pid)  # the orphan, stopped
    server = JobServer(data, log, SERVER_ENV)
    try:
        final = server.api.fullwave_wait(third.id, poll_s=0.2, timeout_s=HANG_GUARD_S)
        assert final.state == "done" and final.runs_done == 1, final
        assert _gone(pid)
    finally:
        server.stop()
        if not _gone(pid):
            os.kill(pid, signal.SIGKILL)
    shutil.rmtree(data, ignore_errors=True)
