"""The estimators' stop protocol and work measure (issue 25): a ``check`` callable reaches every
long loop and its exception stops the computation; ``toa_samples`` is the unit the service bounds
a TOA request by; the TOA bound stays exact for observations far shorter than a carrier period."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from estimators import (
    PathProfile,
    estimate_pdoa,
    estimate_rss,
    estimate_toa,
    toa_crlb,
    toa_samples,
)
from estimators.bounds import tone_energy_integrals


class Stop(Exception):
    pass


def stop_after(n: int):
    calls = {"n": 0}

    def check():
        calls["n"] += 1
        if calls["n"] > n:
            raise Stop

    return check, calls


def test_the_check_reaches_the_synthesis_and_the_trial_loops():
    late = PathProfile(np.linspace(1e-9, 12e-6, 40), np.full(40, 1e-3))  # many path chunks, long trials
    check, calls = stop_after(10**9)
    estimate_toa(late, method="gcc", trials=12, seed=1, check=check)
    n = toa_samples(late)
    # chunks of 2^21 elements: paths x samples for the synthesis, trials x FFT length for the trials
    assert calls["n"] >= math.ceil(40 / max(1, (1 << 21) // n)) + 2
    for k in (0, 3, calls["n"] - 1):  # a check raising at any call stops it with that exception
        check, _ = stop_after(k)
        with pytest.raises(Stop):
            estimate_toa(late, method="gcc", trials=12, seed=1, check=check)
    one = PathProfile([1e-9], [1e-3])
    with pytest.raises(Stop):
        estimate_pdoa(one, band={"start_hz": 400e6, "stop_hz": 420e6, "points": 21}, trials=10, seed=1,
                      check=stop_after(0)[0])
    with pytest.raises(Stop):
        estimate_rss(one, trials=10, seed=1, check=stop_after(0)[0])


def test_toa_samples_is_the_observation_window():
    # the window runs from t = 0 to the last path plus 1.5 bursts and 4 carrier periods (waveforms.py)
    profile = PathProfile([1e-9, 5e-9], [1e-3, 1e-4])
    expected = math.ceil((5e-9 + 1.5 * 25e-9 + 4 / 402e6) * 20e9) + 1
    assert toa_samples(profile) == expected
    assert toa_samples(profile, {"kind": "tone_burst", "sample_rate_hz": 10e9}) == \
        math.ceil((5e-9 + 1.5 * 25e-9 + 4 / 402e6) * 10e9) + 1


@pytest.mark.parametrize("carrier_hz, duration_s, delay_s", [
    (1.0, 1e-15, 0.0), (402e6, 1e-15, 0.0), (402e6, 1e-15, 3e-16), (1e12, 1e-15, 0.0), (402e6, 25e-9, 1e-9),
])
def test_tone_integrals_match_quadrature_even_for_tiny_observations(carrier_hz, duration_s, delay_s):
    """Oracle: adaptive quadrature of Eq 4.11-4.12's integrands, sin^2 and cos^2 (relative error
    of quad ~1e-14 on these smooth integrands; the closed form must agree to 1e-9)."""
    w = 2 * math.pi * carrier_hz
    i_s, i_tau = tone_energy_integrals(carrier_hz, duration_s, delay_s)
    points = np.linspace(0.0, duration_s, 64)[1:-1] if w * duration_s > 10 else None
    ref_tau = w * w * quad(lambda t: math.sin(w * (t - delay_s)) ** 2, 0.0, duration_s, epsrel=1e-13, epsabs=0.0,
                           limit=500, points=points)[0]
    ref_s = quad(lambda t: math.cos(w * (t - delay_s)) ** 2, 0.0, duration_s, epsrel=1e-13, epsabs=0.0,
                 limit=500, points=points)[0]
    assert i_tau == pytest.approx(ref_tau, rel=1e-9)
    assert i_s == pytest.approx(ref_s, rel=1e-9)
    bound = toa_crlb(carrier_hz, duration_s, 1.0, -50.0, delay_s=delay_s)
    assert math.isfinite(bound.sigma_s) and bound.sigma_s > 0
