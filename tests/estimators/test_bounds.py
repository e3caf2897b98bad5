"""Cramér-Rao bounds of estimators.bounds against independent numerical Fisher information
and the published numbers (docs/science.md, thesis Sec 4.4.1 / Fig 5.3 / Sec 5.3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from estimators import EstimatorInputError, multitone_crlb, pdoa_crlb, rss_crlb, toa_crlb

C = 299_792_458.0
V = C / math.sqrt(27.9)  # written out here on purpose: no shared code with the implementation


def _quad(fun, a, b):
    # Oscillatory integrands: split into many sub-intervals so quad converges to ~1e-10 relative.
    value, _ = integrate.quad(fun, a, b, limit=2000, epsabs=0.0, epsrel=1e-11)
    return value


def _toa_sigma_numeric(f, t0, w_band, snr_db, tau=0.0):
    """Eq 4.16 from scipy quadrature of s^2 and (ds/dtau)^2 for s = cos(2 pi f (t - tau))."""
    w = 2 * math.pi * f
    i_s = _quad(lambda t: math.cos(w * (t - tau)) ** 2, 0.0, t0)
    i_tau = _quad(lambda t: (w * math.sin(w * (t - tau))) ** 2, 0.0, t0)
    snr = 10 ** (snr_db / 10)
    return math.sqrt(i_s / (2 * snr * w_band * t0 * i_tau))


@pytest.mark.parametrize("tau", [0.0, 1.338e-9, 0.37e-9])
def test_toa_bound_matches_numerical_integration(tau):
    # 1e-6 relative: quadrature accuracy, far below any physical meaning.
    b = toa_crlb(402e6, 25e-9, 10e9, 30.0, 27.9, delay_s=tau)
    expected = _toa_sigma_numeric(402e6, 25e-9, 10e9, 30.0, tau)
    assert b.sigma_s == pytest.approx(expected, rel=1e-6)
    assert b.sigma_m == pytest.approx(V * expected, rel=1e-6)


def test_toa_bound_published_value_and_listing_erratum():
    # docs/science.md: the correct bound is about 0.032 mm (within 1 %).
    b = toa_crlb(402e6, 25e-9, 10e9, 30.0, 27.9)
    assert b.sigma_m == pytest.approx(0.032e-3, rel=0.01)
    # The thesis listing substitutes f for w: feeding w = 402e6 rad/s (f = 402e6 / 2 pi)
    # reproduces its inflated ~0.21 mm (5 %: the quoted figure has two digits).
    wrong = toa_crlb(402e6 / (2 * math.pi), 25e-9, 10e9, 30.0, 27.9)
    assert wrong.sigma_m == pytest.approx(0.21e-3, rel=0.05)


def test_toa_bound_scaling():
    # sigma ~ 1 / sqrt(SNR W T0) and ~ 1 / f for whole-period observations (Is/Itau = 1/w^2).
    base = toa_crlb(400e6, 25e-9, 10e9, 30.0).sigma_s
    assert toa_crlb(400e6, 25e-9, 10e9, 40.0).sigma_s == pytest.approx(base / math.sqrt(10), rel=1e-9)
    assert toa_crlb(800e6, 25e-9, 10e9, 30.0).sigma_s == pytest.approx(base / 2, rel=1e-9)
    assert base == pytest.approx(1 / (2 * math.pi * 400e6 * math.sqrt(2 * 1000 * 10e9 * 25e-9)), rel=1e-9)


def _two_tone_fisher(f1, f2, t0, snr_db, w_band):
    """Numerical 2x2 Fisher matrix for (tau, theta) of cos(w1 (t - tau) + theta) + cos(w2 (t - tau) + theta).

    N0 from SNR = P / (N0 W), P = E / T0. Returns (F_tau_tau, Schur complement for tau with theta unknown).
    """
    w1, w2 = 2 * math.pi * f1, 2 * math.pi * f2
    energy = _quad(lambda t: (math.cos(w1 * t) + math.cos(w2 * t)) ** 2, 0.0, t0)
    n0 = (energy / t0) / (10 ** (snr_db / 10) * w_band)

    def d_tau(t):
        return w1 * math.sin(w1 * t) + w2 * math.sin(w2 * t)

    def d_theta(t):
        return -math.sin(w1 * t) - math.sin(w2 * t)

    f_tt = 2 / n0 * _quad(lambda t: d_tau(t) ** 2, 0.0, t0)
    f_hh = 2 / n0 * _quad(lambda t: d_theta(t) ** 2, 0.0, t0)
    f_th = 2 / n0 * _quad(lambda t: d_tau(t) * d_theta(t), 0.0, t0)
    return f_tt, f_tt - f_th ** 2 / f_hh


def test_pdoa_bound_matches_numerical_fisher_information():
    f0, w = 410e6, 20e6
    f_tt, f_pd = _two_tone_fisher(f0 - w / 2, f0 + w / 2, 1 / w, 30.0, w)
    b = pdoa_crlb(f0, w, 30.0)  # W T0 = 1 by default
    # 1e-3: over T0 = 1/W the tones' cross terms integrate to ~0 only up to the carrier edge terms.
    assert b.sigma_s == pytest.approx(1 / math.sqrt(f_tt), rel=1e-3)
    assert b.sigma_phase_difference_s == pytest.approx(1 / math.sqrt(f_pd), rel=1e-3)
    assert b.sigma_m == pytest.approx(V / math.sqrt(f_tt), rel=1e-3)


def test_pdoa_bound_published_value():
    # docs/science.md / thesis Fig 5.3 (W T0 = 1): about 0.49 mm at f0 410 MHz, W 20 MHz, SNR 30 dB (1 %).
    b = pdoa_crlb(410e6, 20e6, 30.0, relative_permittivity=27.9)
    assert b.sigma_m == pytest.approx(0.49e-3, rel=0.01)
    # Formula written out: v [8 pi^2 (f0^2 + W^2/4) SNR W T0]^-1/2 and the W^2/4-only term.
    assert b.sigma_m == pytest.approx(V / math.sqrt(8 * math.pi ** 2 * (410e6 ** 2 + 1e14) * 1000), rel=1e-12)
    assert b.sigma_phase_difference_m == pytest.approx(V / math.sqrt(8 * math.pi ** 2 * 1e14 * 1000), rel=1e-12)
    # E/N0 = SNR W T0: a 10x longer observation is 10x more energy.
    assert pdoa_crlb(410e6, 20e6, 30.0, duration_s=10 / 20e6).sigma_m == pytest.approx(b.sigma_m / math.sqrt(10))


def test_multitone_bound_reduces_to_two_tone():
    two = pdoa_crlb(410e6, 20e6, 25.0, duration_s=3e-7)
    multi = multitone_crlb([400e6, 420e6], 25.0, duration_s=3e-7)
    assert multi.sigma_m == pytest.approx(two.sigma_m, rel=1e-12)
    assert multi.sigma_phase_difference_m == pytest.approx(two.sigma_phase_difference_m, rel=1e-12)


def test_multitone_phase_difference_bound_closed_form():
    # N equal tones, rho = SNR W T0 / N each: F = 2 rho sum (w_i - w_bar)^2.
    f = np.linspace(400e6, 420e6, 21)
    snr = 10 ** 3.0
    rho = snr * 1.0 / f.size
    w = 2 * np.pi * f
    expected = V / math.sqrt(2 * rho * np.sum((w - w.mean()) ** 2))
    assert multitone_crlb(f, 30.0).sigma_phase_difference_m == pytest.approx(expected, rel=1e-12)


def test_rss_bound_published_value():
    # Thesis Sec 5.3: sigma sqrt(5) dB, n 3, d 0.1 m -> 0.017 m (0.0172 m, 1 %).
    b = rss_crlb(math.sqrt(5), 3.0, 0.1)
    assert b.sigma_m == pytest.approx(0.0172, rel=0.01)
    assert b.sigma_m == pytest.approx(0.017, rel=0.01)
    assert b.sigma_m == pytest.approx(math.log(10) * math.sqrt(5) / 30 * 0.1, rel=1e-12)


def test_rss_bound_matches_fisher_information_of_lognormal_model():
    # Numerical d/dd of the mean PL(d) = PL0 + 10 n log10(d/d0): F = (dPL/dd)^2 / sigma^2.
    n, sigma, d, h = 4.26, 7.85, 0.08, 1e-7
    slope = (10 * n * math.log10((d + h) / 0.05) - 10 * n * math.log10((d - h) / 0.05)) / (2 * h)
    assert rss_crlb(sigma, n, d).sigma_m == pytest.approx(sigma / abs(slope), rel=1e-6)


@pytest.mark.parametrize("call, field", [
    (lambda: toa_crlb(-1, 25e-9, 10e9, 30), "carrier_hz"),
    (lambda: toa_crlb(402e6, 0, 10e9, 30), "duration_s"),
    (lambda: toa_crlb(402e6, 25e-9, float("nan"), 30), "bandwidth_hz"),
    (lambda: toa_crlb(402e6, 25e-9, 10e9, float("inf")), "snr_db"),
    (lambda: toa_crlb(402e6, 25e-9, 10e9, 30, relative_permittivity=0.5), "relative_permittivity"),
    (lambda: pdoa_crlb(410e6, 0, 30), "tone_spacing_hz"),
    (lambda: pdoa_crlb(410e6, 20e6, 30, duration_s=-1), "duration_s"),
    (lambda: rss_crlb(-1, 3, 0.1), "shadowing_db"),
    (lambda: rss_crlb(2, 3, 0), "distance_m"),
    (lambda: multitone_crlb([400e6], 30), "frequencies_hz"),
])
def test_bound_input_errors_name_the_field(call, field):
    with pytest.raises(EstimatorInputError) as exc:
        call()
    assert exc.value.field == field
    assert exc.value.reason
