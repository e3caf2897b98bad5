"""Phase-difference-of-arrival ranging (thesis Eq 5.1-5.6), two tones or N-tone regression.

The measured quantity is the channel's phasor at each tone, H(f_i) from
:meth:`PathProfile.frequency_response` (H(f) = sum_k a_k exp(-j 2 pi f tau_k)),
so a single path of delay tau has phase -2 pi f tau (Eq 5.2, up to whole
cycles and the gain's own phase, which cancels in differences).

Two tones (Eq 5.3-5.5): with phi_i = -arg H(f_i) the phase lag of tone i
(Eq 5.2), d = v / (2 pi) * (phi2 - phi1) / (f2 - f1), the phase difference
taken in [0, 2 pi); the estimate lies in [0, v / (f2 - f1)),
the maximum unambiguous range (2.84 m for 20 MHz at eps_r 27.9). A true
distance beyond it WRAPS (aliases to d mod v / (f2 - f1)); the result says so.

Regression over N equally spaced tones (spacing df): the delay is minus the
slope of the unwrapped phase against frequency over 2 pi. Unwrapping is made
robust by first taking a coarse delay tau0 from the mean adjacent-tone phasor
product sum_i H_{i+1} conj(H_i) (tau0 in [0, 1/df)), derotating every tone by
exp(+j 2 pi f_i tau0), unwrapping the small residual phase and fitting it by
least squares (free intercept: the gain's phase is a nuisance); tau = tau0 +
residual slope. Unambiguous range v / df.

Noise (per trial, per tone): each tone's phasor is observed as
H_i + n_i, n_i ~ CN(0, sigma^2) independent, with

    sigma^2 = sum_i |H_i|^2 / (SNR W T0),

W = f_max - f_min the occupied band, T0 = ``duration_s`` (default 1/W, the
thesis' W T0 = 1), SNR the in-band ratio of Eq 5.16. This is what a receiver
gets by correlating each of the equal-power transmitted tones over T0 in
white noise of PSD N0/2 with E/N0 = SNR W T0 (total received energy E):
sigma^2 = 2 N0 / T0 per tone, giving a per-tone phase variance of
1 / (2 E_i / N0). With this model the two-tone estimator's spread equals
the phase-difference bound of bounds.pdoa_crlb at high SNR (it is efficient),
and the bound's E/N0 means the same thing as the simulation's.

Statistics are circular: the mean delay is the circular mean over the
ambiguity interval, and the spread is taken from each estimate's deviation
wrapped to +-half the interval, so estimates straddling the wrap point
(distance near 0 or near the maximum range) do not fake a metre of spread.
``wrapped`` is set when a given true distance is at or beyond the maximum
unambiguous range, when trials reach past that range (the distance sits at
its far edge and some trials alias to near zero), or when the circular mean
falls in the top quarter of the range, which is reported as a short
(possibly slightly negative) distance -- the likelier reading in-body -- and
flagged as ambiguous.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from ._checks import Check, checkpoint, finite_float
from ._montecarlo import MonteCarloInputs
from .bounds import multitone_crlb, pdoa_crlb
from .constants import DEFAULT_RELATIVE_PERMITTIVITY
from .errors import EstimatorInputError
from .link import LinkBudget, make_link
from .profile import PathProfile
from .results import PDOAResult, summarise

METHODS = ("two_tone", "regression")
MAX_TONES = 4096
_CHUNK_ELEMENTS = 1 << 20  # trials x tones processed at once


def band_frequencies(band: Mapping | Sequence) -> np.ndarray:
    """Frequencies of ``band = {"start_hz", "stop_hz", "points"}`` (inclusive, equally spaced)."""
    if isinstance(band, Mapping):
        try:
            start, stop, points = band["start_hz"], band["stop_hz"], band["points"]
        except KeyError as exc:
            raise EstimatorInputError(f"missing {exc.args[0]!r}", "band") from None
    else:
        raise EstimatorInputError("must be an object {start_hz, stop_hz, points}", "band")
    start = finite_float(start, "band.start_hz", positive=True)
    stop = finite_float(stop, "band.stop_hz", positive=True)
    if stop <= start:
        raise EstimatorInputError(f"must exceed start_hz ({start:.6g}), got {stop:.6g}", "band.stop_hz")
    if isinstance(points, bool) or not isinstance(points, (int, np.integer)) or not 2 <= points <= MAX_TONES:
        raise EstimatorInputError(f"must be an integer in [2, {MAX_TONES}], got {points!r}", "band.points")
    return np.linspace(start, stop, int(points))


def _frequencies(method: str, frequencies_hz, band, profile: PathProfile) -> np.ndarray:
    if frequencies_hz is not None and band is not None:
        raise EstimatorInputError("give exactly one of frequencies_hz or band", "frequencies_hz")
    if frequencies_hz is None and band is None:
        if profile.band_frequencies_hz is None:
            raise EstimatorInputError("give frequencies_hz or band (the profile has no band of its own to default to)",
                                      "frequencies_hz")
        frequencies_hz = profile.band_frequencies_hz  # the profile's own band (docs/api.md)
        if method == "two_tone":
            frequencies_hz = frequencies_hz[[0, -1]] if frequencies_hz.size > 1 else frequencies_hz
    if band is not None:
        f = band_frequencies(band)
        field = "band"
    else:
        try:
            f = np.asarray(frequencies_hz, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise EstimatorInputError("must be a list of numbers", "frequencies_hz") from None
        field = "frequencies_hz"
        if not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise EstimatorInputError("must be finite and > 0", field)
        if f.size > MAX_TONES:
            raise EstimatorInputError(f"at most {MAX_TONES} tones", field)
    if method == "two_tone":
        if band is not None:
            f = f[[0, -1]]
        if f.size != 2:
            raise EstimatorInputError(f"two_tone needs exactly two frequencies [f1, f2], got {f.size}", field)
        if f[1] <= f[0]:
            raise EstimatorInputError(f"need f2 > f1, got f1={f[0]:.6g} Hz, f2={f[1]:.6g} Hz", field)
        return f
    if f.size < 2:
        raise EstimatorInputError("regression needs at least two frequencies", field)
    df = np.diff(f)
    if np.any(df <= 0):
        raise EstimatorInputError("must be strictly increasing", field)
    if np.max(np.abs(df - df.mean())) > 1e-6 * df.mean():
        raise EstimatorInputError("regression needs equally spaced tones", field)
    return f


def _two_tone_delays(h: np.ndarray, f: np.ndarray) -> np.ndarray:
    dphi = np.angle(h[:, 1] * np.conj(h[:, 0]))  # phi2 - phi1, in (-pi, pi]
    return np.mod(-dphi, 2.0 * math.pi) / (2.0 * math.pi * (f[1] - f[0]))


def _regression_delays(h: np.ndarray, f: np.ndarray) -> np.ndarray:
    df = f[1] - f[0]
    period = 1.0 / df
    z = np.sum(h[:, 1:] * np.conj(h[:, :-1]), axis=1)
    tau0 = np.mod(-np.angle(z), 2.0 * math.pi) / (2.0 * math.pi * df)
    resid = h * np.exp(2j * math.pi * f[None, :] * tau0[:, None])
    psi = np.unwrap(np.angle(resid), axis=1)
    fc = f - f.mean()
    slope = (psi @ fc) / np.dot(fc, fc)
    return np.mod(tau0 - slope / (2.0 * math.pi), period)


def _circular(delays: np.ndarray, period: float) -> tuple[np.ndarray, str | None]:
    """Estimates unwrapped around their circular mean, and why they look wrapped (or None).

    The circular mean is placed in [0, period), except that a mean within
    w = min(3 circular standard deviations, period / 4) below ``period`` is read
    as a short distance seen through noise and moved below zero (the ranges
    this tool configures are far longer than in-body distances); that case is
    flagged. Unwrapped estimates lie within +-period/2 of the mean; some below 0
    are just noise around a short distance, some at or above ``period`` mean
    trials that aliased across the far edge (also flagged).
    """
    resultant = np.mean(np.exp(2j * math.pi * delays / period))
    mean = np.mod(np.angle(resultant) * period / (2.0 * math.pi), period)
    length = min(1.0, float(np.abs(resultant)))
    spread = math.sqrt(-2.0 * math.log(length)) * period / (2.0 * math.pi) if length > 0 else math.inf
    if mean >= period - min(3.0 * spread, 0.25 * period):
        mean -= period
    dev = delays - mean
    dev -= period * np.round(dev / period)
    unwrapped = mean + dev
    if mean < 0.0:
        return unwrapped, ("the mean phase points just below zero distance: either a very short distance "
                           "seen through noise, or a distance at or beyond the maximum unambiguous range "
                           "that aliased (reported as the short one)")
    if np.any(unwrapped >= period):
        return unwrapped, ("the distance is at the far edge of the maximum unambiguous range: some trials "
                           "alias to near zero (statistics are taken circularly)")
    return unwrapped, None


def estimate_pdoa(profile: PathProfile, frequencies_hz=None, band=None, method: str = "two_tone",
                  snr_db: float | None = 30.0, trials: int = 100, seed=0,
                  relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY,
                  true_distance_m: float | None = None, duration_s: float | None = None,
                  return_estimates: bool = False, link: LinkBudget | Mapping | None = None,
                  check: Check = None) -> PDOAResult:
    """Monte Carlo PDOA ranging over ``profile`` (docs/api.md POST /v1/ranging/pdoa).

    Args:
        profile: the channel (its frequency response is evaluated at the tones).
        frequencies_hz: ``[f1, f2]`` (two_tone) or an equally spaced list (regression);
            or ``band={"start_hz", "stop_hz", "points"}`` (two_tone uses its two ends).
            Neither: the profile's own band frequencies (two_tone: its two ends).
        method: ``two_tone`` | ``regression``.
        snr_db: in-band SNR (see module docstring); None = noiseless.
        trials (1..10000), seed (int >= 0 or Generator), relative_permittivity,
        true_distance_m (adds error_m / rmse_m and the wrap check), duration_s (T0,
        default 1 / bandwidth), return_estimates.
        link: a :class:`~estimators.link.LinkBudget` (or its dict) instead of ``snr_db``: the
            in-band SNR is then (S24) from the profile's own path gain over the tones' span
            W unless the link gives a bandwidth; ``snr_db`` is ignored.
        check: called between chunks of trials; raises to stop (``estimators._checks.Check``).
    """
    if not isinstance(profile, PathProfile):
        raise EstimatorInputError("must be a PathProfile", "profile")
    if method not in METHODS:
        raise EstimatorInputError(f"unknown method {method!r} (two_tone | regression)", "method")
    f = _frequencies(method, frequencies_hz, band, profile)
    link = make_link(link)
    if link is not None:
        snr_db = link.snr_db(profile.path_gain_db, float(f[-1] - f[0]))
    mc = MonteCarloInputs(snr_db, trials, seed, relative_permittivity, true_distance_m, from_link=link is not None)
    snr, n_trials, rng, eps, v = mc.snr_db, mc.trials, mc.rng, mc.relative_permittivity, mc.velocity_m_per_s
    true_distance_m = mc.true_distance_m
    width = float(f[-1] - f[0])
    t0 = 1.0 / width if duration_s is None else finite_float(duration_s, "duration_s", positive=True)

    h = profile.frequency_response(f, normalise=True)  # scale-free: immune to extreme gains
    power = float(np.sum(np.abs(h) ** 2))
    if not power > 0.0:
        raise EstimatorInputError("the channel response is zero at every tone (paths cancel exactly)",
                                  "profile.paths.gain")
    sigma = None if snr is None else math.sqrt(power / (10.0 ** (snr / 10.0) * width * t0) / 2.0)
    estimator = _two_tone_delays if method == "two_tone" else _regression_delays
    period = 1.0 / width if method == "two_tone" else 1.0 / float(f[1] - f[0])
    delays = np.empty(n_trials)
    chunk = max(1, _CHUNK_ELEMENTS // f.size)  # bounded memory; the noise stream is the same as one draw
    for start in range(0, n_trials, chunk):
        checkpoint(check)
        count = min(chunk, n_trials - start)
        obs = np.broadcast_to(h, (count, f.size)).copy()
        if sigma is not None:
            obs += sigma * (rng.standard_normal((count, f.size, 2)) @ np.array([1.0, 1.0j]))
        delays[start:start + count] = estimator(obs, f)
    max_range = v * period
    unwrapped, edge_reason = _circular(delays, period)
    dist = v * unwrapped
    stats = summarise(dist, true_distance_m)

    reason = None
    if true_distance_m is not None and true_distance_m >= max_range:
        reason = (f"true distance {true_distance_m:.6g} m is beyond the maximum unambiguous range "
                  f"{max_range:.6g} m: the estimate aliases to the distance modulo that range")
    else:
        reason = edge_reason

    crlb = crlb_pd = None
    if snr is not None:
        if method == "two_tone":
            b = pdoa_crlb(0.5 * (f[0] + f[1]), width, snr, t0, eps)
        else:
            b = multitone_crlb(f, snr, t0, eps)
        crlb, crlb_pd = b.sigma_m, b.sigma_phase_difference_m
    return PDOAResult(method=method, distance_m=stats.distance_m, delay_s=float(np.mean(unwrapped)),
                      std_m=stats.std_m, error_m=stats.error_m, rmse_m=stats.rmse_m, crlb_m=crlb,
                      crlb_phase_difference_m=crlb_pd, max_unambiguous_range_m=max_range,
                      wrapped=reason is not None, wrap_reason=reason, trials=n_trials, frequencies_hz=f,
                      estimates_m=dist if return_estimates else None, snr_db=snr,
                      channel_model=profile.channel_model)
