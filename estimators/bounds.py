"""Cramér-Rao lower bounds for TOA, PDOA and RSS ranging (closed forms).

Notation: SNR is linear (10^(snr_db/10)); v = c / sqrt(eps_r); W a bandwidth;
T0 an observation time; N0 the one-sided noise PSD (two-sided N0/2).

TOA, single tone (thesis Eq 4.7-4.17)
--------------------------------------
Observing r(t) = s(t - tau) + n(t), s(t) = A cos(w t), on [0, T0] in white
Gaussian noise of two-sided PSD N0/2, the Fisher information on tau is
(Eq 4.7)

    F = (2 / N0) * Itau,   Itau = int_0^T0 (d s(t - tau) / d tau)^2 dt.

With s(t - tau) = A cos(w (t - tau)) (Eq 4.8), d/dtau = A w sin(w (t - tau))
(Eq 4.9) and, writing S = sin(2 w (T0 - tau)) + sin(2 w tau),

    Itau = A^2 w^2 [T0/2 - S / (4 w)]                          (Eq 4.11)
    Is   = int_0^T0 s(t - tau)^2 dt = A^2 [T0/2 + S / (4 w)]   (Eq 4.12, = Es)

The SNR over a system bandwidth W is SNR = (Es / T0) / (N0 W) (Eq 4.13), so
N0 = Is / (T0 SNR W) (Eq 4.14) and

    sigma_tau^2 = 1 / F = Is / (2 SNR W T0 Itau)               (Eq 4.16)
    sigma_d     = v sigma_tau                                   (Eq 4.17)

with w = 2 pi f (the angular frequency). ERRATUM: the thesis' MATLAB listing
(App. A.4) substitutes f for w, inflating sigma by about 2 pi (0.21 mm instead
of 0.032 mm at 402 MHz, W 10 GHz, T0 25 ns, SNR 30 dB, eps_r 27.9). The
thesis evaluates Is at tau = 0 and Itau at tau; here both use the same
observed waveform s(t - tau) (identical at tau = 0, the default). For a
sampled observation with per-sample SNR (see waveforms.py), W = fs / 2.

PDOA, two tones (thesis Eq 5.7-5.16)
------------------------------------
Tones at f0 -+ W/2 of equal power, total energy E over T0. By Parseval
(Eq 5.14), F = (2 / N0) int (ds/dtau)^2 dt = sum_i (2 E_i / N0) w_i^2 =
(E / N0) (w1^2 + w2^2) = 8 pi^2 (f0^2 + W^2/4) E/N0, so

    sigma_tau >= [8 pi^2 (f0^2 + W^2/4) E/N0]^(-1/2),  sigma_d = v sigma_tau   (Eq 5.16)

The thesis writes E/N0 as "SNR * T0"; with SNR the in-band ratio P/(N0 W),
E/N0 = SNR W T0 (its plotted case W T0 = 1 reads E/N0 = SNR). This bound
contains the carrier term f0^2: it assumes the carrier-cycle ambiguity is
resolved. An estimator that only uses the phase DIFFERENCE (the common phase
is a nuisance parameter) is bounded by the W^2/4 term alone:

    sigma_tau_pd >= [8 pi^2 (W^2/4) E/N0]^(-1/2) = [2 pi^2 W^2 E/N0]^(-1/2).

N tones (``multitone_crlb``): with E_i/N0 = rho_i, F_full = sum 2 rho_i w_i^2
and, eliminating the common phase, F_pd = sum 2 rho_i (w_i - w_bar)^2 with
w_bar = sum rho_i w_i / sum rho_i. Two equal tones give the formulas above.

RSS (thesis Sec 5.3, after Eq 5.16; IEEE 802.15.6 CM2 log-normal model)
------------------------------------------------------------------------
PL(d) = PL(d0) + 10 n log10(d / d0) + S, S ~ N(0, sigma^2) (dB). The Fisher
information on d is (10 n / (ln 10 d sigma))^2, so

    sigma_d >= ln(10) sigma d / (10 n)

(0.0172 m for sigma = sqrt(5) dB, n = 3, d = 0.1 m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._checks import LINK_SNR_FLOOR_DB, finite_float
from ._checks import relative_permittivity as _check_eps
from ._checks import snr_db as _check_snr
from .constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
from .errors import EstimatorInputError


@dataclass(frozen=True)
class TOABound:
    sigma_s: float
    sigma_m: float


@dataclass(frozen=True)
class PDOABound:
    sigma_s: float
    sigma_m: float
    sigma_phase_difference_s: float
    sigma_phase_difference_m: float


@dataclass(frozen=True)
class RSSBound:
    sigma_m: float


def _snr_linear(snr_db: float) -> float:
    # a bound is a formula: it holds down to a link budget's deepest shadow (LINK_SNR_FLOOR_DB)
    value = _check_snr(snr_db, floor_db=LINK_SNR_FLOOR_DB)
    if value is None:
        raise EstimatorInputError("is required for a bound", "snr_db")
    return 10.0 ** (value / 10.0)


def tone_energy_integrals(carrier_hz: float, duration_s: float, delay_s: float = 0.0,
                          amplitude: float = 1.0) -> tuple[float, float]:
    """(Is, Itau) of Eq 4.11-4.12 for A cos(w (t - tau)) on [0, T0], w = 2 pi f.

    Evaluated without cancellation: with x = w T0 and y = w (T0 - 2 tau), Eq 4.11 reads
    Itau = A^2 w [(x - sin x) + sin x (1 - cos y)] / 2 (both terms >= 0 for x <= pi, x - sin x
    from its series for small x), and Is = A^2 T0 - Itau / w^2 (cos^2 + sin^2 = 1). The
    textbook form T0/2 - S/(4 w) loses every digit when w T0 << 1 (a 1e-15 s observation)."""
    w = 2.0 * math.pi * carrier_hz
    x = w * duration_s
    y = w * (duration_s - 2.0 * delay_s)
    if x < 1e-2:
        x2 = x * x
        x_minus_sin = x * x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    else:
        x_minus_sin = x - math.sin(x)
    a2 = amplitude * amplitude
    i_tau = a2 * w * 0.5 * (x_minus_sin + math.sin(x) * 2.0 * math.sin(0.5 * y) ** 2)
    i_s = a2 * duration_s - i_tau / (w * w)
    return i_s, i_tau


def toa_crlb(carrier_hz: float, duration_s: float, bandwidth_hz: float, snr_db: float,
             relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY, delay_s: float = 0.0) -> TOABound:
    """TOA bound of a single tone, Eq 4.16-4.17 with w = 2 pi f (see module docstring).

    Args: carrier_hz f; duration_s T0; bandwidth_hz W (system/noise bandwidth,
    fs/2 for a sampled observation); snr_db SNR over W; delay_s tau of Eq 4.8.
    Returns sigma_s (delay) and sigma_m = v sigma_s.
    """
    f = finite_float(carrier_hz, "carrier_hz", positive=True)
    t0 = finite_float(duration_s, "duration_s", positive=True)
    bw = finite_float(bandwidth_hz, "bandwidth_hz", positive=True)
    tau = finite_float(delay_s, "delay_s", nonnegative=True)
    snr = _snr_linear(snr_db)
    v = velocity_m_per_s(_check_eps(relative_permittivity))
    i_s, i_tau = tone_energy_integrals(f, t0, tau)
    if i_tau <= 0.0 or i_s <= 0.0:
        raise EstimatorInputError("observation too short to carry timing information", "duration_s")
    sigma_s = math.sqrt(i_s / (2.0 * snr * bw * t0 * i_tau))
    return TOABound(sigma_s, v * sigma_s)


def waveform_toa_crlb(waveform, snr_db: float, bandwidth_hz: float,
                      relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY,
                      carrier_phase_known: bool = True) -> TOABound:
    """Eq 4.16 for any waveform of estimators.waveforms: sigma_tau^2 = Is / (2 SNR W T0 Itau).

    A tone burst uses the closed form (:func:`toa_crlb`); other waveforms
    integrate Is = int s^2 and Itau = int (ds/dt)^2 numerically (analytic
    derivative, trapezoid on a 64-points-per-carrier-period grid over
    +-6 sigma), with T0 the waveform's nominal duration (the same T0 that
    defines P_s in the per-sample SNR, so the bound matches the simulation).

    ``carrier_phase_known=False`` gives the bound of an envelope-only
    (non-coherent) estimator, the carrier phase being a nuisance parameter:
    for s = A g(t) cos(w t + theta) the information left on tau after
    eliminating theta is (2/N0) (A^2/2) int g'^2 dt, i.e. Itau / Is ->
    int g'^2 / int g^2 (= 1 / (2 sigma_t^2) for a Gaussian envelope). It is
    undefined (zero) for a rectangular burst, whose edges are infinitely
    sharp; that case raises.
    """
    if not carrier_phase_known:
        if getattr(waveform, "kind", None) == "tone_burst":
            raise EstimatorInputError("the envelope-only bound needs a band-limited envelope, not a "
                                      "rectangular burst", "waveform.kind")
        bw = finite_float(bandwidth_hz, "bandwidth_hz", positive=True)
        snr = _snr_linear(snr_db)
        v = velocity_m_per_s(_check_eps(relative_permittivity))
        ratio = 1.0 / (2.0 * waveform.sigma_t_s ** 2)  # int g'^2 / int g^2 for a Gaussian
        sigma_s = math.sqrt(1.0 / (2.0 * snr * bw * waveform.duration_s * ratio))
        return TOABound(sigma_s, v * sigma_s)
    if getattr(waveform, "kind", None) == "tone_burst":
        return toa_crlb(waveform.carrier_hz, waveform.duration_s, bandwidth_hz, snr_db, relative_permittivity)
    bw = finite_float(bandwidth_hz, "bandwidth_hz", positive=True)
    snr = _snr_linear(snr_db)
    v = velocity_m_per_s(_check_eps(relative_permittivity))
    sig = waveform.sigma_t_s
    w = 2.0 * math.pi * waveform.carrier_hz
    n = int(max(4096, 64 * 12 * sig * waveform.carrier_hz))
    t = np.linspace(-6.0 * sig, 6.0 * sig, n)
    g = np.exp(-0.5 * (t / sig) ** 2)
    s = g * np.cos(w * t)
    ds = -(t / sig ** 2) * g * np.cos(w * t) - w * g * np.sin(w * t)
    i_s = float(np.trapezoid(s * s, t))
    i_tau = float(np.trapezoid(ds * ds, t))
    sigma_s = math.sqrt(i_s / (2.0 * snr * bw * waveform.duration_s * i_tau))
    return TOABound(sigma_s, v * sigma_s)


def multitone_crlb(frequencies_hz, snr_db: float, duration_s: float | None = None,
                   relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY,
                   relative_powers=None) -> PDOABound:
    """Delay bound of N real tones (generalises Eq 5.15-5.16; see module docstring).

    E/N0 = SNR W T0 with W = max(f) - min(f) and T0 = ``duration_s`` (default
    1 / W, the thesis' W T0 = 1). Energy split by ``relative_powers`` (equal
    by default). Returns the full bound (carrier resolved) and the
    phase-difference (common phase unknown) bound.
    """
    f = np.asarray(frequencies_hz, dtype=float).reshape(-1)
    if f.size < 2 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise EstimatorInputError("need at least two finite, positive frequencies", "frequencies_hz")
    span = float(f.max() - f.min())
    if span <= 0.0:
        raise EstimatorInputError("frequencies must not all be equal", "frequencies_hz")
    t0 = 1.0 / span if duration_s is None else finite_float(duration_s, "duration_s", positive=True)
    snr = _snr_linear(snr_db)
    v = velocity_m_per_s(_check_eps(relative_permittivity))
    p = np.ones_like(f) if relative_powers is None else np.asarray(relative_powers, dtype=float).reshape(-1)
    if p.shape != f.shape or not np.all(np.isfinite(p)) or np.any(p < 0) or p.sum() <= 0:
        raise EstimatorInputError("must be finite, >= 0, not all zero, one per frequency", "relative_powers")
    rho = snr * span * t0 * p / p.sum()
    w = 2.0 * math.pi * f
    f_full = float(np.sum(2.0 * rho * w * w))
    w_bar = float(np.sum(rho * w) / np.sum(rho))
    f_pd = float(np.sum(2.0 * rho * (w - w_bar) ** 2))
    s_full = 1.0 / math.sqrt(f_full)
    s_pd = 1.0 / math.sqrt(f_pd)
    return PDOABound(s_full, v * s_full, s_pd, v * s_pd)


def pdoa_crlb(center_hz: float, tone_spacing_hz: float, snr_db: float, duration_s: float | None = None,
              relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY) -> PDOABound:
    """Two-tone PDOA bound, Eq 5.16 with E/N0 = SNR W T0 (W = tone spacing, T0 default 1/W).

    sigma_s = [8 pi^2 (f0^2 + W^2/4) E/N0]^(-1/2); sigma_phase_difference_s
    = [8 pi^2 (W^2/4) E/N0]^(-1/2); *_m = v * *_s.
    """
    f0 = finite_float(center_hz, "center_hz", positive=True)
    bw = finite_float(tone_spacing_hz, "tone_spacing_hz", positive=True)
    if bw >= 2.0 * f0:
        raise EstimatorInputError("must be below twice center_hz (both tones positive)", "tone_spacing_hz")
    t0 = 1.0 / bw if duration_s is None else finite_float(duration_s, "duration_s", positive=True)
    e_n0 = _snr_linear(snr_db) * bw * t0
    v = velocity_m_per_s(_check_eps(relative_permittivity))
    s_full = 1.0 / math.sqrt(8.0 * math.pi ** 2 * (f0 ** 2 + bw ** 2 / 4.0) * e_n0)
    s_pd = 1.0 / math.sqrt(8.0 * math.pi ** 2 * (bw ** 2 / 4.0) * e_n0)
    return PDOABound(s_full, v * s_full, s_pd, v * s_pd)


def rss_crlb(shadowing_db: float, path_loss_exponent: float, distance_m: float) -> RSSBound:
    """RSS bound sigma_d = ln(10) sigma d / (10 n) (log-normal shadowing, see module docstring)."""
    sigma = finite_float(shadowing_db, "shadowing_db", nonnegative=True)
    n = finite_float(path_loss_exponent, "path_loss_exponent", positive=True)
    d = finite_float(distance_m, "distance_m", positive=True)
    return RSSBound(math.log(10.0) * sigma * d / (10.0 * n))
