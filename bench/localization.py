"""Localization speed (reported, never asserted): one nonlinear fix, one model-based fix
once the travel-time grids exist, building the 12 sensors' grids at the default cell size,
and the peak memory of the grids.

    python -m bench.localization
"""

from __future__ import annotations

import json
import statistics
import time
import tracemalloc

import numpy as np

from estimators.localization import model_based_fix, nonlinear_fix
from estimators.localization.traveltime import clear_cache
from evaluation.fields import DEFAULT_CELL_SIZE_M, sensor_fields, voxel_grid
from raytrace.body.torso import BELT_SITES, UPPER_SITES, default_torso


def _median_s(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def localization(repeat: int = 20, cell_size_m: float = DEFAULT_CELL_SIZE_M) -> dict:
    phantom = default_torso()
    sensors = np.array([phantom.sites[s].position_m for s in (*BELT_SITES, *UPPER_SITES)])
    x = phantom.sites["transverse_colon"].position_m
    t0 = time.perf_counter()
    voxel_grid(phantom, cell_size_m)
    voxelize_s = time.perf_counter() - t0
    clear_cache()
    tracemalloc.start()
    t0 = time.perf_counter()
    fields = sensor_fields(phantom, sensors, 402e6, cell_size_m)
    grids_s = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rng = np.random.default_rng(0)
    r = np.linalg.norm(sensors - x, axis=1) + 1e-4 * rng.standard_normal(len(sensors))
    t_true, _ = fields.evaluate(x)
    tau = t_true + 5e-12 * rng.standard_normal(len(sensors))
    return {
        "cell_size_m": cell_size_m, "cells": int(np.prod(fields.shape)), "sensors": len(sensors),
        "voxelize_s": voxelize_s, "grids_12_sensors_s": grids_s, "grids_peak_memory_mb": peak / 2**20,
        "grids_resident_mb": fields.time_s.nbytes / 2**20,
        "nonlinear_fix_s": _median_s(lambda: nonlinear_fix(sensors, r, 1e-4), repeat),
        "model_based_fix_s": _median_s(lambda: model_based_fix(fields, tau, 5e-12), repeat),
    }


def print_rows(out: dict, row) -> None:
    row("localization: one nonlinear fix [ms]", f"{out['nonlinear_fix_s'] * 1e3:.2f}", "target < 10")
    row("localization: one model-based fix, grids built [ms]", f"{out['model_based_fix_s'] * 1e3:.1f}", "target < 50")
    row(f"localization: 12 sensors' grids, {out['cell_size_m'] * 1e3:g} mm cells [s]",
        f"{out['grids_12_sensors_s']:.2f}", "target < 5")
    row("localization: voxelizing the torso (once per cell size) [s]", f"{out['voxelize_s']:.2f}")
    row("localization: grids' peak traced memory / resident [MB]",
        f"{out['grids_peak_memory_mb']:.0f} / {out['grids_resident_mb']:.0f}")


if __name__ == "__main__":
    result = localization()
    print(json.dumps(result, indent=2))
