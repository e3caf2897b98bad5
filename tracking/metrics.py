"""Errors of a track against the truth: RMSE along the tract and in 3-D, the normalised estimation
error squared (docs/tracking.md, "Evaluation")."""

from __future__ import annotations

import numpy as np

from .measurements import Track

__all__ = ["nees", "rmse_3d_m", "rmse_along_m"]


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
