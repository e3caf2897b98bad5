"""Monte Carlo throughput of the estimators (trials per second)."""

from __future__ import annotations

import time

from estimators.pdoa import estimate_pdoa
from estimators.profile import single_path
from estimators.toa import estimate_toa


def throughput(trials: int = 1000) -> dict:
    profile = single_path(1.338e-9)
    out = {}
    for method in ("first_peak", "all_peaks", "gcc"):
        t0 = time.perf_counter()
        estimate_toa(profile, method=method, snr_db=30.0, trials=trials, seed=1)
        out[f"toa_{method}_trials_per_s"] = trials / (time.perf_counter() - t0)
    for method, kw in (("two_tone", {"frequencies_hz": [400e6, 420e6]}),
                       ("regression", {"band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}})):
        t0 = time.perf_counter()
        estimate_pdoa(profile, method=method, snr_db=30.0, trials=trials, seed=1, **kw)
        out[f"pdoa_{method}_trials_per_s"] = trials / (time.perf_counter() - t0)
    return out
