"""Monte Carlo throughput of the estimators (trials per second).

Each estimator runs once untimed (first-call costs: FFT plans, caches), then
``repeats`` timed runs of ``trials`` trials; the median is reported (single
runs on a shared 2-core VM scatter by 2-3x).

TOA through the channel (docs/science.md 4.4): the README's torso path profile
(capsule small_intestine_1 to belt_anterior, every path, band 400-420 MHz in 21
points) with each of its three channel models: ``band_gains`` (the waveform
through the band gains' H(f), by FFT), ``group_delay`` (first-order, exact in the
time domain) and ``non_dispersive`` (delays and gains only: what every TOA
figure measured before), beside today's single-path figure. The tracer's band
mode is timed too: the same trace with 21 and with 401 band frequencies.
"""

from __future__ import annotations

import statistics
import time

from estimators.pdoa import estimate_pdoa
from estimators.profile import PathProfile, single_path
from estimators.toa import estimate_toa


def _rate(run, trials: int, repeats: int) -> float:
    run()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return trials / statistics.median(times)


def _seconds(run, repeats: int) -> float:
    run()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _torso(points: int):
    import raytrace as rt

    spec = rt.ChannelSpec(rt.Antenna(site="small_intestine_1"), [rt.Antenna(site="belt_anterior")],
                          phantom="torso", frequency_hz=402e6, band=rt.Band(400e6, 420e6, points))
    return spec, rt.trace_channel


def _torso_profiles() -> dict[str, PathProfile]:
    spec, trace = _torso(21)
    result = trace(spec)
    paths = result.profiles[0].paths
    common = dict(delays_s=[p.delay_s for p in paths], gains=[p.gain for p in paths],
                  gains_include_delay_phase=True, reference_frequency_hz=result.frequency_hz)
    return {
        "band_gains": PathProfile(**common, band_frequencies_hz=result.band_frequencies_hz,
                                  band_gains=[p.band_gains for p in paths],
                                  group_delays_s=[p.group_delay_s for p in paths]),
        "group_delay": PathProfile(**common, group_delays_s=[p.group_delay_s for p in paths]),
        "non_dispersive": PathProfile(**common),
    }


def throughput(trials: int = 1000, repeats: int = 5) -> dict:
    profile = single_path(1.338e-9)
    out = {}
    for method in ("first_peak", "all_peaks", "gcc"):
        out[f"toa_{method}_trials_per_s"] = _rate(
            lambda: estimate_toa(profile, method=method, snr_db=30.0, trials=trials, seed=1), trials, repeats)
    torso = _torso_profiles()
    out["torso_profile_paths"] = float(torso["band_gains"].delays_s.size)
    for model, p in torso.items():
        out[f"toa_gcc_torso_{model}_trials_per_s"] = _rate(
            lambda: estimate_toa(p, method="gcc", snr_db=30.0, trials=trials, seed=1), trials, repeats)
    for method, kw in (("two_tone", {"frequencies_hz": [400e6, 420e6]}),
                       ("regression", {"band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}})):
        out[f"pdoa_{method}_trials_per_s"] = _rate(
            lambda: estimate_pdoa(profile, method=method, snr_db=30.0, trials=trials, seed=1, **kw), trials, repeats)
    for points in (21, 401):
        spec, trace = _torso(points)
        out[f"torso_trace_one_receiver_band_{points}_points_s"] = _seconds(lambda: trace(spec), 3)
    return out
