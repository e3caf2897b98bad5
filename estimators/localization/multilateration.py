"""Multilateration from ranges or delays with a constant propagation velocity
(docs/localization.md, "Estimators").

* :func:`linear_fix` -- closed form. Squaring r_i = |x - s_i| and subtracting the mean
  equation removes |x|^2:  2 (s_i - s_bar)^T x = (|s_i|^2 - mean |s|^2) - (r_i^2 - mean r^2),
  solved by (weighted) least squares. Exact for noiseless ranges; it starts the others.
* :func:`nonlinear_fix` -- weighted nonlinear least squares, min sum rho(((r_i - |x - s_i|)
  / sigma_i)^2) (scipy.optimize.least_squares, trust region; rho a robust loss on request).
* :func:`joint_velocity_fix` -- delays tau_i with an unknown effective velocity v: min
  sum ((tau_i - p |x - s_i|) / sigma_i)^2 over x and the slowness p = 1/v. Started from
  the closed form |x - s_i|^2 = v^2 tau_i^2, linear in (x, |x|^2, v^2) after expanding:
  -2 s_i^T x + |x|^2 - v^2 tau_i^2 = -|s_i|^2 (five unknowns: at least five sensors).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import least_squares

from .._checks import finite_float
from ..constants import SPEED_OF_LIGHT_M_PER_S, velocity_m_per_s
from ..errors import EstimatorInputError
from . import _validate as check
from .bounds import (
    _inverse_information,
    bound_from_jacobian,
    joint_velocity_crlb,
    range_crlb,
    unit_vectors,
)
from .results import PositionResult

#: Solver tolerances (relative, scipy.optimize.least_squares) and its evaluation cap.
TOLERANCE = 1e-12
MAX_EVALUATIONS = 200


def _ranges(sensors_m, ranges_m, sigma_m, *, minimum: int = 4):
    s = check.sensor_positions(sensors_m, minimum=minimum)
    r = check.per_sensor(ranges_m, len(s), "ranges_m", nonnegative=True)
    sig = check.per_sensor(1.0 if sigma_m is None else sigma_m, len(s), "sigma_m", positive=True)
    return s, r, sig


def linear_fix(sensors_m: Any, ranges_m: Any, sigma_m: Any = None, *, weighted: bool = True) -> PositionResult:
    """Closed-form least-squares position from ranges (module docstring).

    ``sigma_m`` (per sensor or scalar, default 1 m) weights the differenced equations by
    the inverse of their first-order variance (Var(r_i^2) = 4 r_i^2 sigma_i^2, the
    centring's correlations included) when ``weighted``. The covariance is that variance
    propagated through the solution. Raises EstimatorInputError (``sensors``,
    ``ranges_m``, ``sigma_m``) for fewer than 4 sensors, duplicates, coplanar sets, NaN
    or negative values.
    """
    s, r, sig = _ranges(sensors_m, ranges_m, sigma_m)
    x, cov = _linear_solution(s, r, sig, weighted)
    return _result("linear", s, r, sig, x, cov, iterations=0, converged=True, message="closed form")


def _linear_solution(s, r, sig, weighted):
    n = len(s)
    centre = np.eye(n) - 1.0 / n  # subtract the mean equation
    a = 2.0 * centre @ s
    sq = np.einsum("ij,ij->i", s, s)
    b = centre @ (sq - r**2)
    # d b / d r = -2 centre diag(r); Cov(b) = centre diag(4 r^2 sigma^2) centre (rank n - 1)
    g = -2.0 * centre * r[None, :]
    cov_b = (g * sig[None, :] ** 2) @ g.T
    if weighted and np.all(r > 0):
        # the generalised inverse of the rank-deficient Cov(b) gives the BLUE on its range
        w = np.linalg.pinv(cov_b, rcond=1e-12, hermitian=True)
    else:
        w = np.eye(n)
    normal = a.T @ w @ a
    x = np.linalg.solve(normal, a.T @ w @ b)
    k = np.linalg.solve(normal, a.T @ w)
    return x, k @ cov_b @ k.T


def nonlinear_fix(sensors_m: Any, ranges_m: Any, sigma_m: Any = None, *, initial_position_m: Any = None,
                  loss: str = "linear", loss_scale: float = 1.0) -> PositionResult:
    """Weighted nonlinear least squares on ranges (module docstring).

    Residuals (r_i - |x - s_i|) / sigma_i; ``loss`` is scipy's robust loss ("linear" |
    "soft_l1" | "huber" | "cauchy" | "arctan") with scale ``loss_scale`` in units of sigma.
    Started from ``initial_position_m`` or else :func:`linear_fix`. covariance_m2 is the
    inverse Fisher information at the estimate.
    """
    s, r, sig = _ranges(sensors_m, ranges_m, sigma_m)
    loss = check.loss_name(loss)
    scale = finite_float(loss_scale, "loss_scale", positive=True)
    x0 = (_linear_solution(s, r, sig, True)[0] if initial_position_m is None
          else check.position(initial_position_m, "initial_position_m"))

    def fun(x):
        return (r - np.linalg.norm(x - s, axis=1)) / sig

    def jac(x):
        diff = x - s
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        return -(diff / d[:, None]) / sig[:, None]

    sol = least_squares(fun, x0, jac=jac, method="trf", loss=loss, f_scale=scale, xtol=TOLERANCE,
                        ftol=TOLERANCE, gtol=TOLERANCE, max_nfev=MAX_EVALUATIONS)
    bound = range_crlb(s, sol.x, sig)
    return _result("nonlinear", s, r, sig, sol.x, bound.covariance_m2, iterations=int(sol.nfev),
                   converged=bool(sol.status > 0), message=str(sol.message), bound=bound)


def joint_velocity_fix(sensors_m: Any, delays_s: Any, sigma_s: Any = None, *, initial_position_m: Any = None,
                       initial_velocity_m_per_s: float | None = None, loss: str = "linear",
                       loss_scale: float = 1.0) -> PositionResult:
    """Position and effective propagation velocity from delays (module docstring).

    Needs at least 5 sensors. ``sigma_s`` per-delay sigmas (default 1 ns); residuals_m are
    the delay residuals times the estimated velocity. The result adds velocity_m_per_s and
    its bound velocity_sigma_m_per_s, and ``extra["relative_permittivity"]`` = (c / v)^2.
    """
    s = check.sensor_positions(sensors_m, minimum=5)
    tau = check.per_sensor(delays_s, len(s), "delays_s", positive=True)
    sig = check.per_sensor(1e-9 if sigma_s is None else sigma_s, len(s), "sigma_s", positive=True)
    loss = check.loss_name(loss)
    scale = finite_float(loss_scale, "loss_scale", positive=True)
    if initial_position_m is None or initial_velocity_m_per_s is None:
        x_lin, v_lin = _joint_linear(s, tau)
        if x_lin is None:  # all delays alike: the closed form is singular, start at the default velocity
            v_lin = velocity_m_per_s()
            x_lin = _linear_solution(s, v_lin * tau, np.ones(len(s)), False)[0]
    x0 = x_lin if initial_position_m is None else check.position(initial_position_m, "initial_position_m")
    if initial_velocity_m_per_s is None:
        v0 = v_lin
    else:
        v0 = finite_float(initial_velocity_m_per_s, "initial_velocity_m_per_s", positive=True)
    if not (np.isfinite(v0) and 0.0 < v0 <= SPEED_OF_LIGHT_M_PER_S * 1.5):
        # the closed form can fail with noisy delays (v^2 <= 0): start from the median ratio
        v0 = float(np.median(np.linalg.norm(x0 - s, axis=1) / tau))
    # the slowness is solved for in units of p_unit (about the initial slowness) so that all
    # four unknowns are O(1) for the trust region
    p_unit = float(np.mean(tau)) / float(np.mean(np.linalg.norm(x0 - s, axis=1)) + 1e-3)

    def fun(theta):
        x, q = theta[:3], theta[3] * p_unit
        return (tau - q * np.linalg.norm(x - s, axis=1)) / sig

    def jac(theta):
        x, q = theta[:3], theta[3] * p_unit
        diff = x - s
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        return np.column_stack([-q * diff / d[:, None], -d * p_unit]) / sig[:, None]

    sol = least_squares(fun, np.r_[x0, 1.0 / v0 / p_unit], jac=jac, method="trf", loss=loss, f_scale=scale,
                        xtol=TOLERANCE, ftol=TOLERANCE, gtol=TOLERANCE, max_nfev=MAX_EVALUATIONS)
    x, p = sol.x[:3], sol.x[3] * p_unit
    if not p > 0.0:
        raise EstimatorInputError("the delays admit no positive propagation velocity at the fit", "delays_s")
    v = 1.0 / p
    bound = joint_velocity_crlb(s, x, v, sig)
    u, d = unit_vectors(s, x)
    full = _inverse_information(np.column_stack([p * u, d]) / sig[:, None], "sensors")
    sigma_v = float(np.sqrt(max(full[3, 3], 0.0)) * v**2)  # dv = -v^2 dp
    residual_m = (tau - p * d) * v
    return PositionResult(method="joint_velocity", position_m=x, covariance_m2=bound.covariance_m2,
                          residuals_m=residual_m, iterations=int(sol.nfev), converged=bool(sol.status > 0),
                          bound=bound, cost=float(0.5 * np.sum(((tau - p * d) / sig) ** 2)),
                          message=str(sol.message), velocity_m_per_s=float(v), velocity_sigma_m_per_s=sigma_v,
                          extra={"relative_permittivity": float((SPEED_OF_LIGHT_M_PER_S / v) ** 2)})


def _joint_linear(s: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray | None, float]:
    """Closed form of |x - s_i|^2 = v^2 tau_i^2: unknowns (x, |x|^2, v^2), least squares.
    Columns are scaled to unit norm first (metres^2 and seconds^2 differ by 1e16). None when
    singular (e.g. every delay equal: the |x|^2 and v^2 columns are then parallel)."""
    a = np.column_stack([-2.0 * s, np.ones(len(s)), -(tau**2)])
    b = -np.einsum("ij,ij->i", s, s)
    norms = np.linalg.norm(a, axis=0)
    sv = np.linalg.svd(a / norms, compute_uv=False)
    if sv[-1] < 1e-10 * sv[0]:
        return None, float("nan")
    sol = np.linalg.lstsq(a / norms, b, rcond=None)[0] / norms
    w = sol[4]
    return sol[:3], float(np.sqrt(w)) if w > 0 else float("nan")


def _result(method, s, r, sig, x, cov, *, iterations, converged, message, bound=None) -> PositionResult:
    bound = range_crlb(s, x, sig) if bound is None else bound
    model = np.linalg.norm(x - s, axis=1)
    res = r - model
    return PositionResult(method=method, position_m=np.asarray(x, float), covariance_m2=np.asarray(cov, float),
                          residuals_m=res, iterations=iterations, converged=converged, bound=bound,
                          cost=float(0.5 * np.sum((res / sig) ** 2)), message=message)


__all__ = ["bound_from_jacobian", "joint_velocity_fix", "linear_fix", "nonlinear_fix"]
