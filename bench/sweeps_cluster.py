"""Sweeps across machines: a Dask scheduler and workers started as separate processes, as on a cluster.

    python -m bench.sweeps_cluster                  # 1 then 2 workers, over TCP on loopback
    python -m bench.sweeps_cluster --netns          # each worker in its own network namespace (a "host"),
                                                    # behind a veth pair on a bridge, links shaped to 1 Gbit/s
    python -m bench.sweeps_cluster --quick          # a short sweep (smoke run)

What runs: ``dask scheduler`` and ``dask worker`` (their command-line programs: ``python -m
distributed.cli.dask_scheduler`` / ``dask_worker``), one thread per worker, each worker with its
own local directory, found through a scheduler file as a batch job's processes find each other;
the sweep (capsule every ``ds`` along the torso's tract x the 12 sensor sites, 402 MHz, 2e4 rays,
4 interactions, GCC TOA) is submitted from this process through :class:`sweeps.engines.DaskEngine`,
its tasks pinned to one tracer thread (``TaskInput.tracer_threads``). The same sweep runs first in
this process (the serial engine, one tracer thread: the reference table and the per-trace cost
without any engine), then on 1 and on 2 workers, ``--repeat`` times each in alternating order (the
workers are started afresh each time), the best run of each count kept.

Reported per worker count: start-up (processes started to every worker connected, then each
worker warmed: kernels from numba's cache, the phantom and its scene), the timed sweep's
throughput (links per second, and per worker), the efficiency (throughput over the worker count
times the 1-worker throughput), the per-task time on the workers, and the bytes each task ships
in and out (pickled: what crosses the network). docs/sweeps.md, "Across machines", projects the
scaling from those. Nothing is asserted; the load average is printed with the numbers (the VM is
shared: CPU contention from other work lowers every throughput, the ratios less so).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

from bench.common import ROOT

BRIDGE, SUBNET = "crt-br0", "10.77.0"


def spec(ds_m: float) -> dict:
    return {"name": "cluster-bench", "capsule_positions": {"along_tract": {"ds_m": ds_m}}, "receivers": "sensors",
            "frequencies_hz": [402e6], "channel": {"rays": 20_000, "max_interactions": 4, "dynamic_range_db": 60},
            "ranging": {"toa": {"methods": ["gcc"], "snr_db": 30}}, "trials": 20, "seed": 1, "chunk_positions": 2}


def warm() -> float:
    """What a worker does once: the kernels (numba's cache), the torso and its scenes."""
    t0 = time.perf_counter()
    from bench import scenes
    from raytrace.solver.tracer import warm_up

    warm_up()
    phantom = scenes.torso()
    scenes.trace(phantom, scenes.transmitter(phantom), scenes.receivers(phantom)[:1], rays=1000, max_interactions=1)
    return time.perf_counter() - t0


def _run(cmd: list[str]) -> None:
    subprocess.run(cmd, check=True, capture_output=True)


class Hosts:
    """Network namespaces ``crt-w<k>``, each with a veth pair on the bridge :data:`BRIDGE`
    (``SUBNET.1`` this machine, ``SUBNET.<10 + k>`` worker k), links shaped to ``rate``. Needs root
    and iproute2; everything made is removed by :meth:`close`."""

    def __init__(self, count: int, rate: str = "1gbit"):
        self.count, self.made = count, []
        _run(["ip", "link", "add", BRIDGE, "type", "bridge"])
        self.made.append(("link", BRIDGE))
        _run(["ip", "addr", "add", f"{SUBNET}.1/24", "dev", BRIDGE])
        _run(["ip", "link", "set", BRIDGE, "up"])
        self.shaped = True
        for k in range(count):
            ns, outer, inner = f"crt-w{k}", f"crt-v{k}", f"crt-v{k}p"
            _run(["ip", "netns", "add", ns])
            self.made.append(("netns", ns))
            _run(["ip", "link", "add", outer, "type", "veth", "peer", "name", inner])
            self.made.append(("link", outer))
            _run(["ip", "link", "set", inner, "netns", ns])
            _run(["ip", "link", "set", outer, "master", BRIDGE])
            _run(["ip", "link", "set", outer, "up"])
            for cmd in (["ip", "addr", "add", f"{SUBNET}.{10 + k}/24", "dev", inner],
                        ["ip", "link", "set", inner, "up"], ["ip", "link", "set", "lo", "up"]):
                _run(["ip", "netns", "exec", ns, *cmd])
            for dev, where in ((outer, []), (inner, ["ip", "netns", "exec", ns])):  # both directions
                try:
                    _run([*where, "tc", "qdisc", "add", "dev", dev, "root", "tbf", "rate", rate, "burst", "256kb",
                          "latency", "50ms"])
                except subprocess.CalledProcessError:
                    self.shaped = False

    def prefix(self, k: int) -> list[str]:
        return ["ip", "netns", "exec", f"crt-w{k}"]

    def host(self, k: int | None = None) -> str:
        return f"{SUBNET}.1" if k is None else f"{SUBNET}.{10 + k}"

    def close(self) -> None:
        for kind, name in reversed(self.made):
            subprocess.run(["ip", kind, "del", name], capture_output=True)


class Cluster:
    """A scheduler process now, workers added and removed (module doc)."""

    def __init__(self, root: Path, hosts: Hosts | None = None):
        self.root, self.hosts, self.workers = root, hosts, []
        self.info = root / "scheduler.json"
        self.env = {**os.environ, "PYTHONPATH": ROOT}
        host = hosts.host() if hosts else "127.0.0.1"
        self.scheduler = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", host, "--port", "0", "--no-dashboard",
             "--scheduler-file", str(self.info)], cwd=root, env=self.env, stdout=(root / "scheduler.log").open("w"),
            stderr=subprocess.STDOUT)
        while not self.info.exists():
            if self.scheduler.poll() is not None:
                raise RuntimeError((root / "scheduler.log").read_text()[-3000:])
            time.sleep(0.1)
        self.address = json.loads(self.info.read_text())["address"]

    def add_workers(self, count: int) -> None:
        for k in range(len(self.workers), len(self.workers) + count):
            home = self.root / f"worker-{k}"
            home.mkdir(exist_ok=True)
            cmd = [sys.executable, "-m", "distributed.cli.dask_worker", self.address, "--nthreads", "1",
                   "--nworkers", "1", "--no-dashboard", "--local-directory", str(home), "--name", f"w{k}"]
            if self.hosts:
                cmd = [*self.hosts.prefix(k), *cmd, "--host", self.hosts.host(k)]
            self.workers.append(subprocess.Popen(cmd, cwd=home, env=self.env, stdout=(home / "worker.log").open("w"),
                                                 stderr=subprocess.STDOUT))

    def stop_workers(self) -> None:
        for p in self.workers:
            if p.poll() is None:
                p.terminate()
        for p in self.workers:
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.workers = []

    def close(self) -> None:
        self.stop_workers()
        if self.scheduler.poll() is None:
            self.scheduler.terminate()
            self.scheduler.wait(timeout=60)


