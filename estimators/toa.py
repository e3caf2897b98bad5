"""Time-of-arrival ranging: first peak (Eq 4.18), all peaks (Eq 4.19-4.21), GCC (Eq 4.22-4.24).

All methods work on a batch of noisy received waveforms, shape (trials, samples),
against the known transmitted waveform (see waveforms.py), vectorised over
trials; distances are v * delay with v = c / sqrt(eps_r). Noise is added to
the received waveform only (the transmitted template is known exactly, as in
the bound of Eq 4.7-4.16; the thesis' listing also adds noise to its copy of
the transmitted signal, which only degrades every method).

Carrier-period ambiguity, done right. A tone burst correlates with itself at
every carrier period, and a carrier crest of the received signal matches any
crest of the transmitted one. The thesis' listing patches this with
``1/f - |delay|``, which only works for delays below one period. Here every
method first takes a COARSE delay tau_c from the burst envelope -- the peak
of the magnitude of the analytic cross-correlation |R_a(lag)| (the envelope
of the cross-correlation of Eq 4.22, from a zero-padded FFT), refined by a
parabola through its three top samples -- and the carrier then resolves the
delay within +-half a period of tau_c:

* gcc (Eq 4.22-4.24): the lag maximising the correlation of the received
  samples with the continuous delayed carrier, found in closed form: a
  least-squares fit r ~ alpha u + beta v with u, v = g(t - tau_c)
  {cos, sin}(w (t - tau_c)) over the burst interior gives the carrier phase
  phi = atan2(beta, alpha) in (-pi, pi] and tau = tau_c + phi / w. This is
  the peak of the real cross-correlation on the crest nearest the envelope
  peak -- what the thesis' +-10-lag cubic spline approximates -- computed
  exactly rather than interpolated (noise-free error ~1e-17 m, versus ~0.02
  to 0.04 mm for a phase read off the sampled correlation, whose
  negative-frequency image and burst edges bias it). Efficient: its spread
  meets the bound of Eq 4.16 for the same sampling (W = fs/2).
* all_peaks (Eq 4.19-4.21): as the thesis does, cut the received signal into
  one-period segments and take the crest of each (:func:`segment_crests`);
  the segments are centred on tau_c + the transmitted crest times
  (:func:`crest_grid`), so received crest m pairs with transmitted crest m
  and every difference lies within half a period of tau_c. The delay is the
  MEAN of the crest-time differences.
* first_peak (Eq 4.18): the same with the first crest only. (Eq 4.21 writes the root mean
  square sqrt(T^T T / n), which is biased upward by var / (2 tau) under
  noise; the mean is the unbiased least-squares estimate of a common delay.)
* envelope (not in the thesis; only on request): tau_c itself, i.e. TOA from
  the envelope alone with the carrier phase unknown -- what a receiver that is
  not phase-coherent with the capsule measures. Its accuracy is set by the
  signal BANDWIDTH (bounds.waveform_toa_crlb(carrier_phase_known=False)),
  not the carrier; meant for band-limited pulses (a rectangular burst's
  envelope peak is a triangle whose 3-point parabola is biased by ~1 mm).

Peak methods need fs >= 4 f_c (a crest's +-1/8-period neighbourhood must hold
samples); GCC and envelope only need Nyquist.

Multipath: all methods measure the composite received waveform; with paths
closer than the resolution (about 1 / bandwidth) they return a weighted
group/phase delay, not the first path -- that bias is what the emulator shows.

Dispersion (docs/science.md "Waveforms through the channel", (S25)-(S26)): the
received waveform is the inverse transform of S(f) H(f) with the profile's own
H(f) (waveforms.received). Through dispersive tissue the envelope arrives at
the group delay tau_g = -d arg H / dw, while the carrier keeps the phase
-arg H(f_c) = w_c tau_phi. ``envelope`` measures tau_g; the carrier methods'
fine step follows the carrier phase, so they return tau_phi + m / f_c, the
carrier-phase delay on the cycle nearest the envelope's tau_g (m the nearest
whole number of periods to (tau_g - tau_phi) f_c): a different delay, by the
dispersion and the interfaces' Fresnel phases, and a cycle off when
|tau_phi - tau_g| exceeds half a period.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import scipy.fft

from ._checks import Check, checkpoint
from ._montecarlo import MonteCarloInputs
from .bounds import waveform_toa_crlb
from .constants import DEFAULT_RELATIVE_PERMITTIVITY
from .errors import EstimatorInputError
from .link import LinkBudget, make_link
from .profile import PathProfile
from .results import TOAResult, summarise
from .waveforms import (
    GaussianPulse,
    ToneBurst,
    Waveform,
    add_awgn,
    band_coverage,
    observation_samples,
    received,
    signal_power,
    transmitted,
)

METHODS = ("first_peak", "all_peaks", "gcc", "envelope")
THESIS_METHODS = ("first_peak", "all_peaks", "gcc")
"""What ``method="all"`` runs (the thesis' three; ``envelope`` only on request)."""
MAX_TOTAL_SAMPLES = 50_000_000
"""Cap on trials x samples per request (work budget)."""

_CHUNK_ELEMENTS = 1 << 21  # trials x fft length processed at once (~100 MB peak)


def make_waveform(spec: Waveform | Mapping | None) -> Waveform:
    """A waveform from a dataclass, a dict like docs/api.md's ``waveform`` field, or None (default burst)."""
    if spec is None:
        return ToneBurst()
    if isinstance(spec, (ToneBurst, GaussianPulse)):
        return spec
    if not isinstance(spec, Mapping):
        raise EstimatorInputError("must be an object with a 'kind'", "waveform")
    spec = dict(spec)
    kind = spec.pop("kind", "tone_burst")
    cls = {"tone_burst": ToneBurst, "gaussian_pulse": GaussianPulse}.get(kind)
    if cls is None:
        raise EstimatorInputError(f"unknown kind {kind!r} (tone_burst | gaussian_pulse)", "waveform.kind")
    allowed = set(cls.__dataclass_fields__) - {"kind"}
    extra = set(spec) - allowed
    if extra:
        raise EstimatorInputError(f"unknown field(s) {sorted(extra)} for {kind}", "waveform")
    return cls(**spec)


def _parabola_offset(y0: np.ndarray, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
    """Vertex offset (samples, in [-1, 1]) of the parabola through (-1, y0), (0, y1), (1, y2)."""
    denom = y0 - 2.0 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(denom < 0, 0.5 * (y0 - y2) / denom, 0.0)
    return np.clip(off, -1.0, 1.0)


def analytic_xcorr(rx: np.ndarray, tx: np.ndarray) -> np.ndarray:
    """Analytic cross-correlation R_a[trial, lag + n - 1], lag = -(n-1)..(n-1) (Eq 4.22).

    Re R_a is sum_m rx[m + lag] tx[m] (linear, zero-padded FFT correlation);
    |R_a| is its envelope (negative frequencies of the cross-spectrum removed).
    """
    n = rx.shape[-1]
    nfft = scipy.fft.next_fast_len(2 * n)
    spec = scipy.fft.rfft(rx, nfft, axis=-1) * np.conj(scipy.fft.rfft(tx, nfft))
    spec[..., 1:(nfft + 1) // 2] *= 2.0  # one-sided: positive frequencies doubled, DC/Nyquist once
    r = scipy.fft.ifft(spec, nfft, axis=-1)  # zero-padded = negative frequencies zero
    return np.concatenate([r[..., nfft - (n - 1):], r[..., :n]], axis=-1)


def coarse_delay(r_a: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Envelope-peak delay tau_c (s) per trial and the integer lag index of the peak."""
    env = np.abs(r_a)
    n_lags = env.shape[-1]
    i = np.argmax(env, axis=-1)
    rows = np.arange(env.shape[0])
    im, ip = np.clip(i - 1, 0, n_lags - 1), np.clip(i + 1, 0, n_lags - 1)
    off = _parabola_offset(env[rows, im], env[rows, i], env[rows, ip])
    n = (n_lags + 1) // 2
    return (i - (n - 1) + off) / fs, i


def _fit_window(waveform: Waveform, x: np.ndarray) -> np.ndarray:
    """Envelope weights of the GCC fine fit at times ``x`` since the coarse arrival.

    A tone burst uses its interior [d, T0 - d], d = min(T0/8, a quarter period), so
    the fit never straddles a burst edge even if the coarse delay is off by up to d;
    other waveforms use their own (smooth) envelope.
    """
    if waveform.kind == "tone_burst":
        d = min(waveform.duration_s / 8.0, 0.25 / waveform.carrier_hz)
        return ((x >= d) & (x < waveform.duration_s - d)).astype(float)
    return waveform.envelope(x)


def gcc_delay(rx: np.ndarray, waveform: Waveform, tau_c: np.ndarray) -> np.ndarray:
    """GCC fine delay (s) per trial around the coarse delay ``tau_c`` (see module docstring).

    Least-squares fit rx ~ alpha u + beta v with u, v = g(t - tau_c) {cos, sin}(w (t - tau_c - t_ref)):
    the received carrier is then rho g cos(w (t - tau_c - t_ref) - phi) with phi = atan2(beta, alpha)
    in (-pi, pi], so tau = tau_c + phi / w lies within half a carrier period of tau_c.
    """
    fs, w = waveform.sample_rate_hz, 2.0 * math.pi * waveform.carrier_hz
    t_ref = getattr(waveform, "centre_s", 0.0)
    x = np.arange(rx.shape[-1]) / fs - tau_c[:, None]
    g = _fit_window(waveform, x)
    arg = w * (x - t_ref)
    u, v = g * np.cos(arg), g * np.sin(arg)
    suu, svv, suv = np.sum(u * u, -1), np.sum(v * v, -1), np.sum(u * v, -1)
    sru, srv = np.sum(rx * u, -1), np.sum(rx * v, -1)
    det = suu * svv - suv * suv
    alpha = (svv * sru - suv * srv) / det
    beta = (suu * srv - suv * sru) / det
    return tau_c + np.arctan2(beta, alpha) / w


def crest_grid(waveform: Waveform) -> np.ndarray:
    """Nominal crest times (s) of the transmitted carrier that the peak methods use.

    Crests sit where the carrier phase is 0: m / f_c for a burst (t_ref = 0),
    t_c + m / f_c for a pulse. A burst uses every crest whose one-period segment
    [crest - T/2, crest + T/2) lies inside [0, T0] (so no segment straddles an
    edge); a pulse those within one sigma_t of its centre (envelope >= 0.6).
    """
    period = 1.0 / waveform.carrier_hz
    if waveform.kind == "tone_burst":
        m = np.arange(1, int(math.floor(waveform.duration_s / period - 0.5)) + 1)
        return m * period
    m_max = int(math.floor(waveform.sigma_t_s / period))
    return waveform.centre_s + np.arange(-m_max, m_max + 1) * period


def segment_crests(x: np.ndarray, fs: float, carrier_hz: float, centres_s: np.ndarray) -> np.ndarray:
    """Crest time (s) in each one-period segment centred on ``centres_s`` (Eq 4.19-4.20).

    x: (trials, N) real; centres_s: (trials, M). In each segment [c - T/2, c + T/2)
    the largest sample is the coarse crest; its time is refined by the phase of a
    cosine fitted over its +-K samples (K = round(fs / (8 f_c)), at least 1):
    y_k ~ alpha cos(w k / fs) + beta sin(w k / fs), offset = atan2(beta, alpha) / w,
    exact for a sampled sinusoid at any fractional position (a 3-point parabola
    is both biased and noise-dominated at tens of samples per period).
    Returns (trials, M).
    """
    n = x.shape[-1]
    seg_len = max(2, int(round(fs / carrier_hz)))
    start = np.rint(centres_s * fs).astype(np.int64) - seg_len // 2
    idx = np.clip(start[..., None] + np.arange(seg_len), 0, n - 1)  # (T, M, L)
    rows = np.arange(x.shape[0])[:, None, None]
    seg = x[rows, idx]
    top = np.take_along_axis(idx, np.argmax(seg, axis=-1)[..., None], axis=-1)[..., 0]  # (T, M)
    k_half = max(1, int(round(fs / (8.0 * carrier_hz))))
    k = np.arange(-k_half, k_half + 1)
    win = x[rows, np.clip(top[..., None] + k, 0, n - 1)]
    ph = 2.0 * math.pi * carrier_hz * k / fs
    c, sn = np.cos(ph), np.sin(ph)
    alpha = win @ c / np.dot(c, c)
    beta = win @ sn / np.dot(sn, sn)
    return top / fs + np.arctan2(beta, alpha) / (2.0 * math.pi * carrier_hz)


def peak_delays(rx: np.ndarray, tx_crests: np.ndarray, grid: np.ndarray, fs: float, carrier_hz: float,
                tau_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first_peak, all_peaks) delays per trial from the crests in segments at tau_c + grid."""
    r = segment_crests(rx, fs, carrier_hz, tau_c[:, None] + grid[None, :])
    d = r - tx_crests[None, :]
    return d[:, 0], np.mean(d, axis=1)


def toa_samples(profile: PathProfile, waveform: Waveform | Mapping | None = None) -> int:
    """Samples per trial of a TOA request, the unit of its work: synthesising the received
    waveform costs about ``paths x samples`` complex exponentials, each Monte Carlo trial
    about ``samples`` (an FFT correlation of twice that length). Raises like
    :func:`estimate_toa` for an invalid waveform or an observation over the sample cap."""
    if not isinstance(profile, PathProfile):
        raise EstimatorInputError("must be a PathProfile", "profile")
    return observation_samples(make_waveform(waveform), profile)


def estimate_toa(profile: PathProfile, method: str = "all", waveform: Waveform | Mapping | None = None,
                 snr_db: float | None = 30.0, trials: int = 100, seed=0,
                 relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY,
                 true_distance_m: float | None = None, return_estimates: bool = False,
                 link: LinkBudget | Mapping | None = None, check: Check = None) -> list[TOAResult]:
    """Monte Carlo TOA ranging over ``profile`` (docs/api.md POST /v1/ranging/toa).

    Args:
        profile: the channel (PathProfile).
        method: ``first_peak`` | ``all_peaks`` | ``gcc`` | ``envelope`` | ``all`` (the thesis'
            three, in that order).
        waveform: ToneBurst / GaussianPulse or a dict ``{"kind": ..., ...}``; default
            402 MHz, 25 ns burst at 20 GS/s.
        snr_db: per-sample SNR (waveforms.py docstring); None = noiseless.
        trials: Monte Carlo runs, 1..10000. seed: int >= 0 or numpy Generator.
        relative_permittivity: velocity assumption (default 27.9).
        true_distance_m: adds error_m / rmse_m.
        return_estimates: attach the per-trial distance estimates.
        link: a :class:`~estimators.link.LinkBudget` (or its dict) instead of ``snr_db``: the
            per-sample SNR is then (S24) from the profile's own path gain, over the noise
            bandwidth fs / 2 unless the link gives one; ``snr_db`` is ignored.
        check: called between chunks of synthesis and of trials; raises to stop
            (``estimators._checks.Check``). Work: see :func:`toa_samples`.

    The waveform goes through the profile's channel model (module docstring,
    waveforms.received); each result names it (``channel_model``) and reports the
    ``snr_db`` used. Returns one TOAResult per method. crlb_m is the Eq 4.16 bound for this
    waveform and SNR with W = fs / 2 (None when noiseless); the envelope
    method's is the envelope-only bound (None for a rectangular burst, whose
    envelope has unbounded bandwidth). Every trial yields an estimate; below
    the threshold SNR (about 0 dB per sample for the default burst) the coarse
    envelope picks wrong lags and errors grow far beyond the bound.
    """
    if not isinstance(profile, PathProfile):
        raise EstimatorInputError("must be a PathProfile", "profile")
    if method == "all":
        methods = THESIS_METHODS
    elif method in METHODS:
        methods = (method,)
    else:
        raise EstimatorInputError(
            f"unknown method {method!r} (first_peak | all_peaks | gcc | envelope | all)", "method")
    wf = make_waveform(waveform)
    link = make_link(link)
    if link is not None:
        snr_db = link.snr_db(profile.path_gain_db, wf.sample_rate_hz / 2.0)
    mc = MonteCarloInputs(snr_db, trials, seed, relative_permittivity, true_distance_m, from_link=link is not None)
    snr, n_trials, rng, eps, v = mc.snr_db, mc.trials, mc.rng, mc.relative_permittivity, mc.velocity_m_per_s
    true_distance_m = mc.true_distance_m
    fs, fc = wf.sample_rate_hz, wf.carrier_hz
    peak_methods = [m for m in methods if m in ("first_peak", "all_peaks")]
    if peak_methods and fs < 4.0 * fc:
        raise EstimatorInputError(
            f"peak methods need sample_rate_hz >= 4 x carrier ({4 * fc:.6g} Hz) to locate crests; "
            "use method 'gcc' or sample faster", "waveform.sample_rate_hz")

    n = observation_samples(wf, profile)
    if n * n_trials > MAX_TOTAL_SAMPLES:
        raise EstimatorInputError(
            f"{n_trials} trials x {n} samples exceeds the work cap of {MAX_TOTAL_SAMPLES} samples", "trials")
    tx = transmitted(wf, n)
    clean = received(wf, profile, n, normalise=True, check=check)
    power = signal_power(clean, wf)
    if not power > 0.0:
        raise EstimatorInputError("the paths cancel: the received waveform is identically zero",
                                  "profile.paths.gain")
    grid = crest_grid(wf)
    if peak_methods and grid.size == 0:
        raise EstimatorInputError("the burst holds no whole carrier period away from its edges for the "
                                  "peak methods", "waveform.duration_s")
    tx_crests = segment_crests(tx[None, :], fs, fc, grid[None, :])[0] if peak_methods else grid

    est = {m: np.empty(n_trials) for m in methods}
    chunk = max(1, _CHUNK_ELEMENTS // scipy.fft.next_fast_len(2 * n))
    for start in range(0, n_trials, chunk):
        checkpoint(check)
        count = min(chunk, n_trials - start)
        rx = add_awgn(clean, snr, rng, count, power)
        r_a = analytic_xcorr(rx, tx)
        tau_c, _ = coarse_delay(r_a, fs)
        sl = slice(start, start + count)
        if "gcc" in est:
            est["gcc"][sl] = gcc_delay(rx, wf, tau_c)
        if "envelope" in est:
            est["envelope"][sl] = tau_c
        if "first_peak" in est or "all_peaks" in est:
            first, allp = peak_delays(rx, tx_crests, grid, fs, fc, tau_c)
            if "first_peak" in est:
                est["first_peak"][sl] = first
            if "all_peaks" in est:
                est["all_peaks"][sl] = allp

    coverage = band_coverage(wf, profile, n)
    crlb = None if snr is None else waveform_toa_crlb(wf, snr, fs / 2.0, eps).sigma_m
    crlb_env = None
    if snr is not None and "envelope" in methods and wf.kind != "tone_burst":
        crlb_env = waveform_toa_crlb(wf, snr, fs / 2.0, eps, carrier_phase_known=False).sigma_m
    out = []
    for m in methods:
        dist = v * est[m]
        stats = summarise(dist, true_distance_m)
        out.append(TOAResult(method=m, distance_m=stats.distance_m, delay_s=float(np.mean(est[m])),
                             std_m=stats.std_m, error_m=stats.error_m, rmse_m=stats.rmse_m,
                             crlb_m=crlb_env if m == "envelope" else crlb,
                             trials=n_trials, estimates_m=dist if return_estimates else None, snr_db=snr,
                             channel_model=profile.channel_model, band_coverage=coverage))
    return out
