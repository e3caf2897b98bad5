"""Errors of a track against the truth: RMSE along the tract and in 3-D, the normalised estimation
error squared, and the consistency bands of averaged NEES / NIS (docs/tracking.md, "Consistency")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from .measurements import Track

__all__ = ["ConsistencyBand", "average_band", "integrated_autocorrelation", "nees", "rmse_3d_m", "rmse_along_m"]


def rmse_along_m(track: Track, true_s_m: np.ndarray) -> float:
    """sqrt(mean_k (s_hat_k - s_k)^2) [m]: the error along the tract."""
    return float(np.sqrt(np.mean((track.s_m - np.asarray(true_s_m)) ** 2)))


def rmse_3d_m(track: Track, true_position_m: np.ndarray) -> float:
    """sqrt(mean_k |x_hat_k - x_k|^2) [m]: the error of the reported 3-D point."""
    d = track.position_m - np.asarray(true_position_m)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def nees(track: Track, true_s_m: np.ndarray, true_v_m_per_s: np.ndarray | None = None,
         true_roll_deg: np.ndarray | None = None) -> np.ndarray:
    """Normalised estimation error squared per step, e^T P^-1 e (Bar-Shalom, Li & Kirubarajan 2001,
    Eq 5.4.2-1), over the state components given (s always; v and roll when their truth is given),
    from the Kalman filter's ``extra["state_covariance"]``. Chi-square with that many degrees of
    freedom when the filter is consistent."""
    P = track.extra["state_covariance"]
    comps = [0] + ([1] if true_v_m_per_s is not None else []) + ([2] if true_roll_deg is not None else [])
    est = np.stack([track.s_m, track.v_m_per_s, track.roll_deg], axis=1)[:, comps]
    truth = [np.asarray(true_s_m)] + ([np.asarray(true_v_m_per_s)] if true_v_m_per_s is not None else []) \
        + ([np.asarray(true_roll_deg)] if true_roll_deg is not None else [])
    e = est - np.stack(truth, axis=1)
    Ps = P[:, comps][:, :, comps]
    return np.einsum("ki,ki->k", e, np.linalg.solve(Ps, e[..., None])[..., 0])


def integrated_autocorrelation(series: np.ndarray, window_factor: float = 5.0) -> float:
    """Integrated autocorrelation time tau = 1 + 2 sum_k rho_k of a stationary series, with Sokal's
    automatic window (the smallest lag M with M >= window_factor tau(M)); 1 for white noise. The
    variance of the series' mean is tau var / n, so n / tau samples are worth independent ones."""
    x = np.asarray(series, float)
    x = x[np.isfinite(x)]
    n = len(x)
    if n < 4 or np.var(x) == 0.0:
        return 1.0
    d = x - x.mean()
    f = np.fft.rfft(d, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    tau = 1.0
    for m in range(1, n):
        tau = 1.0 + 2.0 * float(acf[1:m + 1].sum())
        if m >= window_factor * tau:
            break
    return max(tau, 1.0)


@dataclass(frozen=True)
class ConsistencyBand:
    """The average of a normalised error over ``samples`` values (``effective`` of them independent)
    against the two-sided ``probability`` band of a consistent filter: chi-square(effective x dof)
    / effective (Bar-Shalom, Li & Kirubarajan 2001, Sec 5.4.2). ``inside`` says whether it is in."""

    average: float
    lower: float
    upper: float
    dof: int
    samples: int
    effective: float

    @property
    def inside(self) -> bool:
        return self.lower <= self.average <= self.upper

    def to_dict(self) -> dict:
        return {"average": self.average, "lower": self.lower, "upper": self.upper, "dof": self.dof,
                "samples": self.samples, "effective": self.effective, "inside": self.inside}


def average_band(runs: list[np.ndarray], dof: int, probability: float = 0.95,
                 correlated: bool | str = True) -> ConsistencyBand:
    """The average of the finite values of ``runs`` (one array per Monte Carlo run, e.g. a track's
    NEES per step or its NIS at the steps with a measurement) and its band (:class:`ConsistencyBand`).
    ``correlated``: False for values that a consistent filter makes independent (innovations: NIS);
    True when the values within a run are autocorrelated (NEES: the estimation error of successive
    steps) and each run counts n / tau values (:func:`integrated_autocorrelation`); ``"runs"`` when a
    run's values may share one error for its whole length (a prior draw or a body bias that the run
    never averages away): each run counts as one value, the widest and safest band."""
    values = [np.asarray(r, float)[np.isfinite(np.asarray(r, float))] for r in runs]
    values = [v for v in values if len(v)]
    if not values:
        nan = float("nan")
        return ConsistencyBand(nan, nan, nan, int(dof), 0, 0.0)
    total = sum(len(v) for v in values)
    if correlated == "runs":
        effective = float(len(values))
    else:
        effective = sum(len(v) / (integrated_autocorrelation(v) if correlated else 1.0) for v in values)
    k = effective * dof
    tail = 0.5 * (1.0 - probability)
    return ConsistencyBand(float(np.mean(np.concatenate(values))), float(chi2.ppf(tail, k) / effective),
                           float(chi2.ppf(1.0 - tail, k) / effective), int(dof), int(total), float(effective))
