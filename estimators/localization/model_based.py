"""Heterogeneity-aware position fix from delays and precomputed travel-time fields
(docs/localization.md, "Model-based fix").

    x_hat = argmin_x  sum_i rho( ((tau_i - T_i(x)) / sigma_i)^2 ),
    sigma_i^2 = sigma_meas,i^2 + sigma_model^2

with T_i the first-arrival time from sensor i (:mod:`.traveltime`), trilinearly
interpolated, and rho a robust loss (soft_l1 by default: the delays of multipath-dominated
links are not first arrivals and must not drag the fix). ``sigma_model`` is the fields'
discretisation error as a uniform error's standard deviation, err / sqrt(3), unless given.

Start: the same cost over the domain cells on a coarse lattice (every k-th cell, at most
:data:`START_CANDIDATES` points: a global search, no other estimator needed); its
:data:`STARTS` lowest points at least :data:`START_SEPARATION_CELLS` apart each start
scipy.optimize.least_squares (trust region, bounded to the grid), and the lowest final
cost wins. Several starts because the cost can have distant minima of nearly equal depth:
a capsule below both sensor rows of the default torso reaches most sensors by head waves
along the subcutaneous fat, and the travel times then change little along a direction
that trades depth below the fat for height.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from .._checks import finite_float
from ..errors import EstimatorInputError
from . import _validate as check
from .bounds import travel_time_crlb
from .multilateration import MAX_EVALUATIONS, TOLERANCE
from .results import PositionResult
from .traveltime import TravelTimeField, TravelTimeFields

#: Most lattice points the global start evaluates.
START_CANDIDATES = 30_000
#: Local solves started from the lowest lattice points, and their least separation [cells].
STARTS = 4
START_SEPARATION_CELLS = 6.0


def _rho(z: np.ndarray, loss: str) -> np.ndarray:
    """scipy's robust losses of z = (r / scale)^2."""
    if loss == "linear":
        return z
    if loss == "soft_l1":
        return 2.0 * (np.sqrt(1.0 + z) - 1.0)
    if loss == "huber":
        return np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    if loss == "cauchy":
        return np.log1p(z)
    return np.arctan(z)


def model_based_fix(fields: TravelTimeFields | Sequence[TravelTimeField], delays_s: Any, sigma_s: Any = None, *,
                    model_sigma_s: float | None = None, initial_position_m: Any = None, loss: str = "soft_l1",
                    loss_scale: float = 1.0) -> PositionResult:
    """Model-based fix (module docstring). ``fields`` one per delay, sharing one grid
    (:class:`TravelTimeFields` or a list of :class:`TravelTimeField`). ``sigma_s``
    measurement sigmas (default 0: the model sigma alone weights). residuals_m are the delay
    residuals times the local speed 1 / |grad T_i| at the estimate. The bound uses the
    measurement sigmas (floored at 1e-15 s) and the travel-time gradients; the covariance the
    fit's total sigmas. ``extra``: sigma_total_s, model_sigma_s, inside_domain (whether the
    estimate's cell is in the propagation domain).
    """
    ff = fields if isinstance(fields, TravelTimeFields) else TravelTimeFields(fields)
    if len(ff) < 4:
        raise EstimatorInputError(f"a 3-D fix needs at least 4 sensors, got {len(ff)}", "fields")
    check.sensor_positions(ff.sensors_m, "sensors", minimum=4)
    tau = check.per_sensor(delays_s, len(ff), "delays_s", positive=True)
    meas = check.per_sensor(0.0 if sigma_s is None else sigma_s, len(ff), "sigma_s", nonnegative=True)
    model = (ff.discretisation_error_s / np.sqrt(3.0) if model_sigma_s is None
             else finite_float(model_sigma_s, "model_sigma_s", nonnegative=True))
    sig = np.sqrt(meas**2 + model**2)
    if np.any(sig <= 0.0):
        raise EstimatorInputError("every delay needs a positive sigma (measurement or model)", "sigma_s")
    loss = check.loss_name(loss)
    scale = finite_float(loss_scale, "loss_scale", positive=True)
    starts = (_global_starts(ff, tau, sig, loss, scale) if initial_position_m is None
              else [check.position(initial_position_m, "initial_position_m")])

    memo: dict = {}

    def at(x):  # least_squares asks for fun and jac at the same point: interpolate once
        key = x.tobytes()
        if key not in memo:
            memo.clear()
            memo[key] = ff.evaluate(x)
        return memo[key]

    def fun(x):
        return (tau - at(x)[0]) / sig

    def jac(x):
        return -at(x)[1] / sig[:, None]

    sol, evaluations = None, 0
    for x0 in starts:
        trial = least_squares(fun, np.clip(x0, ff.lower_m, ff.upper_m), jac=jac, method="trf", loss=loss,
                              f_scale=scale, bounds=(ff.lower_m, ff.upper_m), xtol=TOLERANCE, ftol=TOLERANCE,
                              gtol=TOLERANCE, max_nfev=MAX_EVALUATIONS)
        evaluations += int(trial.nfev)
        if sol is None or trial.cost < sol.cost:
            sol = trial
    x = sol.x
    t, grad = ff.evaluate(x)
    speed = 1.0 / np.maximum(np.linalg.norm(grad, axis=1), 1e-30)
    residual_s = tau - t
    bound = travel_time_crlb(grad, np.maximum(meas, 1e-15))
    fit = travel_time_crlb(grad, sig)
    return PositionResult(method="model_based", position_m=x, covariance_m2=fit.covariance_m2,
                          residuals_m=residual_s * speed, iterations=evaluations, converged=bool(sol.status > 0),
                          bound=bound, cost=float(0.5 * np.sum((residual_s / sig) ** 2)), message=str(sol.message),
                          extra={"sigma_total_s": sig, "model_sigma_s": float(model),
                                 "inside_domain": ff.inside_domain(x), "starts": len(starts)})


def _global_starts(ff: TravelTimeFields, tau, sig, loss, scale) -> list[np.ndarray]:
    """The lowest lattice points of the robust cost over the domain cells, at least
    START_SEPARATION_CELLS apart (module docstring)."""
    if not ff.domain.any():
        raise EstimatorInputError("the fields share no propagation-domain cell", "fields")
    cand, t = ff.lattice(START_CANDIDATES)  # (P, 3) cells, (S, P) times
    z = ((tau[:, None] - t) / (sig[:, None] * scale)) ** 2
    cost = _rho(z, loss).sum(axis=0)
    chosen: list[np.ndarray] = []
    for i in np.argsort(cost):
        c = cand[i]
        if all(np.linalg.norm(c - o) >= START_SEPARATION_CELLS for o in chosen):
            chosen.append(c)
            if len(chosen) == STARTS:
                break
    return [ff.origin_m + (c + 0.5) * ff.spacing_m for c in chosen]
