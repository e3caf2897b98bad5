"""Waveform synthesis for TOA ranging: transmitted bursts, multipath reception, AWGN.

Representation. Every waveform is the real part of a complex (analytic /
baseband-times-carrier) signal

    s(t) = Re{ s_a(t) },    s_a(t) = A g(t) exp(j 2 pi f_c t),

with a real envelope g. Path k of a :class:`~estimators.profile.PathProfile`
contributes Re{ a_k s_a(t - tau_k) }: the envelope and the carrier are both
evaluated at the EXACT fractional delay t - tau_k (never rounded to a sample),
and the complex gain a_k (default phase convention, delay phase excluded)
scales and phase-shifts it. So a one-path profile with a_k = 1 reproduces
s(t - tau) exactly at every sample.

Time axis: the burst starts at t = 0 and samples are t_n = n / fs,
n = 0..N-1, with N long enough to hold the latest path's burst plus a guard.

Noise. ``snr_db`` is the per-sample signal-to-noise ratio

    SNR = P_s / sigma^2,   P_s = sum_n |r_clean[n]|^2 / (T0 fs),

i.e. the received noiseless waveform's energy spread over the nominal
duration T0 of the burst, divided by the noise variance per sample. For one
path this is A^2 |a|^2 / 2 over sigma^2 (the burst's mean power). Real noise
is N(0, sigma^2) per sample; complex noise is CN(0, sigma^2) (sigma^2/2 per
component). Sampled white noise of variance sigma^2 has two-sided PSD
N0/2 = sigma^2 / fs over the band |f| < fs/2, so this SNR is the thesis'
Ps / (N0 W) (Eq 4.13) with W = fs / 2: that is the W to put in the TOA bound
for the same sampling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ._checks import Check, checkpoint, finite_float
from .errors import EstimatorInputError
from .profile import PathProfile

MAX_SAMPLES_PER_TRIAL = 1 << 18
"""Cap on samples per observation (about 13 us at 20 GS/s)."""

_PATH_CHUNK_ELEMENTS = 1 << 21  # paths x samples evaluated at once (bounded memory)
_SPECTRUM_FLOOR = 1e-20  # |S_a|^2 relative to its peak below which H is not evaluated (amplitude 1e-10)


def _check_common(carrier_hz, sample_rate_hz, amplitude, field_prefix: str) -> tuple[float, float, float]:
    fc = finite_float(carrier_hz, f"{field_prefix}.carrier_hz", positive=True)
    fs = finite_float(sample_rate_hz, f"{field_prefix}.sample_rate_hz", positive=True)
    amp = finite_float(amplitude, f"{field_prefix}.amplitude", positive=True)
    return fc, fs, amp


@dataclass(frozen=True)
class ToneBurst:
    """Rectangular tone burst A cos(2 pi f_c t) for 0 <= t < T0 (the thesis' Ch. 4 signal).

    ``duration_s`` is the observation/burst time T0 of Eq 4.7-4.17. Nyquist:
    ``sample_rate_hz`` must exceed 2 f_c (raises otherwise).
    """

    carrier_hz: float = 402e6
    duration_s: float = 25e-9
    sample_rate_hz: float = 20e9
    amplitude: float = 1.0
    kind: str = "tone_burst"

    def __post_init__(self) -> None:
        fc, fs, amp = _check_common(self.carrier_hz, self.sample_rate_hz, self.amplitude, "waveform")
        t0 = finite_float(self.duration_s, "waveform.duration_s", positive=True)
        if fs <= 2.0 * fc:
            raise EstimatorInputError(
                f"{fs:.6g} Hz is at or below the Nyquist rate 2 f_c = {2 * fc:.6g} Hz of the carrier",
                "waveform.sample_rate_hz")
        if t0 * fs < 4:
            raise EstimatorInputError(f"burst of {t0:.3g} s holds fewer than 4 samples at {fs:.6g} Hz",
                                      "waveform.duration_s")
        if t0 * fc < 1.0:
            raise EstimatorInputError(f"burst of {t0:.3g} s is shorter than one carrier period",
                                      "waveform.duration_s")
        for name, value in (("carrier_hz", fc), ("sample_rate_hz", fs), ("amplitude", amp), ("duration_s", t0)):
            object.__setattr__(self, name, value)

    def envelope(self, t: np.ndarray) -> np.ndarray:
        """g(t) = 1 on [0, T0), else 0."""
        return ((t >= 0.0) & (t < self.duration_s)).astype(float)

    @property
    def highest_frequency_hz(self) -> float:
        return self.carrier_hz


@dataclass(frozen=True)
class GaussianPulse:
    """Gaussian-modulated carrier A exp(-(t - t_c)^2 / (2 sigma_t^2)) cos(2 pi f_c (t - t_c)).

    A band-limited pulse for wideband TOA. ``bandwidth_hz`` B is the two-sided
    -3 dB width of its power spectrum around f_c, so sigma_t = sqrt(ln 2) / (pi B)
    (|G(f)|^2 ~ exp(-4 pi^2 sigma_t^2 f^2) is half at f = B/2). The pulse is
    centred at t_c = 4 sigma_t and its nominal duration (used for the SNR's
    P_s and for the bound's T0) is T0 = 8 sigma_t. The carrier phase is
    referenced to the pulse centre, so the pulse peak is a carrier crest.
    Nyquist: fs must exceed 2 (f_c + 2B) (the spectrum is ~ -50 dB there).
    """

    carrier_hz: float = 410e6
    bandwidth_hz: float = 20e6
    sample_rate_hz: float = 20e9
    amplitude: float = 1.0
    kind: str = "gaussian_pulse"

    def __post_init__(self) -> None:
        fc, fs, amp = _check_common(self.carrier_hz, self.sample_rate_hz, self.amplitude, "waveform")
        bw = finite_float(self.bandwidth_hz, "waveform.bandwidth_hz", positive=True)
        if bw > 2.0 * fc:
            raise EstimatorInputError(f"{bw:.6g} Hz exceeds twice the carrier (the pulse would have DC content)",
                                      "waveform.bandwidth_hz")
        if fs <= 2.0 * (fc + 2.0 * bw):
            raise EstimatorInputError(
                f"{fs:.6g} Hz is at or below the Nyquist rate 2 (f_c + 2 B) = {2 * (fc + 2 * bw):.6g} Hz",
                "waveform.sample_rate_hz")
        for name, value in (("carrier_hz", fc), ("sample_rate_hz", fs), ("amplitude", amp), ("bandwidth_hz", bw)):
            object.__setattr__(self, name, value)

    @property
    def sigma_t_s(self) -> float:
        return math.sqrt(math.log(2.0)) / (math.pi * self.bandwidth_hz)

    @property
    def centre_s(self) -> float:
        return 4.0 * self.sigma_t_s

    @property
    def duration_s(self) -> float:
        return 8.0 * self.sigma_t_s

    def envelope(self, t: np.ndarray) -> np.ndarray:
        return np.exp(-0.5 * ((t - self.centre_s) / self.sigma_t_s) ** 2)

    @property
    def highest_frequency_hz(self) -> float:
        return self.carrier_hz + 2.0 * self.bandwidth_hz


Waveform = ToneBurst | GaussianPulse


def analytic(waveform: Waveform, t: np.ndarray) -> np.ndarray:
    """Complex signal s_a(t) = A g(t) exp(j 2 pi f_c (t - t_ref)) (t_ref = pulse centre, 0 for a burst)."""
    t_ref = getattr(waveform, "centre_s", 0.0)
    return waveform.amplitude * waveform.envelope(t) * np.exp(2j * np.pi * waveform.carrier_hz * (t - t_ref))


def sample_times(waveform: Waveform, n_samples: int) -> np.ndarray:
    return np.arange(n_samples) / waveform.sample_rate_hz


def observation_samples(waveform: Waveform, profile: PathProfile) -> int:
    """Samples needed to hold the latest path's burst plus a guard of T0/2 + 4 carrier periods."""
    t_end = float(profile.delays_s.max()) + 1.5 * waveform.duration_s + 4.0 / waveform.carrier_hz
    if not t_end * waveform.sample_rate_hz < MAX_SAMPLES_PER_TRIAL:  # also catches an infinite pulse
        field = "waveform.bandwidth_hz" if waveform.kind == "gaussian_pulse" else "waveform.sample_rate_hz"
        raise EstimatorInputError(
            f"observing up to the last path ({profile.delays_s.max():.3g} s) plus the {waveform.duration_s:.3g} s "
            f"waveform needs over {MAX_SAMPLES_PER_TRIAL} samples per trial at {waveform.sample_rate_hz:.6g} Hz; "
            "lower sample_rate_hz, shorten the waveform or drop late paths", field)
    n = int(math.ceil(t_end * waveform.sample_rate_hz)) + 1
    if n > MAX_SAMPLES_PER_TRIAL:
        raise EstimatorInputError(
            f"observing up to the last path ({profile.delays_s.max():.3g} s) needs {n} samples per trial, "
            f"over the cap of {MAX_SAMPLES_PER_TRIAL}; lower sample_rate_hz or drop late paths",
            "waveform.sample_rate_hz")
    return n


def transmitted(waveform: Waveform, n_samples: int) -> np.ndarray:
    """Real transmitted samples s(t_n), shape (n_samples,)."""
    return analytic(waveform, sample_times(waveform, n_samples)).real


def received(waveform: Waveform, profile: PathProfile, n_samples: int, *, complex_output: bool = False,
             normalise: bool = False, check: Check = None) -> np.ndarray:
    """Noiseless received samples: the transmitted waveform through the profile's channel.

    The channel is the profile's frequency response H(f) = sum_k b_k(f) exp(-j 2 pi f tau_k)
    with b_k(f) from :attr:`PathProfile.channel_model` (docs/science.md "Waveforms through
    the channel"), i.e. the received analytic signal is the inverse transform of S_a(f) H(f):

    * ``non_dispersive``: b_k = a_k, so path k contributes Re{a_k s_a(t_n - tau_k)}, the
      envelope and the carrier evaluated at the EXACT fractional delay (never rounded to a
      sample), computed in the time domain;
    * ``group_delay``: b_k(f) = a_k exp(-j 2 pi (f - f0) (tau_g,k - tau_k)) makes path k the
      exact time-domain term Re{a_k exp(j 2 pi f0 (tau_g,k - tau_k)) s_a(t_n - tau_g,k)}: its
      envelope at the group delay, its carrier phase that of the phase delay;
    * ``band_gains``: S_a(f) H(f) on the FFT grid of the sampled waveform (zero-padded to
      twice the observation, so nothing wraps into it), H with the band gains interpolated
      inside the band and continued to first order outside it (:meth:`PathProfile.path_responses`).

    Returns shape (n_samples,), real (or the complex sum when ``complex_output``).
    ``normalise`` divides the gains by :attr:`PathProfile.gain_scale` (TOA is scale-free;
    this keeps extreme gains from overflowing). Paths are evaluated in chunks of bounded
    memory (vectorised within a chunk); ``check`` (``estimators._checks.Check``) is called
    before each chunk.
    """
    model = profile.channel_model
    if model == "band_gains":
        out = _received_through_band(waveform, profile, n_samples, normalise, check)
        return out if complex_output else out.real
    t = sample_times(waveform, n_samples)
    out = np.zeros(n_samples, dtype=complex)
    chunk = max(1, _PATH_CHUNK_ELEMENTS // n_samples)
    scale = profile.gain_scale if normalise else 1.0
    a = profile.baseband_gains / scale
    tau = profile.delays_s
    if model == "group_delay":
        a = a * np.exp(2j * np.pi * profile.reference_frequency_hz * (profile.group_delays_s - tau))
        tau = profile.group_delays_s
    for start in range(0, tau.size, chunk):
        checkpoint(check)
        sl = slice(start, start + chunk)
        out += a[sl] @ analytic(waveform, t[None, :] - tau[sl, None])
    return out if complex_output else out.real


def _fft_grid(waveform: Waveform, n_samples: int) -> tuple[int, np.ndarray, np.ndarray]:
    """(nfft, frequencies of the FFT bins [Hz] (negative ones included), S_a on them)."""
    nfft = scipy.fft.next_fast_len(2 * n_samples)
    spectrum = scipy.fft.fft(analytic(waveform, sample_times(waveform, nfft)))
    return nfft, scipy.fft.fftfreq(nfft, 1.0 / waveform.sample_rate_hz), spectrum


def _received_through_band(waveform: Waveform, profile: PathProfile, n_samples: int, normalise: bool,
                           check: Check = None) -> np.ndarray:
    """F^-1{S_a H}, H evaluated only where |S_a| exceeds 1e-10 of its peak (a Gaussian pulse's
    spectrum fills a few percent of the bins; the bins left out change the waveform by < 1e-10
    relative each, far below any noise; a burst's sinc spectrum keeps every bin)."""
    nfft, f, spectrum = _fft_grid(waveform, n_samples)
    power = np.abs(spectrum) ** 2
    keep = np.flatnonzero(power >= _SPECTRUM_FLOOR * power.max())
    fk = f[keep]
    scale = profile.gain_scale if normalise else 1.0
    h = np.zeros(keep.size, complex)
    chunk = max(1, _PATH_CHUNK_ELEMENTS // max(keep.size, 1))
    for start in range(0, profile.delays_s.size, chunk):
        checkpoint(check)
        sl = slice(start, start + chunk)
        b = profile.path_responses(fk, sl, extrapolate=True, scale=scale)
        h += np.sum(b * np.exp(-2j * np.pi * fk[None, :] * profile.delays_s[sl, None]), axis=0)
    out = np.zeros(nfft, complex)
    out[keep] = spectrum[keep] * h
    return scipy.fft.ifft(out)[:n_samples]


def band_coverage(waveform: Waveform, profile: PathProfile, n_samples: int) -> float | None:
    """Share of the transmitted waveform's energy at frequencies inside the profile's band
    (where its band gains are data rather than the first-order continuation); None when
    the profile has no band gains."""
    if profile.channel_model != "band_gains":
        return None
    _, f, spectrum = _fft_grid(waveform, n_samples)
    return profile.band_coverage(f, np.abs(spectrum) ** 2)


def signal_power(clean: np.ndarray, waveform: Waveform) -> float:
    """P_s = sum |clean|^2 / (T0 fs): the per-sample power over the nominal burst duration."""
    return float(np.sum(np.abs(clean) ** 2) / (waveform.duration_s * waveform.sample_rate_hz))


def add_awgn(clean: np.ndarray, snr_db: float | None, rng: np.random.Generator, trials: int,
             power: float) -> np.ndarray:
    """Return (trials, N) noisy copies of ``clean`` at per-sample SNR ``power / sigma^2``.

    Real input gets N(0, sigma^2); complex input CN(0, sigma^2). ``snr_db=None``
    means noiseless (copies only). Randomness only from ``rng``.
    """
    out = np.broadcast_to(clean, (trials, clean.size)).copy()
    if snr_db is None:
        return out
    sigma2 = power / 10.0 ** (snr_db / 10.0)
    if np.iscomplexobj(clean):
        noise = rng.standard_normal((trials, clean.size, 2)) @ np.array([1.0, 1.0j])
        out += math.sqrt(sigma2 / 2.0) * noise
    else:
        out += math.sqrt(sigma2) * rng.standard_normal((trials, clean.size))
    return out
