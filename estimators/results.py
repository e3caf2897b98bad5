"""Result dataclasses of the ranging estimators and their Monte Carlo statistics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class RangingStats:
    """Statistics of ``trials`` distance estimates (metres).

    distance_m: mean estimate; std_m: sample standard deviation (ddof=1, 0 for
    one trial); error_m: mean - true distance (signed bias); rmse_m: sqrt of
    the mean squared error against the true distance. error/rmse are None
    without a true distance.
    """

    distance_m: float
    std_m: float
    error_m: float | None
    rmse_m: float | None


def summarise(estimates_m: np.ndarray, true_distance_m: float | None) -> RangingStats:
    est = np.asarray(estimates_m, dtype=float)
    mean = float(np.mean(est))
    std = float(np.std(est, ddof=1)) if est.size > 1 else 0.0
    if true_distance_m is None:
        return RangingStats(mean, std, None, None)
    err = est - true_distance_m
    return RangingStats(mean, std, float(mean - true_distance_m), float(np.sqrt(np.mean(err ** 2))))


@dataclass(frozen=True)
class TOAResult:
    """One TOA method's Monte Carlo outcome (docs/api.md ranging response).

    delay_s is the mean delay estimate; distance_m = v * delay_s.
    crlb_m is the TOA bound (Eq 4.16-4.17) for the same waveform, SNR and
    sampling (W = fs / 2); None when noiseless. snr_db is the per-sample SNR
    the trials ran at (from the request, or from its link budget; None when
    noiseless). channel_model names how the waveform went through the
    channel (estimators.profile: ``band_gains``, ``group_delay`` or
    ``non_dispersive``); band_coverage is the share of the transmitted
    waveform's energy inside the profile's band (``band_gains`` only; the
    rest went through the first-order continuation of the band gains).
    """

    method: str
    distance_m: float
    delay_s: float
    std_m: float
    error_m: float | None
    rmse_m: float | None
    crlb_m: float | None
    trials: int
    estimates_m: np.ndarray | None = field(default=None, repr=False, compare=False)
    snr_db: float | None = None
    channel_model: str = "non_dispersive"
    band_coverage: float | None = None


@dataclass(frozen=True)
class PDOAResult:
    """PDOA Monte Carlo outcome.

    max_unambiguous_range_m: v / (f2 - f1) for two tones, v / (tone spacing)
    for regression. wrapped: True when the true distance (if given) is at or
    beyond that range, or when trial estimates (unwrapped around their
    circular mean) reach past it, i.e. the phase ambiguity has bitten;
    ``wrap_reason`` says which. crlb_m is the
    full two-tone / multi-tone bound (Eq 5.16, carrier term included, carrier
    ambiguity assumed resolved); crlb_phase_difference_m the bound of an
    estimator that only uses phase differences (the W^2/4 term) -- the one
    this estimator should approach. snr_db is the in-band SNR the trials ran
    at (request or link budget); channel_model how H(f) was evaluated at the
    tones (estimators.profile).
    """

    method: str
    distance_m: float
    delay_s: float
    std_m: float
    error_m: float | None
    rmse_m: float | None
    crlb_m: float | None
    crlb_phase_difference_m: float | None
    max_unambiguous_range_m: float
    wrapped: bool
    wrap_reason: str | None
    trials: int
    frequencies_hz: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.empty(0))
    estimates_m: np.ndarray | None = field(default=None, repr=False, compare=False)
    snr_db: float | None = None
    channel_model: str = "non_dispersive"


@dataclass(frozen=True)
class RSSResult:
    """RSS (CM2 path-loss inversion) Monte Carlo outcome.

    path_loss_db: the deterministic path loss that was inverted (before
    shadowing). distance_m: mean of the inverted distances over trials;
    median_distance_m: the inversion without shadowing (the lognormal
    estimator's median). crlb_m = ln(10) sigma / (10 n) d at d = the true
    distance (or the median estimate without one).
    """

    method: str
    model: str
    distance_m: float
    median_distance_m: float
    path_loss_db: float
    std_m: float
    error_m: float | None
    rmse_m: float | None
    crlb_m: float
    trials: int
    estimates_m: np.ndarray | None = field(default=None, repr=False, compare=False)
