"""Localization speed (reported, never asserted): one nonlinear fix, one model-based fix
once the travel-time grids exist, building the 12 sensors' grids at the default cell size,
the peak memory of the grids, and the first model-based fix of a fresh process -- what a
freshly started server does on its first POST /v1/localize -- cold (empty disk cache; the
fields solved in parallel, and one after another as before), after a restart (the fields on
disk) and warm (in memory), wall and CPU time (docs/localization.md, "Speed").

    python -m bench.localization [--repeat 20] [--first-fix-rounds 3]

The first-fix rounds run each case in its own interpreter, interleaved (cold parallel, cold
serial, restarted; then again), so that the machine's load drifts over all of them alike; each
process builds the torso before its clock starts (a server does it before it is ready). CPU time
is the process's and its children's (the field solvers), from getrusage.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc

import numpy as np

from estimators.localization import model_based_fix, nonlinear_fix
from estimators.localization.traveltime import clear_cache
from evaluation.fields import DEFAULT_CELL_SIZE_M, sensor_fields, voxel_grid
from raytrace.body.torso import BELT_SITES, UPPER_SITES, default_torso

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _median_s(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _torso_case():
    phantom = default_torso()
    sensors = np.array([phantom.sites[s].position_m for s in (*BELT_SITES, *UPPER_SITES)])
    x = phantom.sites["transverse_colon"].position_m
    return phantom, sensors, x


def localization(repeat: int = 20, cell_size_m: float = DEFAULT_CELL_SIZE_M, first_fix_rounds: int = 2) -> dict:
    phantom, sensors, x = _torso_case()
    t0 = time.perf_counter()
    voxel_grid(phantom, cell_size_m)
    voxelize_s = time.perf_counter() - t0
    clear_cache()
    tracemalloc.start()
    t0 = time.perf_counter()
    fields = sensor_fields(phantom, sensors, 402e6, cell_size_m, "phase", workers=1)
    grids_s = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rng = np.random.default_rng(0)
    r = np.linalg.norm(sensors - x, axis=1) + 1e-4 * rng.standard_normal(len(sensors))
    t_true, _ = fields.evaluate(x)
    tau = t_true + 5e-12 * rng.standard_normal(len(sensors))
    out = {
        "cell_size_m": cell_size_m, "cells": int(np.prod(fields.shape)), "sensors": len(sensors),
        "voxelize_s": voxelize_s, "grids_12_sensors_s": grids_s, "grids_peak_memory_mb": peak / 2**20,
        "grids_resident_mb": fields.time_s.nbytes / 2**20,
        "nonlinear_fix_s": _median_s(lambda: nonlinear_fix(sensors, r, 1e-4), repeat),
        "model_based_fix_s": _median_s(lambda: model_based_fix(fields, tau, 5e-12), repeat),
    }
    if first_fix_rounds:
        out["first_fix"] = first_fixes(first_fix_rounds, cell_size_m)
    return out


# ------------------------------------------------------------------ the first fix of a fresh process
def _cpu_s() -> float:
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def first_fix(cache_dir: str, workers: int | None, cell_size_m: float = DEFAULT_CELL_SIZE_M) -> dict:
    """In this (fresh) process: the torso built, then one model-based fix with the 12 sensors'
    fields through ``cache_dir``, then a second (warm) fix; wall and CPU time of each."""
    phantom, sensors, x = _torso_case()
    delays = None
    out = {}
    for name in ("first", "warm"):
        w0, c0 = time.perf_counter(), _cpu_s()
        fields = sensor_fields(phantom, sensors, 402e6, cell_size_m, "group", cache_dir=cache_dir, workers=workers)
        if delays is None:
            delays = fields.evaluate(x)[0]  # the exact times: the fix's own cost, not its error
        fix = model_based_fix(fields, delays)
        out[f"{name}_wall_s"] = time.perf_counter() - w0
        out[f"{name}_cpu_s"] = _cpu_s() - c0
        out[f"{name}_error_m"] = float(np.linalg.norm(fix.position_m - x))
    return out


def _child(cache_dir: str, workers: int | None, cell_size_m: float) -> dict:
    cmd = [sys.executable, "-m", "bench.localization", "--child", cache_dir, "--cell-size-m", str(cell_size_m)]
    if workers is not None:
        cmd += ["--workers", str(workers)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [ROOT, os.environ.get("PYTHONPATH")]))}
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def first_fixes(rounds: int = 2, cell_size_m: float = DEFAULT_CELL_SIZE_M) -> dict:
    """Interleaved rounds of: cold + parallel (empty disk cache), cold + serial (empty disk
    cache, one process: the code before the parallel build), restarted (the disk cache the
    first case left). Medians over the rounds of each measure."""
    runs: dict[str, list[dict]] = {"cold_parallel": [], "cold_serial": [], "restarted": []}
    for _ in range(rounds):
        with tempfile.TemporaryDirectory() as tmp:
            runs["cold_parallel"].append(_child(tmp, None, cell_size_m))
            runs["restarted"].append(_child(tmp, None, cell_size_m))
        with tempfile.TemporaryDirectory() as tmp:
            runs["cold_serial"].append(_child(tmp, 1, cell_size_m))
    out: dict = {"rounds": rounds, "load_average": os.getloadavg()[0], "cpus": len(os.sched_getaffinity(0))}
    for case, rows in runs.items():
        for key in rows[0]:
            out[f"{case}_{key}"] = statistics.median(r[key] for r in rows)
    return out


def print_rows(out: dict, row) -> None:
    row("localization: one nonlinear fix [ms]", f"{out['nonlinear_fix_s'] * 1e3:.2f}", "target < 10")
    row("localization: one model-based fix, grids built [ms]", f"{out['model_based_fix_s'] * 1e3:.1f}", "target < 50")
    row(f"localization: 12 sensors' grids, {out['cell_size_m'] * 1e3:g} mm cells, one process [s]",
        f"{out['grids_12_sensors_s']:.2f}", "target < 5")
    row("localization: voxelizing the torso (once per cell size) [s]", f"{out['voxelize_s']:.2f}")
    row("localization: grids' peak traced memory / resident [MB]",
        f"{out['grids_peak_memory_mb']:.0f} / {out['grids_resident_mb']:.0f}")
    ff = out.get("first_fix")
    if ff:
        for case, label in (("cold_parallel", "fresh process, empty disk cache, parallel"),
                            ("cold_serial", "fresh process, empty disk cache, one process"),
                            ("restarted", "restarted process, fields on disk")):
            row(f"localization: first model-based fix, 12 sensors, {label}: wall / CPU [s]",
                f"{ff[f'{case}_first_wall_s']:.2f} / {ff[f'{case}_first_cpu_s']:.2f}", "a few s")
        row("localization: the next (warm) fix: wall / CPU [s]",
            f"{ff['cold_parallel_warm_wall_s']:.3f} / {ff['cold_parallel_warm_cpu_s']:.3f}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--first-fix-rounds", type=int, default=3)
    ap.add_argument("--cell-size-m", type=float, default=DEFAULT_CELL_SIZE_M)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--workers", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        print(json.dumps(first_fix(args.child, args.workers, args.cell_size_m)))
        return
    result = localization(args.repeat, args.cell_size_m, args.first_fix_rounds)
    print(json.dumps(result, indent=2))
    print_rows(result, lambda name, value, target="": print(f"| {name} | {value} | {target} |"))


if __name__ == "__main__":
    main()
