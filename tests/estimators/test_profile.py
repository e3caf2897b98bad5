"""PathProfile validation and frequency response (estimators.profile)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import EstimatorInputError, PathProfile


def test_frequency_response_is_the_sum_of_delayed_paths():
    tau = np.array([1.338e-9, 1.7e-9, 2.2e-9])
    a = np.array([1.0, -0.5j, 0.3 + 0.1j])
    f = np.linspace(400e6, 420e6, 21)
    p = PathProfile(tau, a)
    # Written out independently, one path at a time.
    expected = sum(a[k] * np.exp(-2j * math.pi * f * tau[k]) for k in range(3))
    np.testing.assert_allclose(p.frequency_response(f), expected, rtol=1e-12)


def test_band_gains_interpolated_and_equivalent_to_constant_gains():
    tau = np.array([1.338e-9, 1.7e-9])
    a = np.array([1.0, 0.4 - 0.2j])
    fb = np.array([390e6, 410e6, 430e6])
    p_const = PathProfile(tau, a)
    p_band = PathProfile(tau, a, band_frequencies_hz=fb, band_gains=np.repeat(a[:, None], 3, axis=1))
    f = np.array([395e6, 400e6, 410e6, 427.5e6])
    np.testing.assert_allclose(p_band.frequency_response(f), p_const.frequency_response(f), rtol=1e-12)
    # A linearly varying band gain is reproduced exactly between the band points.
    slope = np.array([[1.0, 1.5, 2.0], [0.0, 0.0, 0.0]], dtype=complex)
    p_lin = PathProfile(tau, a, band_frequencies_hz=fb, band_gains=slope)
    h = p_lin.frequency_response(np.array([400e6]))
    assert h[0] == pytest.approx(1.25 * np.exp(-2j * math.pi * 400e6 * tau[0]), rel=1e-12)
    with pytest.raises(EstimatorInputError) as exc:
        p_band.frequency_response([450e6])
    assert exc.value.field == "frequencies_hz"


def test_phase_convention_with_delay_phase_included():
    tau = np.array([1.338e-9, 2.0e-9])
    a = np.array([0.8, 0.2j])
    f_ref = 402e6
    with_phase = a * np.exp(-2j * math.pi * f_ref * tau)
    p = PathProfile(tau, with_phase, gains_include_delay_phase=True, reference_frequency_hz=f_ref)
    np.testing.assert_allclose(p.baseband_gains, a, rtol=1e-12)
    f = np.array([400e6, 410e6])
    np.testing.assert_allclose(p.frequency_response(f), PathProfile(tau, a).frequency_response(f), rtol=1e-12)
    with pytest.raises(EstimatorInputError) as exc:
        PathProfile(tau, with_phase, gains_include_delay_phase=True)
    assert exc.value.field == "profile.reference_frequency_hz"


def test_path_gain_db():
    p = PathProfile([1e-9, 2e-9], [1e-3, 1e-3j])
    assert p.path_gain_db == pytest.approx(10 * math.log10(2e-6))


@pytest.mark.parametrize("kwargs, field", [
    (dict(delays_s=[], gains=[]), "profile.paths"),
    (dict(delays_s=[1e-9, 2e-9], gains=[1.0]), "profile.paths.gain"),
    (dict(delays_s=[1e-9, float("nan")], gains=[1.0, 1.0]), "profile.paths[1].delay_s"),
    (dict(delays_s=[1e-9, float("inf")], gains=[1.0, 1.0]), "profile.paths[1].delay_s"),
    (dict(delays_s=[-1e-9], gains=[1.0]), "profile.paths[0].delay_s"),
    (dict(delays_s=[1e-9, 2e-9], gains=[1.0, complex(float("nan"), 0)]), "profile.paths[1].gain"),
    (dict(delays_s=[1e-9], gains=[0.0]), "profile.paths.gain"),
    (dict(delays_s=[1e-9], gains=[1.0], band_frequencies_hz=[4e8, 4.1e8],
          band_gains=[[1.0, 1.0, 1.0]]), "profile.band_gains"),
    (dict(delays_s=[1e-9], gains=[1.0], band_frequencies_hz=[4e8, 4.1e8]), "profile.band_gains"),
    (dict(delays_s=[1e-9], gains=[1.0], band_frequencies_hz=[4.1e8, 4e8],
          band_gains=[[1.0, 1.0]]), "profile.band_frequencies_hz"),
    (dict(delays_s=[1e-9], gains=[1.0], band_frequencies_hz=[4e8, 4.1e8],
          band_gains=[[1.0, float("nan")]]), "profile.paths[0].band_gains[1]"),
    (dict(delays_s="abc", gains=[1.0]), "profile.paths.delay_s"),
])
def test_invalid_profiles_raise_naming_the_field(kwargs, field):
    with pytest.raises(EstimatorInputError) as exc:
        PathProfile(**kwargs)
    assert exc.value.field == field
    assert isinstance(exc.value, ValueError)
    assert field in str(exc.value)


def test_gains_whose_modulus_overflows_range_like_unit_gains():
    """|1.5e308 (1 + 1j)| is not a float; TOA is scale-free, so the answer is that of (1 + 1j)."""
    import warnings

    from estimators import estimate_toa

    huge = PathProfile([1.338e-9, 1.6e-9], np.array([1.0, 0.5]) * 1.5e308 * (1 + 1j))
    unit = PathProfile([1.338e-9, 1.6e-9], np.array([1.0, 0.5]) * (1 + 1j))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = estimate_toa(huge, method="gcc", snr_db=30.0, trials=5, seed=1)[0]
    ref = estimate_toa(unit, method="gcc", snr_db=30.0, trials=5, seed=1)[0]
    assert got.distance_m == pytest.approx(ref.distance_m, rel=1e-9)


@pytest.mark.parametrize("scale", [1e-300, 1e-150, 1.0, 1e150, 1e300])
def test_extreme_gain_scales_neither_overflow_nor_underflow(scale):
    import warnings

    from estimators import estimate_pdoa, estimate_rss, estimate_toa

    p = PathProfile([1.338e-9, 1.6e-9], [scale, 0.5 * scale])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow / invalid-value RuntimeWarning either
        assert p.path_gain_db == pytest.approx(20 * math.log10(scale) + 10 * math.log10(1.25), rel=1e-12)
        toa = estimate_toa(p, method="gcc", snr_db=30.0, trials=20, seed=1)[0]
        ref = estimate_toa(PathProfile([1.338e-9, 1.6e-9], [1.0, 0.5]), method="gcc", snr_db=30.0, trials=20,
                           seed=1)[0]
        assert toa.distance_m == pytest.approx(ref.distance_m, rel=1e-9)  # TOA is scale-free
        pd = estimate_pdoa(p, frequencies_hz=[400e6, 420e6], snr_db=30.0, trials=20, seed=1)
        assert math.isfinite(pd.distance_m)
        rss = estimate_rss(p, trials=5, seed=1)
        assert math.isfinite(rss.path_loss_db)
