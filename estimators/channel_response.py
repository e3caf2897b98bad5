"""Channel outputs as channel emulators give them: frequency response, impulse response, taps.

For one receiver's :class:`~estimators.profile.PathProfile` (docs/science.md "Channel
outputs", (S27)-(S29)), with b_k(f) the path's gain without its delay phase
(:attr:`PathProfile.channel_model`: band gains with dispersion, Fresnel and absorption
at every frequency; the first-order group-delay model; or constant gains):

* :func:`cfr`, the summed frequency response at given frequencies (S27)

      H(f) = sum_k b_k(f) exp(-j 2 pi f tau_k);

* :func:`cir`, the baseband-equivalent impulse response band-limited to
  [f_lo, f_hi] around a centre f_c and sampled at a given rate (S28)

      h(t) = int_{f_lo}^{f_hi} H(f) exp(j 2 pi (f - f_c) t) df        [1/s]

  (an ideal band-pass receiver's view of the channel, mixed down by f_c);

* :func:`taps`, the discrete-time channel of a system of bandwidth W sampled at W (S29)

      h_l = h(l / W) / W  with [f_lo, f_hi] = [f_c - W/2, f_c + W/2],

  which for frequency-flat paths is sum_k a_k exp(-j 2 pi f_c tau_k) sinc(l - W tau_k),
  the taps of Sionna RT's ``Paths.taps`` and of the textbooks (Tse & Viswanath, Eq 2.34).

Delays are absolute: t = 0 (tap l = 0) is the transmitter's emission, never the first
path's arrival, unless ``normalize_delays=True`` asks for the time axis to start at the
first path (its phase delay), as Sionna's ``normalize_delays`` does.

The integral (S28) is evaluated in closed form for the profile's own model of b_k
(constant, exponential in f, or linear between band frequencies, each piece integrated
exactly with exp(j 2 pi f u)), not by quadrature: exact for any delay, however late.
"""

from __future__ import annotations

import math

import numpy as np

from ._checks import finite_float
from .errors import EstimatorInputError
from .profile import PathProfile

MAX_OUTPUT_SAMPLES = 1 << 16
"""Cap on impulse-response samples / taps per call."""
_CHUNK_ELEMENTS = 1 << 20  # paths x samples evaluated at once

#: Lowest tap bandwidth and impulse-response sampling rate [Hz]: samples at most a second apart
#: (in-body delays are nanoseconds; below this h / W or h / fs overflows for no purpose).
MIN_RATE_HZ = 1.0


def _check_profile(profile) -> PathProfile:
    if not isinstance(profile, PathProfile):
        raise EstimatorInputError("must be a PathProfile", "profile")
    return profile


def _time_origin(profile: PathProfile, normalize_delays: bool) -> float:
    return profile.first_path_delay_s if normalize_delays else 0.0


def cfr(profile: PathProfile, frequencies_hz, *, normalize_delays: bool = False) -> np.ndarray:
    """(S27) H(f) at ``frequencies_hz`` (complex, same shape; absolute delays unless
    ``normalize_delays``, which multiplies by exp(+j 2 pi f tau_first)). A ``band_gains``
    profile is only known inside its band (outside raises, field ``frequencies_hz``)."""
    profile = _check_profile(profile)
    h = profile.frequency_response(frequencies_hz)
    if normalize_delays:
        f = np.asarray(frequencies_hz, float)
        h = h * np.exp(2j * math.pi * f * profile.first_path_delay_s)
    return h


