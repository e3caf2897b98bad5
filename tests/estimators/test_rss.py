"""RSS ranging by CM2 path-loss inversion (estimators.rss)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import CM2_MODELS, EstimatorInputError, PathProfile, estimate_rss, rss_crlb

# IEEE 802.15.6 CM2 (thesis Table 2.2), written out independently of the implementation.
DEEP = (47.14, 4.26, 7.85)
SURFACE = (49.81, 4.22, 6.81)


def _pl(d, model):
    pl0, n, _ = model
    return pl0 + 10 * n * math.log10(d / 0.05)


def test_model_constants():
    m = CM2_MODELS["cm2_deep_tissue"]
    assert (m.path_loss_d0_db, m.exponent, m.shadowing_db, m.reference_distance_m) == (*DEEP, 0.05)
    m = CM2_MODELS["cm2_near_surface"]
    assert (m.path_loss_d0_db, m.exponent, m.shadowing_db, m.reference_distance_m) == (*SURFACE, 0.05)


@pytest.mark.parametrize("model, params", [("cm2_deep_tissue", DEEP), ("cm2_near_surface", SURFACE)])
@pytest.mark.parametrize("d", [0.03, 0.076, 0.15])
def test_deterministic_inversion_from_rss_and_from_profile(model, params, d):
    pl = _pl(d, params)
    r = estimate_rss(rss_dbm=10.0 - pl, transmit_power_dbm=10.0, model=model, trials=1, shadowing=False,
                     true_distance_m=d)
    assert r.distance_m == pytest.approx(d, rel=1e-12)
    assert r.path_loss_db == pytest.approx(pl, rel=1e-12)
    # A profile whose incoherent path power is 10^(-PL/10), split over two paths.
    amp = math.sqrt(10 ** (-pl / 10) / 2)
    p = PathProfile([1e-9, 2e-9], [amp, 1j * amp])
    rp = estimate_rss(p, model=model, trials=1, shadowing=False)
    assert rp.distance_m == pytest.approx(d, rel=1e-9)
    assert r.crlb_m == pytest.approx(math.log(10) * params[2] * d / (10 * params[1]), rel=1e-12)


def test_shadowing_statistics():
    d = 0.08
    r = estimate_rss(rss_dbm=-_pl(d, DEEP), transmit_power_dbm=0.0, trials=5000, seed=9, true_distance_m=d,
                     return_estimates=True)
    logd = np.log10(r.estimates_m)
    # log10 d_hat = log10 d + S / (10 n): mean and spread of a Gaussian, 5000 samples
    # (std error of the std ~1 %, of the mean ~0.0026 in log10 units; 4-sigma margins).
    assert np.std(logd, ddof=1) == pytest.approx(7.85 / 42.6, rel=0.04)
    assert np.mean(logd) == pytest.approx(math.log10(d), abs=4 * 7.85 / 42.6 / math.sqrt(5000))
    assert r.median_distance_m == pytest.approx(d, rel=1e-12)
    # Log-normal: the mean is above the median by exp(s^2 / 2), s = ln10 sigma / (10 n).
    s = math.log(10) * 7.85 / 42.6
    assert r.distance_m == pytest.approx(d * math.exp(s * s / 2), rel=0.05)
    assert r.crlb_m == pytest.approx(rss_crlb(7.85, 4.26, d).sigma_m)


def test_same_seed_same_result():
    kw = dict(rss_dbm=-60.0, transmit_power_dbm=0.0, trials=50, return_estimates=True)
    a, b, c = estimate_rss(seed=1, **kw), estimate_rss(seed=1, **kw), estimate_rss(seed=2, **kw)
    np.testing.assert_array_equal(a.estimates_m, b.estimates_m)
    assert not np.array_equal(a.estimates_m, c.estimates_m)


@pytest.mark.parametrize("kw, field", [
    (dict(rss_dbm=-60.0, transmit_power_dbm=0.0, model="free_space"), "model"),
    (dict(rss_dbm=-60.0), "transmit_power_dbm"),
    (dict(), "profile"),
    (dict(rss_dbm=float("nan"), transmit_power_dbm=0.0), "rss_dbm"),
    (dict(rss_dbm=-60.0, transmit_power_dbm=0.0, trials=0), "trials"),
    (dict(rss_dbm=-60.0, transmit_power_dbm=0.0, true_distance_m=0.0), "true_distance_m"),
])
def test_invalid_requests_raise_naming_the_field(kw, field):
    with pytest.raises(EstimatorInputError) as exc:
        estimate_rss(**kw)
    assert exc.value.field == field
