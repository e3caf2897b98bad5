"""PDOA ranging (estimators.pdoa): exactness, efficiency against the bound, multipath, wrapping, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import EstimatorInputError, PathProfile, estimate_pdoa, single_path

C = 299_792_458.0
V = C / math.sqrt(27.9)
D_TRUE = 0.076
TAU = D_TRUE / V
BAND_402 = {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}
BAND_2450 = {"start_hz": 2440e6, "stop_hz": 2460e6, "points": 21}


@pytest.mark.parametrize("method, kw", [
    ("two_tone", {"frequencies_hz": [400e6, 420e6]}),
    ("two_tone", {"band": BAND_402}),
    ("regression", {"band": BAND_402}),
    ("regression", {"band": BAND_2450}),
])
def test_noiseless_single_path_is_exact(method, kw):
    r = estimate_pdoa(single_path(TAU, 0.3 * np.exp(2.0j)), method=method, snr_db=None, trials=1,
                      true_distance_m=D_TRUE, **kw)
    assert abs(r.error_m) < 1e-5  # acceptance: 0.01 mm (numerically ~1e-16)
    assert not r.wrapped


def test_max_unambiguous_range():
    r2 = estimate_pdoa(single_path(TAU), frequencies_hz=[400e6, 420e6], snr_db=None, trials=1)
    assert r2.max_unambiguous_range_m == pytest.approx(V / 20e6, rel=1e-12)
    assert r2.max_unambiguous_range_m == pytest.approx(2.84, abs=0.005)  # thesis Sec 5.2.2
    rr = estimate_pdoa(single_path(TAU), band=BAND_402, method="regression", snr_db=None, trials=1)
    assert rr.max_unambiguous_range_m == pytest.approx(V / 1e6, rel=1e-12)


def test_two_tone_spread_reaches_the_phase_difference_bound():
    r = estimate_pdoa(single_path(TAU), frequencies_hz=[400e6, 420e6], snr_db=30.0, trials=1000, seed=7,
                      true_distance_m=D_TRUE)
    v_over = V / (2 * math.pi * 20e6)
    # Bound written out: phase difference variance 2 / (E/N0), E/N0 = SNR W T0 = 1000.
    expected_pd = v_over * math.sqrt(2 / 1000)
    assert r.crlb_phase_difference_m == pytest.approx(expected_pd, rel=1e-9)
    # Acceptance: within 2x at high SNR. It is efficient, so also no more than ~10 % below
    # (1000 trials: the sample std is good to ~7 % at 3 sigma).
    assert 0.9 * expected_pd < r.std_m < 2 * expected_pd
    assert abs(r.error_m) < 4 * r.std_m / math.sqrt(1000)
    assert r.crlb_m < r.crlb_phase_difference_m  # the carrier-resolved bound is far tighter
    assert not r.wrapped


def test_regression_spread_reaches_the_multitone_bound():
    r = estimate_pdoa(single_path(TAU), band=BAND_402, method="regression", snr_db=30.0, trials=1000, seed=8,
                      true_distance_m=D_TRUE)
    assert 0.9 * r.crlb_phase_difference_m < r.std_m < 2 * r.crlb_phase_difference_m
    assert abs(r.error_m) < 4 * r.std_m / math.sqrt(1000)
    # Spread is circular: a 7.6 cm distance is near the 0 edge of a 57 m interval, yet no wrap.
    assert not r.wrapped


def _three_path_profile():
    return PathProfile([TAU, TAU + 300e-12, TAU + 650e-12], [1.0, 0.5, 0.3])


@pytest.mark.parametrize("band", [BAND_402, BAND_2450])
def test_three_path_multitone_errs_by_millimetres(band):
    # Thesis Table 5.2: 5 mm (400-420 MHz) and 11.4 mm (2440-2460 MHz). Order of magnitude only.
    p3 = _three_path_profile()
    clean = estimate_pdoa(p3, band=band, method="regression", snr_db=None, trials=1, true_distance_m=D_TRUE)
    assert 1e-3 < abs(clean.error_m) < 2e-2
    # The bias is the channel's group delay at the band centre (independent oracle: finite difference
    # of the unwrapped phase of the summed phasors).
    f0 = 0.5 * (band["start_hz"] + band["stop_hz"])
    h = [sum(a * np.exp(-2j * math.pi * f * t) for a, t in zip([1.0, 0.5, 0.3], [TAU, TAU + 300e-12, TAU + 650e-12]))
         for f in (f0 - 1e3, f0 + 1e3)]
    group_delay = -np.angle(h[1] / h[0]) / (2 * math.pi * 2e3)
    assert clean.distance_m == pytest.approx(V * group_delay, abs=1.5e-3)
    noisy = estimate_pdoa(p3, band=band, method="regression", snr_db=30.0, trials=500, seed=1,
                          true_distance_m=D_TRUE)
    assert 1e-3 < noisy.rmse_m < 5e-2


def test_beyond_the_unambiguous_range_wraps_and_says_so():
    d = 3.0  # beyond 2.84 m
    r = estimate_pdoa(single_path(d / V), frequencies_hz=[400e6, 420e6], snr_db=None, trials=1,
                      true_distance_m=d)
    assert r.wrapped
    assert "unambiguous" in r.wrap_reason
    assert r.distance_m == pytest.approx(d - V / 20e6, abs=1e-9)  # aliased modulo the range
    assert r.error_m == pytest.approx(-V / 20e6, abs=1e-9)


def test_at_the_edge_of_the_range_without_truth_it_still_flags_wrapping():
    rng_m = V / 20e6
    # 1.5 cm inside the far edge with a 2 cm spread: genuinely ambiguous. The circular mean is read as
    # a short distance (-1.5 cm), flagged; it equals the true one modulo the range.
    d = rng_m - 0.015
    r = estimate_pdoa(single_path(d / V), frequencies_hz=[400e6, 420e6], snr_db=30.0, trials=400, seed=2)
    assert r.wrapped and "below zero" in r.wrap_reason
    assert r.distance_m == pytest.approx(d - rng_m, abs=0.01)
    assert r.std_m < 0.03  # circular statistics: no fake metre of spread
    # 0.3 m inside the edge (15 spreads): an ordinary, unflagged estimate.
    d = rng_m - 0.3
    r = estimate_pdoa(single_path(d / V), frequencies_hz=[400e6, 420e6], snr_db=30.0, trials=400, seed=2,
                      true_distance_m=d)
    assert not r.wrapped
    assert abs(r.error_m) < 0.005
    # Heavy noise (6 dB: ~0.3 m spread) 1 m from the edge: the mean stays put (over 3 spreads away)
    # but some of the 10000 trials spill past the edge, and the result says so.
    d = rng_m - 1.0
    r = estimate_pdoa(single_path(d / V), frequencies_hz=[400e6, 420e6], snr_db=6.0, trials=10_000, seed=2)
    assert r.distance_m == pytest.approx(d, abs=0.05)
    assert r.wrapped and "far edge" in r.wrap_reason


def test_short_distance_through_heavy_noise_is_not_reported_at_the_far_edge():
    # 1 mm true distance, std ~ 0.1 m: raw trials land near 0 and near 2.84 m; the result must
    # stay near zero whatever the number of trials (not jump to the far edge).
    for trials in (7, 50, 1000):
        r = estimate_pdoa(single_path(0.001 / V), frequencies_hz=[400e6, 420e6], snr_db=15.0, trials=trials,
                          seed=1)
        assert abs(r.distance_m) < 0.3


def test_same_seed_same_result():
    kw = dict(band=BAND_402, method="regression", snr_db=20.0, trials=100, return_estimates=True)
    a = estimate_pdoa(single_path(TAU), seed=5, **kw)
    b = estimate_pdoa(single_path(TAU), seed=5, **kw)
    c = estimate_pdoa(single_path(TAU), seed=6, **kw)
    np.testing.assert_array_equal(a.estimates_m, b.estimates_m)
    assert not np.array_equal(a.estimates_m, c.estimates_m)
    assert a.estimates_m.shape == (100,)


def test_band_gains_are_used():
    # Per-frequency gains whose phase grows linearly with f act as an extra delay of 100 ps.
    fb = np.linspace(400e6, 420e6, 21)
    extra = 100e-12
    p = PathProfile([TAU], [1.0], band_frequencies_hz=fb, band_gains=np.exp(-2j * math.pi * fb * extra)[None, :])
    r = estimate_pdoa(p, band=BAND_402, method="regression", snr_db=None, trials=1)
    assert r.delay_s == pytest.approx(TAU + extra, abs=1e-15)


@pytest.mark.parametrize("kw, field", [
    (dict(frequencies_hz=[420e6, 400e6]), "frequencies_hz"),
    (dict(frequencies_hz=[400e6, 400e6]), "frequencies_hz"),
    (dict(frequencies_hz=[400e6, 410e6, 420e6]), "frequencies_hz"),
    (dict(frequencies_hz=[400e6, float("nan")]), "frequencies_hz"),
    (dict(frequencies_hz=[400e6, 420e6], band=BAND_402), "frequencies_hz"),
    (dict(), "frequencies_hz"),
    (dict(band={"start_hz": 420e6, "stop_hz": 400e6, "points": 21}), "band.stop_hz"),
    (dict(band={"start_hz": 400e6, "stop_hz": 420e6, "points": 1}), "band.points"),
    (dict(band={"start_hz": 400e6, "stop_hz": 420e6}), "band"),
    (dict(band=BAND_402, method="fft"), "method"),
    (dict(frequencies_hz=[400e6, 405e6, 420e6], method="regression"), "frequencies_hz"),
    (dict(frequencies_hz=[400e6, 420e6], trials=0), "trials"),
    (dict(frequencies_hz=[400e6, 420e6], trials=10_001), "trials"),
    (dict(frequencies_hz=[400e6, 420e6], duration_s=0.0), "duration_s"),
    (dict(frequencies_hz=[400e6, 420e6], snr_db=float("inf")), "snr_db"),
])
def test_invalid_requests_raise_naming_the_field(kw, field):
    with pytest.raises(EstimatorInputError) as exc:
        estimate_pdoa(single_path(TAU), **kw)
    assert exc.value.field == field
    assert exc.value.reason


def test_chunked_trials_give_the_same_stream_as_one_batch():
    # 10000 trials x 201 tones is processed in chunks; trial i's noise must not depend on the chunking.
    kw = dict(band={"start_hz": 400e6, "stop_hz": 420e6, "points": 201}, method="regression", snr_db=20.0,
              seed=3, return_estimates=True)
    big = estimate_pdoa(single_path(TAU), trials=10_000, **kw)
    small = estimate_pdoa(single_path(TAU), trials=7, **kw)
    np.testing.assert_allclose(big.estimates_m[:7], small.estimates_m, rtol=0, atol=1e-12)
    assert np.all(np.isfinite(big.estimates_m))
