"""A sweep on a Dask scheduler and workers started as separate processes, as on a cluster:
``dask scheduler`` and ``dask worker`` (their command-line programs, over TCP), each worker with
its own local directory and no access to the uploaded phantom's stored files.

Oracle: the same sweep in this process (the serial engine), compared value for value
(``Table.equals``). Nothing here is timed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sweeps import load_spec, run_sweep
from sweeps.task import PhantomSource

TINY = {
    "name": "tiny-cluster",
    "phantom": "torso",
    "capsule_positions": [{"site": "small_intestine_1"}, {"s_m": 0.05}, {"site": "stomach"}],
    "receivers": [{"site": "belt_anterior"}, {"site": "belt_left"}],
    "frequencies_hz": [402e6],
    "channel": {"max_interactions": 2, "rays": 1000},
    "ranging": {"toa": {"methods": ["gcc"]}, "rss": {}},
    "trials": 3,
    "seed": 5,
    "chunk_positions": 1,
}


def _dask(command: str, *args: str, cwd: Path, log: Path) -> subprocess.Popen:
    """``dask <command> ARGS`` of this interpreter's environment, in its own directory."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    return subprocess.Popen([sys.executable, "-m", f"distributed.cli.dask_{command}", *args], cwd=cwd, env=env,
                            stdout=log.open("w"), stderr=subprocess.STDOUT)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A scheduler and two single-threaded workers, three processes started here and found through
    the scheduler file (as a batch job's processes find each other on a shared filesystem)."""
    root = tmp_path_factory.mktemp("dask-cluster")
    info = root / "scheduler.json"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file", str(info),
                   cwd=root, log=root / "scheduler.log")]
    try:
        for k in range(2):
            home = root / f"worker-{k}"
            home.mkdir()
            procs.append(_dask("worker", "--scheduler-file", str(info), "--nthreads", "1", "--nworkers", "1",
                               "--no-dashboard", "--local-directory", str(home), "--name", f"w{k}",
                               cwd=home, log=home / "worker.log"))
        from distributed import Client

        deadline = time.monotonic() + 300  # starting a process is not what this test judges
        while not info.exists():
            assert time.monotonic() < deadline, (root / "scheduler.log").read_text()
            time.sleep(0.2)
        address = json.loads(info.read_text())["address"]
        with Client(address, timeout="60s", set_as_default=False) as client:
            client.wait_for_workers(2, timeout=300)
            pids = set(client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids and not pids & {p.pid for p in procs[:1]}
        yield address
    finally:
        for p in reversed(procs):
            _stop(p)


def test_a_sweep_on_separately_started_processes_gives_the_local_table(cluster, tmp_path):
    spec = load_spec(TINY)
    local = run_sweep(spec, tmp_path / "serial", workers=0)
    remote = run_sweep(spec, tmp_path / "cluster", cluster=cluster)
    assert local.state["state"] == "done" and remote.state["state"] == "done", remote.state
    assert remote.state["engine"] == f"dask:{cluster}"
    assert remote.results.equals(local.results)


class _MovingFilesAway:
    """The Dask engine, except that the uploaded phantom's stored files are moved away once the
    sweep has read them and before any task runs: the workers cannot read them."""

    remote = True

    def __init__(self, address: str, stored: Path, moved: Path):
        from sweeps.engines import DaskEngine

        self.inner, self.stored, self.moved = DaskEngine(address), stored, moved
        self.name = self.inner.name
        self.shipped = None

    def run(self, fn, inputs, cancel=None, shared=None):
        shutil.move(self.stored, self.moved)
        self.shipped = shared
        return self.inner.run(fn, inputs, cancel, shared)

    def close(self):
        self.inner.close()


def test_an_uploaded_phantom_reaches_workers_that_cannot_read_its_files(cluster, tmp_path, glb_phantom):
    """The workers build the phantom from the bytes the engine ships them, once each."""
    from raytrace.body.gltf import load_phantom

    glb, manifest = glb_phantom()
    stored = tmp_path / "stored"
    stored.mkdir()
    (stored / "mesh.glb").write_bytes(glb)
    (stored / "manifest.json").write_text(json.dumps(manifest))
    phantom = load_phantom(glb, manifest)
    source = PhantomSource("upload-1", str(stored / "mesh.glb"), str(stored / "manifest.json"))
    spec = load_spec({**TINY, "phantom": "upload-1",
                      "receivers": [{"site": "sensor"}, {"position_m": [0.05, -0.12, 0]}],
                      "capsule_positions": [{"site": "capsule"}, {"position_m": [0.0, 0.01, -0.01]},
                                            {"position_m": [0.05, 0.05, 0.05]}]})
    local = run_sweep(spec, tmp_path / "serial", phantom=phantom, source=source, workers=0)
    engine = _MovingFilesAway(cluster, stored, tmp_path / "moved")
    try:
        remote = run_sweep(spec, tmp_path / "cluster", phantom=phantom, source=source, engine=engine)
    finally:
        engine.close()
    assert not stored.exists() and engine.shipped["phantom_files"].glb == glb
    assert remote.state["state"] == "done", remote.state
    assert remote.results.equals(local.results)
