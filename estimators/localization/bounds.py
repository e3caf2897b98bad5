"""Position Cramér-Rao bounds and dilution of precision (docs/localization.md, "Bounds").

Measurements m_i = h_i(theta) + e_i, e_i ~ N(0, sigma_i^2) independent, theta = (x, extra):
the Fisher information is F = H^T diag(sigma^-2) H with H_ij = d h_i / d theta_j, and
Cov(theta_hat) >= F^-1 for any unbiased estimator. The position bound is the (3, 3) block
of F^-1 (nuisance parameters eliminated, which is what inverting the full F does).

* constant velocity, ranges r_i = |x - s_i|: the rows of H are the unit vectors
  u_i = (x - s_i) / |x - s_i|;
* joint velocity, delays tau_i = p |x - s_i| with slowness p = 1 / v: rows (p u_i, d_i);
* model-based, delays tau_i = T_i(x): rows grad T_i(x), the travel-time gradients;
* RSS (log-normal path loss in dB, PL_i = PL0 + 10 n log10(d_i / d0) + S_i, S_i ~ N(0,
  sigma_dB^2)): rows 10 n / (ln 10 d_i) u_i with sigma_dB.

GDOP/PDOP are the bounds for unit sigma on ranges (delays are scaled by the velocity):
PDOP = sqrt(trace of the position block of (H^T H)^-1), GDOP = sqrt(trace of all of it).
Symmetric oracle: 6 sensors on the axes, equidistant from x: H^T H = 2 I, so
sigma_x = sigma sqrt(1/2) and PDOP = sqrt(3/2).
"""

from __future__ import annotations

import numpy as np

from ..errors import EstimatorInputError
from .results import PositionBound


def bound_from_jacobian(jacobian: np.ndarray, sigma: np.ndarray, dop_jacobian: np.ndarray | None = None,
                        *, field: str = "sensors") -> PositionBound:
    """PositionBound from the (N, P) measurement Jacobian (first three columns: position),
    the per-measurement sigmas (same unit as the measurements), and optionally the Jacobian
    in range units for the DOPs (default: ``jacobian``)."""
    h = np.asarray(jacobian, float)
    w = 1.0 / np.asarray(sigma, float)
    cov = _inverse_information(h * w[:, None], field)
    hd = h if dop_jacobian is None else np.asarray(dop_jacobian, float)
    dop = _inverse_information(hd, field)
    pos = cov[:3, :3]
    return PositionBound(covariance_m2=pos, sigma_m=np.sqrt(np.clip(np.diag(pos), 0.0, None)),
                         rms_m=float(np.sqrt(max(np.trace(pos), 0.0))),
                         gdop=float(np.sqrt(max(np.trace(dop), 0.0))),
                         pdop=float(np.sqrt(max(np.trace(dop[:3, :3]), 0.0))))


def _inverse_information(weighted_jacobian: np.ndarray, field: str) -> np.ndarray:
    """(J^T J)^-1, computed with unit-norm columns (parameters of different units, metres
    and seconds per metre, would otherwise fake an ill-conditioned matrix)."""
    norms = np.linalg.norm(weighted_jacobian, axis=0)
    if np.any(norms == 0.0):
        raise EstimatorInputError("the measurements do not depend on every parameter here", field)
    scaled = weighted_jacobian / norms
    info = scaled.T @ scaled
    # a singular Fisher matrix means the geometry does not determine the position
    if np.linalg.cond(info) > 1e12:
        raise EstimatorInputError("the sensor geometry does not determine the position at this point "
                                  "(singular Fisher information)", field)
    return np.linalg.inv(info) / np.outer(norms, norms)


def unit_vectors(sensors_m: np.ndarray, position_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) unit vectors from each sensor towards ``position_m`` and the (N,) distances."""
    diff = np.asarray(position_m, float)[None, :] - np.asarray(sensors_m, float)
    d = np.linalg.norm(diff, axis=1)
    if np.any(d < 1e-12):
        raise EstimatorInputError("the position coincides with a sensor: its unit vector is undefined",
                                  "position_m")
    return diff / d[:, None], d


def range_crlb(sensors_m, position_m, sigma_m) -> PositionBound:
    """Bound for ranges with known, constant velocity (rows: unit vectors)."""
    u, _ = unit_vectors(sensors_m, position_m)
    return bound_from_jacobian(u, np.broadcast_to(np.asarray(sigma_m, float), (len(u),)))


def joint_velocity_crlb(sensors_m, position_m, velocity_m_per_s: float, sigma_s) -> PositionBound:
    """Bound for delays with an unknown velocity (parameters x and slowness p = 1/v)."""
    u, d = unit_vectors(sensors_m, position_m)
    p = 1.0 / float(velocity_m_per_s)
    jac = np.column_stack([p * u, d])
    sigma = np.broadcast_to(np.asarray(sigma_s, float), (len(u),))
    # DOPs in range units: multiply delays by v; the slowness column then scales by v, and
    # is expressed in metres by the mean range (dp * v * mean d is a range offset)
    dop = np.column_stack([u, d / np.mean(d)])
    return bound_from_jacobian(jac, sigma, dop)


def travel_time_crlb(gradients_s_per_m: np.ndarray, sigma_s) -> PositionBound:
    """Bound for delays modelled by travel-time fields (rows: grad T_i at the position).
    DOPs in range units: gradients scaled to unit length (the local propagation direction)."""
    g = np.asarray(gradients_s_per_m, float)
    sigma = np.broadcast_to(np.asarray(sigma_s, float), (len(g),))
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return bound_from_jacobian(g, sigma, g / np.where(norm > 0, norm, 1.0))


def rss_position_crlb(sensors_m, position_m, exponent: float, shadowing_db) -> PositionBound:
    """Bound for path losses in dB under log-normal shadowing (rows: 10 n / (ln 10 d_i) u_i)."""
    u, d = unit_vectors(sensors_m, position_m)
    jac = (10.0 * float(exponent) / (np.log(10.0) * d))[:, None] * u
    return bound_from_jacobian(jac, np.broadcast_to(np.asarray(shadowing_db, float), (len(u),)), u)