class Recording:
    """:class:`sweeps.engines.DaskEngine`, recording each task's time on its worker and the pickled
    bytes of its input and output."""

    remote = True

    def __init__(self, client):
        from sweeps.engines import DaskEngine

        self.inner = DaskEngine(client.scheduler.address, client=client)
        self.name = self.inner.name
        self.task_s, self.task_cpu_s, self.in_bytes, self.out_bytes, self.workers = [], [], [], [], set()

    def run(self, fn, inputs, cancel=None, shared=None):
        self.in_bytes += [len(pickle.dumps(item)) for item in inputs]
        for i, out in self.inner.run(fn, inputs, cancel, shared):
            if not isinstance(out, BaseException):
                self.task_s.append(out.elapsed_s)
                self.task_cpu_s.append(out.cpu_s)
                self.out_bytes.append(len(pickle.dumps(out)))
                self.workers.add(out.worker)
            yield i, out

    def close(self) -> None:
        pass


def _serial(spec_dict: dict, root: Path) -> dict:
    from sweeps import load_spec, run_sweep

    t0, c0 = time.perf_counter(), time.process_time()
    summary = run_sweep(load_spec(spec_dict), root, workers=0, tracer_threads=1)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    links = summary.results.num_rows
    return {"elapsed_s": elapsed, "cpu_s": cpu, "links": links, "links_per_s": links / elapsed,
            "links_per_cpu_s": links / cpu, "table": summary.results}


def _measure(cluster: Cluster, n: int, sweep: dict, root: Path, table) -> dict:
    """Start ``n`` workers, warm them, run the sweep on them, stop them."""
    from distributed import Client

    from sweeps import load_spec, run_sweep

    t0 = time.perf_counter()
    cluster.add_workers(n)
    try:
        with Client(cluster.address, timeout="60s", set_as_default=False) as client:
            client.wait_for_workers(n, timeout=600)
            connected = time.perf_counter() - t0
            warm_s = client.run(warm)
            started = time.perf_counter() - t0
            engine = Recording(client)
            scheduler = psutil.Process(cluster.scheduler.pid)
            s0, w0 = sum(scheduler.cpu_times()[:2]), client.run(time.process_time)
            t1 = time.perf_counter()
            summary = run_sweep(load_spec(sweep), root, engine=engine)
            elapsed = time.perf_counter() - t1
            s1, w1 = sum(scheduler.cpu_times()[:2]), client.run(time.process_time)
    finally:
        cluster.stop_workers()
    links = summary.results.num_rows
    return {"workers": n, "connect_s": connected, "startup_s": started,
            "warm_s": float(np.median(list(warm_s.values()))), "elapsed_s": elapsed, "links": links,
            "links_per_s": links / elapsed, "links_per_s_per_worker": links / elapsed / n,
            "workers_cpu_s": float(sum(w1[k] - w0[k] for k in w1)), "scheduler_cpu_s": s1 - s0,
            "tasks_cpu_s": float(np.sum(engine.task_cpu_s)),
            "tasks": len(engine.task_s), "task_s_median": float(np.median(engine.task_s)),
            "task_s_sum": float(np.sum(engine.task_s)), "workers_used": len(engine.workers),
            "in_bytes_median": int(np.median(engine.in_bytes)), "out_bytes_median": int(np.median(engine.out_bytes)),
            "same_table_as_serial": bool(summary.results.equals(table)), "load": os.getloadavg()[0]}


