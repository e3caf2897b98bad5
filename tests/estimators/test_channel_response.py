"""CFR / CIR / taps (estimators.channel_response, docs/science.md (S27)-(S29)) against closed forms
and a dense quadrature written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import EstimatorInputError, PathProfile
from estimators.channel_response import cfr, cir, taps

TAU = np.array([1.339e-9, 1.706e-9, 2.206e-9, 1.0e-6])  # the last one late: absolute delays must hold
A = np.array([0.15, -0.09 + 0.06j, 0.05j, 0.01])


def test_taps_of_flat_paths_are_the_sinc_sum():
    # h_l = sum_k a_k exp(-j 2 pi fc tau_k) sinc(l - W tau_k) (Tse & Viswanath Eq 2.34; Sionna's taps),
    # with tap l at the absolute delay l / W: the 1 us path lands on tap 20 at W = 20 MHz.
    # 1e-15 absolute: the closed-form integral against the closed-form sum (|h| ~ 0.1).
    fc, w = 402e6, 20e6
    ell, h = taps(PathProfile(TAU, A), w, centre_hz=fc)
    expected = sum(A[k] * np.exp(-2j * np.pi * fc * TAU[k]) * np.sinc(ell - w * TAU[k]) for k in range(4))
    np.testing.assert_allclose(h, expected, rtol=0, atol=1e-15)
    assert ell[0] == -6 and ell[-1] == 26 and ell[10 + np.argmax(np.abs(h[10:]))] == 20
    # normalize_delays: the time axis starts at the first path, nothing else changes
    ell_n, h_n = taps(PathProfile(TAU, A), w, centre_hz=fc, normalize_delays=True, l_min=-2, l_max=3)
    shifted = sum(A[k] * np.exp(-2j * np.pi * fc * TAU[k]) * np.sinc(ell_n - w * (TAU[k] - TAU[0])) for k in range(4))
    np.testing.assert_allclose(h_n, shifted, rtol=0, atol=1e-15)


def test_cir_of_dispersive_band_gains_is_the_band_limited_integral():
    # Band gains b_k(f) = a_k (1 + c_k (f - f0)) exp(-j 2 pi (f - f0) d_k) sampled every MHz: the
    # profile interpolates them linearly, which the dense trapezoid below integrates with the
    # test's own interpolation (np.interp of the real and imaginary parts). (S28) over the whole
    # 400-420 MHz band at 100 MHz sampling: 1e-9 relative (the trapezoid's own error at 4e5 points).
    fb = np.linspace(400e6, 420e6, 21)
    c = np.array([0.01e-6, -0.02e-6, 0.0, 0.03e-6])
    d = np.array([-0.3e-9, -0.2e-9, 0.1e-9, -0.4e-9])
    bg = A[:, None] * (1 + c[:, None] * (fb - 410e6)) * np.exp(-2j * np.pi * (fb - 410e6) * d[:, None])
    p = PathProfile(TAU, A, band_frequencies_hz=fb, band_gains=bg)
    t, h = cir(p, 100e6, start_s=-20e-9, num_samples=12)
    ff = np.linspace(400e6, 420e6, 400_001)
    hf = sum((np.interp(ff, fb, bg[k].real) + 1j * np.interp(ff, fb, bg[k].imag)) * np.exp(-2j * np.pi * ff * TAU[k])
             for k in range(4))
    expected = np.array([np.trapezoid(hf * np.exp(2j * np.pi * (ff - 410e6) * ti), ff) for ti in t])
    np.testing.assert_allclose(h, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    np.testing.assert_allclose(t, -20e-9 + np.arange(12) / 100e6)
    # CFR at the band frequencies: the band gains' sum with their delay phases (1e-12)
    np.testing.assert_allclose(cfr(p, fb), np.sum(bg * np.exp(-2j * np.pi * fb * TAU[:, None]), axis=0), rtol=1e-12)
    with pytest.raises(EstimatorInputError) as exc:
        taps(p, 40e6)  # 390-430 MHz: beyond the band gains
    assert exc.value.field == "bandwidth_hz"


def test_group_delay_model_cir_is_a_delayed_sinc():
    # b(f) = a exp(-j 2 pi (f - f0)(tau_g - tau_p)): one path's band-limited response is
    # a exp(-j 2 pi fc tau_p) exp(-j 2 pi (fc - f0)(tau_g - tau_p)) W sinc(W (t - tau_g)).
    tau_p, tau_g, f0, a = 2.45e-9, 2.16e-9, 402e6, 0.01 - 0.02j
    p = PathProfile([tau_p], [a], reference_frequency_hz=f0, group_delays_s=[tau_g])
    w, fc = 50e6, 405e6
    t, h = cir(p, 200e6, bandwidth_hz=w, centre_hz=fc, num_samples=30)
    expected = (a * np.exp(-2j * math.pi * fc * tau_p) * np.exp(-2j * math.pi * (fc - f0) * (tau_g - tau_p))
                * w * np.sinc(w * (t - tau_g)))
    np.testing.assert_allclose(h, expected, rtol=0, atol=1e-12 * w * abs(a))
