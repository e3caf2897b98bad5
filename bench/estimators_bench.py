"""Monte Carlo throughput of the estimators (trials per second).

Each estimator runs once untimed (first-call costs: FFT plans, caches), then
``repeats`` timed runs of ``trials`` trials; the median is reported (single
runs on a shared 2-core VM scatter by 2-3x).
"""

from __future__ import annotations

import statistics
import time

from estimators.pdoa import estimate_pdoa
from estimators.profile import single_path
from estimators.toa import estimate_toa


def _rate(run, trials: int, repeats: int) -> float:
    run()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return trials / statistics.median(times)


def throughput(trials: int = 1000, repeats: int = 5) -> dict:
    profile = single_path(1.338e-9)
    out = {}
    for method in ("first_peak", "all_peaks", "gcc"):
        out[f"toa_{method}_trials_per_s"] = _rate(
            lambda: estimate_toa(profile, method=method, snr_db=30.0, trials=trials, seed=1), trials, repeats)
    for method, kw in (("two_tone", {"frequencies_hz": [400e6, 420e6]}),
                       ("regression", {"band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}})):
        out[f"pdoa_{method}_trials_per_s"] = _rate(
            lambda: estimate_pdoa(profile, method=method, snr_db=30.0, trials=trials, seed=1, **kw), trials, repeats)
    return out