def run(quick: bool = False, counts: tuple[int, ...] = (1, 2), netns: bool = False, repeat: int = 2) -> dict:
    """Every measurement of the module doc: the serial reference, then each worker count ``repeat``
    times (the order alternating), its best run kept (the least disturbed by the shared VM)."""
    sweep = spec(0.04 if quick else 0.01)
    out: dict = {"netns": netns, "counts": list(counts), "repeat": repeat, "load_start": os.getloadavg()[0]}
    warm()
    root = Path(tempfile.mkdtemp(prefix="capsule-rt-bench-cluster-"))
    hosts = None
    try:
        reference = _serial(sweep, root / "serial")
        table = reference.pop("table")
        out["serial"] = reference
        if netns:
            hosts = Hosts(max(counts))
            out["links_shaped"] = hosts.shaped
        cluster = Cluster(root, hosts)
        try:
            all_runs = []
            for rep in range(repeat):
                for n in (counts if rep % 2 == 0 else counts[::-1]):
                    all_runs.append(_measure(cluster, n, sweep, root / f"cluster-{n}-{rep}", table))
        finally:
            cluster.close()
    finally:
        if hosts is not None:
            hosts.close()
        shutil.rmtree(root, ignore_errors=True)
    out["all_runs"] = all_runs
    out["runs"] = [max((r for r in all_runs if r["workers"] == n), key=lambda r: r["links_per_s"]) for n in counts]
    one = next((r for r in out["runs"] if r["workers"] == 1), None)
    for r in out["runs"]:
        r["efficiency"] = r["links_per_s"] / (r["workers"] * one["links_per_s"]) if one else None
        # CPU spent per link: the in-process loop's over the workers' and the scheduler's (what the
        # engine costs, whatever else shares the cores)
        r["links_per_worker_cpu_s"] = r["links"] / r["workers_cpu_s"]
        r["cpu_efficiency"] = out["serial"]["cpu_s"] / (r["workers_cpu_s"] + r["scheduler_cpu_s"])
        r["same_table_as_serial"] = all(x["same_table_as_serial"] for x in all_runs if x["workers"] == r["workers"])
    if one:
        out["overhead_1_worker_vs_serial"] = one["elapsed_s"] / out["serial"]["elapsed_s"] - 1.0
    out["load_end"] = os.getloadavg()[0]
    return out


def print_rows(report: dict, row) -> None:
    s = report["serial"]
    where = "own network namespaces" + (", 1 Gbit/s links" if report.get("links_shaped") else "") if report["netns"] \
        else "loopback"
    row(f"sweep across processes ({where}): {s['links']} links, in-process loop (1 thread)",
        f"{s['links_per_s']:.1f} links/s ({s['elapsed_s']:.1f} s), {s['links_per_cpu_s']:.1f} per CPU-s")
    for r in report["runs"]:
        row(f"  {r['workers']} dask worker(s): start-up to warm / links per s (per worker)",
            f"{r['startup_s']:.1f} s / {r['links_per_s']:.1f} ({r['links_per_s_per_worker']:.1f})",
            "same table" if r["same_table_as_serial"] else "TABLE DIFFERS")
        row("    efficiency (wall) / CPU efficiency vs the loop / links per worker CPU-s",
            f"{r['efficiency']:.2f} / {r['cpu_efficiency']:.2f} / {r['links_per_worker_cpu_s']:.1f}")
        row("    task time median / scheduler CPU per task / bytes in, out per task",
            f"{r['task_s_median']:.2f} s / {1e3 * r['scheduler_cpu_s'] / r['tasks']:.1f} ms / "
            f"{r['in_bytes_median']}, {r['out_bytes_median']}")
    if "overhead_1_worker_vs_serial" in report:
        row("  1 worker vs the in-process loop", f"{report['overhead_1_worker_vs_serial']:+.1%}")
    row("  load average at start / end", f"{report['load_start']:.1f} / {report['load_end']:.1f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="18 positions instead of 69")
    ap.add_argument("--netns", action="store_true", help="each worker in its own network namespace (root, iproute2)")
    ap.add_argument("--workers", default="1,2", help="worker counts, comma separated")
    ap.add_argument("--repeat", type=int, default=2, help="runs per worker count (the best is kept)")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "sweeps_cluster.json"))
    args = ap.parse_args(argv)
    report = run(args.quick, tuple(int(k) for k in args.workers.split(",")), args.netns, args.repeat)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(report, fh, indent=2, default=float)
    print_rows(report, lambda name, value, target="": print(f"  {name:<66} {value:>26}  {target}"))


if __name__ == "__main__":
    main()
