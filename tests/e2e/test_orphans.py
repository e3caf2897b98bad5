"""No orphan outlives a SIGKILL of the server (issue 34, item 5): a sweep's pool workers (~430 MB each) and
the multiprocessing resource tracker stayed alive after the server was killed, and the next start did not
reap them (three kills: nine processes, 2.6 GB).

A real ``capsule-rt serve`` runs a sweep; once its pool's workers exist (read from /proc: the server's
children running multiprocessing's spawn_main), the server is SIGKILLed, a new one starts on the same data
directory, and once it is ready every process of the first one is gone (or a zombie, which holds no memory
and only waits for its reaper). Every verdict is about process state; the only clock is a hang guard.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from tests.conftest import HANG_GUARD_S
from tests.e2e.jobs import JobServer, wait_for_job

pytestmark = [pytest.mark.e2e, pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="Linux /proc")]

SPEC = {"name": "orphans", "capsule_positions": [{"site": "small_intestine_1"}, {"s_m": 0.3}],
        "receivers": [{"site": "belt_anterior"}], "channel": {"rays": 1000, "max_interactions": 2},
        "ranging": {"toa": {"methods": ["gcc"]}}, "trials": 2, "chunk_positions": 1}


def _stat(pid: int) -> tuple[int, str, int] | None:
    """(parent pid, state, start time in clock ticks) of a live process; None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), fields[0], int(fields[19])


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _children(pid: int) -> dict[int, int]:
    """pid -> start time of every child of ``pid``."""
    out = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            stat = _stat(int(entry))
            if stat is not None and stat[0] == pid:
                out[int(entry)] = stat[2]
    return out


def _alive(pid: int, started: int) -> bool:
    """The same process (same start time: not a recycled pid) still exists and is not a zombie."""
    stat = _stat(pid)
    return stat is not None and stat[2] == started and stat[1] != "Z"


def _until(predicate, what: str):
    deadline = time.monotonic() + HANG_GUARD_S
    while not (value := predicate()):
        if time.monotonic() > deadline:
            raise AssertionError(f"hung: never saw {what}")
        time.sleep(0.1)
    return value


def test_a_sigkilled_servers_pool_is_reaped_at_the_next_start(tmp_path):
    data = tmp_path / "data"
    first = JobServer(data, tmp_path / "first.log", {"CAPSULE_RT_SWEEP_WORKERS": "2"})
    try:
        sweep = first.http.post("/v1/sweeps", json=SPEC)
        assert sweep.status_code == 202, sweep.text
        wait_for_job(first.http, f"/v1/sweeps/{sweep.json()['id']}", lambda s: s["state"] == "done", HANG_GUARD_S)
        # the pool stays warm between jobs: its workers and the resource tracker are the server's children
        children = _children(first.proc.pid)
        workers = {p: t for p, t in children.items() if "spawn_main" in _cmdline(p)}
        tracker = {p: t for p, t in children.items() if "resource_tracker" in _cmdline(p)}
        assert len(workers) == 2 and len(tracker) == 1, {p: _cmdline(p) for p in children}
        assert all(os.getpgid(p) != os.getpgid(first.proc.pid) for p in workers)  # a process group of their own
    finally:
        first.proc.send_signal(signal.SIGKILL)
        first.proc.wait()
        first.http.close()
        first.api.close()
    left = {**workers, **tracker}
    survivors = {p for p, t in left.items() if _alive(p, t)}
    assert set(workers) <= survivors  # what the server's death alone leaves behind: the orphans to reap

    second = JobServer(data, tmp_path / "second.log", {"CAPSULE_RT_SWEEP_WORKERS": "2"})
    try:
        # ready means the runner took the data directory's lock and reaped what the last holder left
        assert [p for p in workers if _alive(p, workers[p])] == []
        # the tracker exits by itself once no worker holds its pipe
        _until(lambda: not any(_alive(p, t) for p, t in tracker.items()), "the orphaned resource tracker exit")
        assert second.http.get("/v1/sweeps").status_code == 200
    finally:
        second.stop()
