"""Small shared helpers: timing, percentiles, growth exponents, sub-process points."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from typing import Callable

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def timed(fn: Callable[[], object], repeat: int) -> np.ndarray:
    """Wall times [s] of ``repeat`` calls of ``fn``."""
    out = np.empty(repeat)
    for i in range(repeat):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out


def percentiles(samples_s: np.ndarray) -> dict:
    return {
        "p50_s": float(np.percentile(samples_s, 50)),
        "p95_s": float(np.percentile(samples_s, 95)),
        "n": int(len(samples_s)),
    }


def growth_exponent(x, y) -> float:
    """Least-squares slope of log y against log x: y ~ x^k."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


def run_point(args: list[str], timeout_s: float = 600.0) -> dict:
    """Run ``python -m bench.point ARGS`` in a fresh interpreter (honest peak memory)."""
    proc = subprocess.run(
        [sys.executable, "-m", "bench.point", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"bench.point {args} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])