def _phi(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(int_0^1 e^{y x} dx, int_0^1 x e^{y x} dx), accurate for every complex y (series near 0)."""
    small = np.abs(y) < 0.5
    p1 = np.empty_like(y)
    p2 = np.empty_like(y)
    big = ~small
    if big.any():
        yb = y[big]
        e = np.exp(yb)
        p1[big] = (e - 1.0) / yb
        p2[big] = (e * (yb - 1.0) + 1.0) / (yb * yb)
    if small.any():
        ys = y[small]
        term = np.ones_like(ys)  # y^k / k!
        s1 = np.zeros_like(ys)
        s2 = np.zeros_like(ys)
        for k in range(18):  # |y| < 0.5: the next term is below 0.5^18 / 18! ~ 6e-22
            s1 += term / (k + 1)
            s2 += term / (k + 2)
            term = term * ys / (k + 1)
        p1[small], p2[small] = s1, s2
    return p1, p2


def _pieces(profile: PathProfile, sl: slice, centre_hz: float, lo_hz: float, hi_hz: float, extrapolate: bool):
    """b_k on [lo, hi] as pieces (nu1, width, p (K,), r (K,), s (K,)) with
    b_k(f_c + nu) = (p + r (nu - nu1) / width) exp(s (nu - nu1)) on [nu1, nu1 + width]."""
    model = profile.channel_model
    zeros = np.zeros(profile.delays_s[sl].size, complex)
    if model == "non_dispersive":
        return [(lo_hz - centre_hz, hi_hz - lo_hz, profile.baseband_gains[sl], zeros, zeros)]
    if model == "group_delay":
        p = profile.path_responses(np.array([lo_hz]), sl)[:, 0]
        s = -2j * math.pi * (profile.group_delays_s[sl] - profile.delays_s[sl])
        return [(lo_hz - centre_hz, hi_hz - lo_hz, p, zeros, s)]
    bf = profile.band_frequencies_hz
    tol = 1e-9 * bf[-1]
    if not extrapolate and (lo_hz < bf[0] - tol or hi_hz > bf[-1] + tol):
        raise EstimatorInputError(
            f"[{lo_hz:.6g}, {hi_hz:.6g}] Hz is not inside the profile's band [{bf[0]:.6g}, {bf[-1]:.6g}] Hz "
            "(per-frequency gains are only known inside it): trace a wider band or ask for a narrower one",
            "bandwidth_hz")
    span = profile.continuation_span_hz
    knots = np.concatenate([bf, [bf[0] - span, bf[-1] + span]])
    edges = np.unique(np.concatenate([[lo_hz, hi_hz], knots[(knots > lo_hz) & (knots < hi_hz)]]))
    rate_lo, rate_hi = profile.edge_rates(sl)
    values = profile.path_responses(edges, sl, extrapolate=True)
    out = []
    for i in range(edges.size - 1):
        a, b = edges[i], edges[i + 1]
        if b <= bf[0] + tol:  # below the band: exponential continuation (magnitude held beyond one span)
            s = rate_lo if a >= bf[0] - span - tol else 1j * rate_lo.imag
            out.append((a - centre_hz, b - a, values[:, i], zeros, s))
        elif a >= bf[-1] - tol:  # above it
            s = rate_hi if b <= bf[-1] + span + tol else 1j * rate_hi.imag
            out.append((a - centre_hz, b - a, values[:, i], zeros, s))
        else:  # inside: linear between band frequencies
            out.append((a - centre_hz, b - a, values[:, i], values[:, i + 1] - values[:, i], zeros))
    return out


def _band_limited(profile: PathProfile, times_s: np.ndarray, centre_hz: float, lo_hz: float, hi_hz: float,
                  extrapolate: bool) -> np.ndarray:
    """(S28) h(t) at absolute ``times_s``, in closed form piece by piece (module docstring)."""
    t = np.asarray(times_s, float).reshape(-1)
    out = np.zeros(t.size, complex)
    tau = profile.delays_s
    chunk = max(1, _CHUNK_ELEMENTS // max(t.size, 1))
    for start in range(0, tau.size, chunk):
        sl = slice(start, start + chunk)
        u = t[None, :] - tau[sl, None]  # (K, T): time since each path's phase delay
        carrier = np.exp(-2j * math.pi * centre_hz * tau[sl])[:, None]
        for nu1, width, p, r, s in _pieces(profile, sl, centre_hz, lo_hz, hi_hz, extrapolate):
            y = (s[:, None] + 2j * math.pi * u) * width
            p1, p2 = _phi(y)
            out += np.sum(carrier * np.exp(2j * math.pi * nu1 * u) * width * (p[:, None] * p1 + r[:, None] * p2),
                          axis=0)
    return out


def _centre_and_band(profile: PathProfile, centre_hz, bandwidth_hz) -> tuple[float, float]:
    if centre_hz is None:
        if profile.band_frequencies_hz is not None and profile.band_frequencies_hz.size > 1:
            centre_hz = 0.5 * (profile.band_frequencies_hz[0] + profile.band_frequencies_hz[-1])
        elif profile.reference_frequency_hz is not None:
            centre_hz = profile.reference_frequency_hz
        else:
            raise EstimatorInputError("required for a profile without a reference frequency or band", "centre_hz")
    fc = finite_float(centre_hz, "centre_hz", positive=True)
    if bandwidth_hz is None:
        bf = profile.band_frequencies_hz
        if bf is None or bf.size < 2:
            raise EstimatorInputError("required for a profile without a band of its own", "bandwidth_hz")
        bandwidth_hz = 2.0 * min(fc - bf[0], bf[-1] - fc)
        if not bandwidth_hz > 0:
            raise EstimatorInputError(f"centre {fc:.6g} Hz is not inside the profile's band", "centre_hz")
    w = finite_float(bandwidth_hz, "bandwidth_hz", positive=True)
    if w < MIN_RATE_HZ:
        raise EstimatorInputError(f"must be at least {MIN_RATE_HZ:g} Hz (taps 1 / W apart), got {w:g}", "bandwidth_hz")
    if w >= 2.0 * fc:
        raise EstimatorInputError(f"must be below twice the centre frequency ({2 * fc:.6g} Hz)", "bandwidth_hz")
    return fc, w


def cir(profile: PathProfile, sample_rate_hz: float, *, bandwidth_hz: float | None = None,
        centre_hz: float | None = None, start_s: float = 0.0, num_samples: int | None = None,
        normalize_delays: bool = False, extrapolate: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(S28) the baseband impulse response h(t) [1/s] sampled at ``sample_rate_hz``.

    The band is ``centre_hz +- bandwidth_hz / 2``: by default the centre of the profile's
    band (else its reference frequency) and the widest band around it the profile's band
    gains cover (required without band gains). Samples are at t_n = start_s + n / fs,
    n = 0..num_samples-1 (default: up to 8 / bandwidth after the last path), on the absolute
    time axis (or, ``normalize_delays``, relative to the first path's phase delay). A band
    beyond the profile's band gains raises (field ``bandwidth_hz``) unless ``extrapolate``
    (their first-order continuation). Returns (times_s, h).
    """
    profile = _check_profile(profile)
    fs = finite_float(sample_rate_hz, "sample_rate_hz", positive=True)
    if fs < MIN_RATE_HZ:
        raise EstimatorInputError(f"must be at least {MIN_RATE_HZ:g} Hz, got {fs:g}", "sample_rate_hz")
    fc, w = _centre_and_band(profile, centre_hz, bandwidth_hz)
    t0 = finite_float(start_s, "start_s")
    origin = _time_origin(profile, normalize_delays)
    if num_samples is None:
        end = float(profile.delays_s.max()) - origin + 8.0 / w
        num_samples = max(1, int(math.ceil((end - t0) * fs)) + 1)
    if isinstance(num_samples, bool) or not isinstance(num_samples, (int, np.integer)) or num_samples < 1:
        raise EstimatorInputError(f"must be a positive integer, got {num_samples!r}", "num_samples")
    if num_samples > MAX_OUTPUT_SAMPLES:
        raise EstimatorInputError(f"{num_samples} samples exceed the cap of {MAX_OUTPUT_SAMPLES}: lower "
                                  "sample_rate_hz or give num_samples", "num_samples")
    times = t0 + np.arange(int(num_samples)) / fs
    return times, _band_limited(profile, times + origin, fc, fc - w / 2.0, fc + w / 2.0, extrapolate)


def taps(profile: PathProfile, bandwidth_hz: float, *, centre_hz: float | None = None, l_min: int | None = None,
         l_max: int | None = None, normalize_delays: bool = False,
         extrapolate: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(S29) discrete taps h_l = h(l / W) / W at bandwidth W = ``bandwidth_hz`` around ``centre_hz``
    (default: the profile's band centre, else its reference frequency).

    Tap l is the delay l / W, absolute (tap 0 at emission) unless ``normalize_delays``. By
    default l runs from floor(W tau_first) - 6 to ceil(W tau_last) + 6 (the sinc's first six
    side lobes either side). Returns (tap indices l, h_l).
    """
    profile = _check_profile(profile)
    fc, w = _centre_and_band(profile, centre_hz, bandwidth_hz)
    origin = _time_origin(profile, normalize_delays)
    if l_min is None:
        l_min = int(math.floor(w * (profile.first_path_delay_s - origin))) - 6
    if l_max is None:
        l_max = int(math.ceil(w * (float(profile.delays_s.max()) - origin))) + 6
    for name, value in (("l_min", l_min), ("l_max", l_max)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise EstimatorInputError(f"must be an integer, got {value!r}", name)
    if l_max < l_min:
        raise EstimatorInputError(f"must be >= l_min ({l_min}), got {l_max}", "l_max")
    if l_max - l_min + 1 > MAX_OUTPUT_SAMPLES:
        raise EstimatorInputError(f"{l_max - l_min + 1} taps exceed the cap of {MAX_OUTPUT_SAMPLES}", "l_max")
    ell = np.arange(int(l_min), int(l_max) + 1)
    return ell, _band_limited(profile, ell / w + origin, fc, fc - w / 2.0, fc + w / 2.0, extrapolate) / w
