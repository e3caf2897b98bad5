"""Sweep throughput and the engines' overhead (``docs/sweeps.md``, "Performance"): reported, never asserted.

    python -m bench.sweeps [--quick]

One sweep (capsule every ``ds`` along the torso's GI tract, every skin sensor, 402 MHz,
GCC TOA) run five ways on this machine: a plain in-process loop (the serial engine: the
reference), the local pool with 1 and 2 worker processes, and a Dask ``LocalCluster``
(started here, ``tcp://127.0.0.1``) with 1 and 2 single-threaded worker processes. The
workers are started and each warmed by a short sweep before the timed one (start-up is a
one-off cost, reported apart). Throughput counts links: positions x receivers per second.
Overhead of an engine = its 1-worker time / the in-process loop's time - 1 (target <= 10 %):
the work per worker is the same, so the difference is shipping tasks and results.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from raytrace.solver.tracer import warm_up
from sweeps import load_spec, run_sweep
from sweeps.engines import DaskEngine, ProcessEngine, SerialEngine


def _spec(ds_m: float, name: str = "bench") -> dict:
    return {"name": name, "capsule_positions": {"along_tract": {"ds_m": ds_m}}, "receivers": "sensors",
            "frequencies_hz": [402e6], "channel": {"rays": 20_000, "max_interactions": 4, "dynamic_range_db": 60},
            "ranging": {"toa": {"methods": ["gcc"], "snr_db": 30}}, "trials": 20, "seed": 1, "chunk_positions": 2}


def _timed(engine, spec: dict, root: Path) -> dict:
    # a few one-position tasks, so that every worker (not just the first) has its phantom, scene
    # and kernels before the timed sweep
    warm = {**spec, "name": "warm", "capsule_positions": {"along_tract": {"ds_m": 0.25}}, "chunk_positions": 1}
    t0 = time.perf_counter()
    run_sweep(load_spec(warm), root / f"{engine.name}-warm".replace(":", "-"), engine=engine)
    warm_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = run_sweep(load_spec(spec), root / engine.name.replace(":", "-").replace("/", "_"), engine=engine)
    elapsed = time.perf_counter() - t0
    links = summary.results.num_rows
    return {"engine": engine.name, "elapsed_s": elapsed, "links": links, "links_per_s": links / elapsed,
            "first_sweep_s": warm_s, "state": summary.state["state"], "table": summary.results}


def run(quick: bool = False) -> dict:
    spec = _spec(0.1 if quick else 0.04)
    out: dict = {"positions": None, "receivers": None}
    warm_up()
    with tempfile.TemporaryDirectory(prefix="capsule-rt-bench-sweeps-") as tmp:
        root = Path(tmp)
        results = [_timed(SerialEngine(), spec, root)]
        for n in (1, 2):
            engine = ProcessEngine(n)
            try:
                results.append(_timed(engine, spec, root))
            finally:
                engine.close()
        from distributed import Client, LocalCluster

        for n in (1, 2):
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                              host="127.0.0.1") as cluster, Client(cluster) as client:
                results.append(_timed(DaskEngine(cluster.scheduler_address, client=client), spec, root))
        reference = results[0]
        for r in results:
            r["same_table_as_in_process"] = bool(r.pop("table").equals(reference["table"])) if r is not reference \
                else True
        reference.pop("table", None)
    first = results[0]
    out["positions"] = first["links"] // 12
    out["receivers"] = 12
    out["runs"] = results
    by = {r["engine"].split(":tcp")[0] if r["engine"].startswith("dask") else r["engine"]: r for r in results}
    dask = [r for r in results if r["engine"].startswith("dask")]
    out["overhead_local_1_worker"] = by["local:1"]["elapsed_s"] / first["elapsed_s"] - 1.0
    out["overhead_dask_1_worker"] = dask[0]["elapsed_s"] / first["elapsed_s"] - 1.0
    out["speedup_local_2_workers"] = first["elapsed_s"] / by["local:2"]["elapsed_s"]
    out["speedup_dask_2_workers"] = first["elapsed_s"] / dask[1]["elapsed_s"]
    return out


def print_rows(report: dict, row) -> None:
    row(f"sweep: {report['positions']} positions x {report['receivers']} sensors, 402 MHz", "links/s (time)")
    for r in report["runs"]:
        row(f"  {r['engine'].replace('127.0.0.1:', '')}", f"{r['links_per_s']:.1f} ({r['elapsed_s']:.1f} s)",
            "same table" if r["same_table_as_in_process"] else "TABLE DIFFERS")
    row("engine overhead vs in-process loop, local pool (1 worker)", f"{report['overhead_local_1_worker']:+.1%}",
        "target <= 10 %")
    row("engine overhead vs in-process loop, Dask (1 worker)", f"{report['overhead_dask_1_worker']:+.1%}",
        "target <= 10 %")
    row("speed-up on 2 workers, local pool / Dask",
        f"{report['speedup_local_2_workers']:.2f} / {report['speedup_dask_2_workers']:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="7 positions instead of 18")
    args = ap.parse_args()
    report = run(args.quick)
    print_rows(report, lambda name, value, target="": print(f"  {name:<60} {value:>18}  {target}"))
    print(json.dumps({k: v for k, v in report.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
