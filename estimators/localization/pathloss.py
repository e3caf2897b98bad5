"""RSS localization: path losses through a log-distance path-loss model, then multilateration
(docs/localization.md, "RSS").

Model (IEEE 802.15.6 CM2, thesis Eq 2.2, or one fitted to a phantom):
PL_i = PL(d0) + 10 n log10(d_i / d0) + S_i, S_i ~ N(0, sigma^2) dB. Inverting it gives
median distances d_hat_i = d0 10^((PL_i - PL(d0)) / (10 n)); the maximum-likelihood
position under log-normal shadowing minimises

    sum_i (10 n log10(d_hat_i / |x - s_i|) / sigma)^2,

multilateration on log-distances (started from :func:`.multilateration.linear_fix` on
d_hat with sigma_d = ln(10) sigma d_hat / (10 n)).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import least_squares

from .._checks import finite_float
from ..errors import EstimatorInputError
from ..rss import CM2_MODELS, REFERENCE_DISTANCE_M, PathLossModel
from . import _validate as check
from .bounds import rss_position_crlb
from .multilateration import MAX_EVALUATIONS, TOLERANCE, _linear_solution
from .results import PositionResult


def path_loss_model(model: Any, field: str = "model") -> PathLossModel:
    """A :class:`estimators.rss.PathLossModel` from a CM2 name, an instance, or a mapping
    with path_loss_d0_db, exponent, shadowing_db (and optionally reference_distance_m, name)."""
    if isinstance(model, PathLossModel):
        m = model
    elif isinstance(model, str):
        if model not in CM2_MODELS:
            raise EstimatorInputError(f"unknown model {model!r} ({' | '.join(CM2_MODELS)} or a fitted model)", field)
        return CM2_MODELS[model]
    elif isinstance(model, dict):
        extra = set(model) - {"name", "path_loss_d0_db", "exponent", "shadowing_db", "reference_distance_m"}
        if extra:
            raise EstimatorInputError(f"unknown field(s) {sorted(extra)}", field)
        try:
            m = PathLossModel(name=str(model.get("name", "fitted")), path_loss_d0_db=model["path_loss_d0_db"],
                              exponent=model["exponent"], shadowing_db=model["shadowing_db"],
                              reference_distance_m=model.get("reference_distance_m", REFERENCE_DISTANCE_M))
        except KeyError as exc:
            raise EstimatorInputError(f"missing {exc.args[0]}", f"{field}.{exc.args[0]}") from None
    else:
        raise EstimatorInputError("must be a CM2 model name, a PathLossModel or a mapping", field)
    finite_float(m.path_loss_d0_db, f"{field}.path_loss_d0_db")
    finite_float(m.exponent, f"{field}.exponent", positive=True)
    finite_float(m.shadowing_db, f"{field}.shadowing_db", positive=True)
    finite_float(m.reference_distance_m, f"{field}.reference_distance_m", positive=True)
    return m


def fit_path_loss_model(distances_m: Any, path_loss_db: Any, *, reference_distance_m: float = REFERENCE_DISTANCE_M,
                        name: str = "fitted") -> PathLossModel:
    """Least-squares log-distance model PL(d0) + 10 n log10(d / d0) through (distance, path
    loss) pairs (e.g. traced links of a phantom); shadowing_db is the residual standard
    deviation (ddof = 2). Needs at least 3 pairs over more than one distance."""
    d = np.asarray(distances_m, dtype=float).ravel()
    pl = np.asarray(path_loss_db, dtype=float).ravel()
    if d.shape != pl.shape or len(d) < 3:
        raise EstimatorInputError("needs at least 3 (distance, path loss) pairs of equal length", "distances_m")
    if not (np.isfinite(d).all() and np.isfinite(pl).all()) or np.any(d <= 0):
        raise EstimatorInputError("distances must be finite and > 0, path losses finite", "distances_m")
    d0 = finite_float(reference_distance_m, "reference_distance_m", positive=True)
    with np.errstate(divide="ignore"):
        x = 10.0 * np.log10(d / d0)
    if not np.isfinite(x).all():  # d / d0 under- or overflowed
        raise EstimatorInputError("distances and reference_distance_m must be within a factor 1e300 of each "
                                  "other", "distances_m")
    if np.ptp(x) <= 0.0:
        raise EstimatorInputError("distances must not all be equal", "distances_m")
    a = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(a, pl, rcond=None)
    resid = pl - a @ coef
    sigma = float(np.sqrt(np.sum(resid**2) / max(len(d) - 2, 1)))
    if not coef[1] > 0:
        raise EstimatorInputError("the fitted path loss does not grow with distance", "path_loss_db")
    return PathLossModel(name=name, path_loss_d0_db=float(coef[0]), exponent=float(coef[1]),
                         shadowing_db=max(sigma, 1e-6), reference_distance_m=d0)


def rss_fix(sensors_m: Any, path_loss_db: Any, model: Any = "cm2_deep_tissue", *, initial_position_m: Any = None,
            loss: str = "linear", loss_scale: float = 1.0) -> PositionResult:
    """Maximum-likelihood position from per-sensor path losses [dB] (module docstring).
    residuals_m: d_hat_i - |x - s_i|; ``extra["distances_m"]`` the inverted distances."""
    s = check.sensor_positions(sensors_m, minimum=4)
    pl = check.per_sensor(path_loss_db, len(s), "path_loss_db")
    m = path_loss_model(model)
    loss = check.loss_name(loss)
    scale = finite_float(loss_scale, "loss_scale", positive=True)
    d_hat = np.asarray(m.median_distance_m(pl), float)
    k = 10.0 * m.exponent / m.shadowing_db  # dB per decade over sigma

    if initial_position_m is None:
        sigma_d = np.log(10.0) * m.shadowing_db * d_hat / (10.0 * m.exponent)
        x0 = _linear_solution(s, d_hat, sigma_d, True)[0]
    else:
        x0 = check.position(initial_position_m, "initial_position_m")

    def fun(x):
        return k * np.log10(d_hat / np.maximum(np.linalg.norm(x - s, axis=1), 1e-9))

    def jac(x):
        diff = x - s
        d2 = np.maximum(np.einsum("ij,ij->i", diff, diff), 1e-18)
        return -(k / np.log(10.0)) * diff / d2[:, None]

    sol = least_squares(fun, x0, jac=jac, method="trf", loss=loss, f_scale=scale, xtol=TOLERANCE, ftol=TOLERANCE,
                        gtol=TOLERANCE, max_nfev=MAX_EVALUATIONS)
    x = sol.x
    bound = rss_position_crlb(s, x, m.exponent, m.shadowing_db)
    res = fun(x)
    return PositionResult(method="rss", position_m=x, covariance_m2=bound.covariance_m2,
                          residuals_m=d_hat - np.linalg.norm(x - s, axis=1), iterations=int(sol.nfev),
                          converged=bool(sol.status > 0), bound=bound, cost=float(0.5 * np.sum(res**2)),
                          message=str(sol.message), extra={"distances_m": d_hat, "model": m.name})
