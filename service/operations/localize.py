"""The work of POST /v1/localize and /v1/localize/evaluate: the capsule's position from several
sensors (docs/localization.md), shared by the routes (service.routes.localize) and the CLI
(``capsule-rt localize``).

A thin layer over :mod:`estimators.localization` (the fixes) and :mod:`evaluation.localization`
(trace -> ranges -> fixes -> statistics). The rules relating several sensors (the same measurement
kind for all, sigmas for all or none, enough distinct non-coplanar sensors, sensors inside the
phantom's body) are checked here or by the estimators, each a 422 whose ``loc`` names the sensor's
field.

Work is bounded before it starts: at most ``MAX_SENSORS`` sensors (64; this server's
``max_receivers`` for an evaluation, which traces them), the model-based grid at most
:data:`MAX_GRID_CELLS` cells, evaluation trials at most ``MAX_EVALUATE_TRIALS`` (and the
server's ``max_trials``), rays and interactions at most the server's channel limits
(:mod:`service.admission`). The work runs in a worker thread under the request's Budget, checked
between sensors' travel-time fields, between trials, and inside the trace.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from estimators.constants import velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.localization import METHODS, Measurements, PositionResult, locate
from estimators.rss import CM2_MODELS
from evaluation.fields import DEFAULT_CELL_SIZE_M
from raytrace import Budget, Phantom
from raytrace.errors import InputError, InvalidGeometryError, field_text
from service import costs
from service.admission import admit, lower_or_refuse, trace_knobs
from service.errors import Unprocessable
from service.registry import Registry
from service.schemas.localize import (
    DEFAULT_PHANTOM,
    DEFAULT_RAYS,
    LocalizeEvaluateRequest,
    LocalizeRequest,
    PositionOrSite,
)
from service.settings import Settings

#: Cell edge of the model-based travel-time grids [m] (docs/localization.md, "Travel-time fields").
CELL_SIZE_M = DEFAULT_CELL_SIZE_M
#: The sensor fields that give what a method measures (its registry entry's ``measures``): a delay is
#: turned into a range at the request's relative permittivity.
_NEEDS = {"ranges_m": ("range_m", "delay_s"), "delays_s": ("delay_s",), "path_loss_db": ("rss_dbm",)}
#: Most cells of a model-based grid (phantom bounds / CELL_SIZE_M plus a margin); the torso has 0.7 M.
MAX_GRID_CELLS = 8_000_000


def _num(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _finite_list(a: Any) -> list:
    return [_num(v) for v in np.asarray(a, float).ravel()]


def _stop(budget: Budget | None) -> None:
    if budget is not None:
        budget.charge(0)


def _phantom(registry: Registry, phantom_id: str | None) -> Phantom:
    return registry.get(phantom_id or DEFAULT_PHANTOM, field_loc=["body", "phantom"])


def _place(phantom: Phantom | None, point: PositionOrSite, where: str, *, in_body: bool = True) -> np.ndarray:
    """A point's position: its site's, or its position_m checked against the phantom (inside its
    bounds, off its surfaces, and in its body, not in the air around it)."""
    if point.site is not None:
        site = phantom.sites.get(point.site)
        if site is None:
            known = ", ".join(sorted(phantom.sites)) or "none"
            raise Unprocessable(f"phantom {phantom.name!r} has no site {point.site!r}; its sites: {known}",
                                loc=["body", *_loc(where), "site"])
        return np.asarray(site.position_m, float)
    p = np.asarray(point.position_m, float)
    if phantom is not None and in_body:
        medium = phantom.antenna_medium(p, field=f"{where}.position_m")
        if medium < 0:
            raise InvalidGeometryError(f"position {p.tolist()} m lies outside the phantom's body (in the air around "
                                       "it): an in-body link has no path there", field=f"{where}.position_m")
    return p


def _loc(where: str) -> list:
    name, _, index = where.partition("[")
    return [name, int(index.rstrip("]"))] if index else [name]


def field_cache_dir(settings: Settings) -> Path:
    """Where the model-based travel-time fields are kept between restarts (docs/localization.md,
    "Speed"): ``<data_dir>/cache/traveltime``, bounded (estimators.localization.fieldstore)."""
    return Path(settings.data_dir) / "cache" / "traveltime"


def _grid_cells(phantom: Phantom) -> int:
    lo, hi = np.asarray(phantom.bounds_m[0], float), np.asarray(phantom.bounds_m[1], float)
    return int(np.prod(np.ceil((hi - lo) / CELL_SIZE_M).astype(np.int64) + 2))


def _check_grid(phantom: Phantom) -> None:
    cells = _grid_cells(phantom)
    if cells > MAX_GRID_CELLS:
        raise Unprocessable(f"the phantom's travel-time grid at {CELL_SIZE_M * 1e3:g} mm cells has {cells} cells, over "
                            f"this server's work limit of {MAX_GRID_CELLS}: use a constant-velocity method",
                            loc=["body", "phantom"])


def _measurements(req: LocalizeRequest) -> tuple[str, np.ndarray, np.ndarray | None]:
    """(kind, values, sigmas in metres or None): one kind for every sensor, sigmas for all or none."""
    kinds = ["range_m" if s.range_m is not None else "delay_s" if s.delay_s is not None else "rss_dbm"
             for s in req.sensors]
    kind = kinds[0]
    for i, k in enumerate(kinds):
        if k != kind:
            raise Unprocessable(f"sensor 0 gives {kind}, this one {k}: give every sensor the same kind",
                                loc=["body", "sensors", i, k])
    needs = _NEEDS[METHODS[req.method].measures]
    if kind not in needs:
        raise Unprocessable(f"method {req.method} needs {' or '.join(needs)} per sensor, got {kind}",
                            loc=["body", "sensors", 0, kind])
    sig = [s.sigma_m for s in req.sensors]
    given = [x is not None for x in sig]
    if any(given) and not all(given):
        i = given.index(False) if given[0] else given.index(True)
        raise Unprocessable("give sigma_m for every sensor or for none", loc=["body", "sensors", i, "sigma_m"])
    if req.method == "rss" and any(given):
        raise Unprocessable("rss weighs by the path-loss model's shadowing; sigma_m does not apply",
                            loc=["body", "sensors", given.index(True), "sigma_m"])
    values = np.array([getattr(s, kind) for s in req.sensors], float)
    return kind, values, (np.array(sig, float) if all(given) else None)


def _with_sensor_loc(exc: EstimatorInputError, kind: str) -> EstimatorInputError:
    """The estimators name arrays (``ranges_m[3]``, ``sensors``); the request names sensors' fields."""
    field = str(getattr(exc, "field", "") or "")
    for prefix, leaf in (("ranges_m", kind), ("delays_s", kind), ("path_loss_db", kind), ("sigma_m", "sigma_m"),
                         ("sigma_s", "sigma_m")):
        if field.startswith(prefix + "["):
            return EstimatorInputError(exc.reason, f"sensors{field[len(prefix):]}.{leaf}")
        if field == prefix:
            return EstimatorInputError(exc.reason, f"sensors[0].{leaf}")
    if not field.startswith("sensors"):  # the geometry as a whole (``fields``, ``position_m``, ...)
        return EstimatorInputError(exc.reason, "sensors")
    return exc


def localize(req: LocalizeRequest, registry: Registry, settings: Settings, budget: Budget | None = None) -> dict:
    """A POST /v1/localize body -> the response dict (no HTTP; the CLI calls it too)."""
    kind, values, sigma_m = _measurements(req)
    entry = METHODS[req.method]  # the one registry of position methods (estimators.localization.methods)
    uses_phantom = req.phantom is not None or entry.needs_fields or any(s.site for s in req.sensors)
    phantom = _phantom(registry, req.phantom) if uses_phantom else None
    sensors = np.array([_place(phantom, s, f"sensors[{i}]") for i, s in enumerate(req.sensors)])
    _stop(budget)
    v = velocity_m_per_s(req.relative_permittivity)
    given = Measurements(sensors_m=sensors, sigma_m=sigma_m, sigma_s=None if sigma_m is None else sigma_m / v,
                         loss=req.loss, model=CM2_MODELS[req.path_loss_model])
    try:
        if entry.measures == "ranges_m":
            given = replace(given, ranges_m=values if kind == "range_m" else values * v)
        elif entry.measures == "path_loss_db":
            given = replace(given, path_loss_db=req.transmit_power_dbm - values)
        else:
            given = replace(given, delays_s=values)
        if entry.needs_fields:
            from estimators.localization._validate import sensor_positions
            from evaluation.fields import sensor_fields

            sensor_positions(sensors)  # duplicates / coplanar refused before any grid is built
            _check_grid(phantom)
            admit(costs.travel_time_fields(_grid_cells(phantom), len(sensors)), settings)
            fields = sensor_fields(phantom, sensors, req.frequency_hz, CELL_SIZE_M, delay_kind=req.delay_kind,
                                   check=lambda: _stop(budget), cache_dir=field_cache_dir(settings))
            _stop(budget)
            given = replace(given, fields=fields)
        fix = locate(req.method, given)
    except EstimatorInputError as exc:
        raise _with_sensor_loc(exc, kind) from exc
    out = _fix_dict(fix, sensors, bounded=sigma_m is not None or entry.measures == "path_loss_db")
    out["delay_kind"] = req.delay_kind if entry.needs_fields else None
    return out


def _fix_dict(fix: PositionResult, sensors: np.ndarray, *, bounded: bool) -> dict:
    out = {
        "method": fix.method,
        "position_m": _finite_list(fix.position_m),
        "covariance_m2": [_finite_list(row) for row in fix.covariance_m2],
        "crlb_m": _num(fix.bound.rms_m) if bounded else None,
        "crlb_sigma_m": _finite_list(fix.bound.sigma_m) if bounded else None,
        "gdop": _num(fix.bound.gdop),
        "pdop": _num(fix.bound.pdop),
        "residuals_m": _finite_list(fix.residuals_m),
        "iterations": int(fix.iterations),
        "converged": bool(fix.converged),
        "message": fix.message,
        "sensor_positions_m": [list(map(float, s)) for s in sensors],
        "velocity_m_per_s": None if fix.velocity_m_per_s is None else _num(fix.velocity_m_per_s),
        "velocity_sigma_m_per_s": None if fix.velocity_sigma_m_per_s is None else _num(fix.velocity_sigma_m_per_s),
        "relative_permittivity": _num(fix.extra["relative_permittivity"]) if "relative_permittivity" in fix.extra
        else None,
        "inside_domain": bool(fix.extra["inside_domain"]) if "inside_domain" in fix.extra else None,
    }
    if None in out["position_m"] or any(None in row for row in out["covariance_m2"]) or None in out["residuals_m"]:
        raise Unprocessable("the fix is not finite: the measurements do not determine a position",
                            loc=["body", "sensors"])
    if out["gdop"] is None or out["pdop"] is None:
        raise Unprocessable("the sensor geometry does not determine the position", loc=["body", "sensors"])
    return out


def evaluate(req: LocalizeEvaluateRequest, registry: Registry, settings: Settings,
             budget: Budget | None = None) -> dict:
    """A POST /v1/localize/evaluate body -> the response dict (no HTTP; the CLI calls it too)."""
    from evaluation.localization import evaluate_localization

    if len(req.sensors) > settings.max_receivers:
        raise Unprocessable(f"{len(req.sensors)} sensors exceed this server's limit of {settings.max_receivers}",
                            loc=["body", "sensors"])
    req.trials = lower_or_refuse(req.trials if "trials" in req.model_fields_set else None, "max_trials", settings,
                                 ("trials",), default=req.trials)
    rays, interactions = trace_knobs(req.rays, req.max_interactions, settings, default_rays=DEFAULT_RAYS,
                                     default_interactions=6)
    phantom = _phantom(registry, req.phantom)
    capsule = _place(phantom, req.capsule, "capsule")
    sensors = np.array([_place(phantom, s, f"sensors[{i}]") for i, s in enumerate(req.sensors)])
    methods = req.methods
    model_based = methods is not None and "model_based" in methods or methods is None and req.ranging != "rss"
    if model_based:
        _check_grid(phantom)
    band = None
    if req.ranging == "pdoa":
        band = {"start_hz": 400e6, "stop_hz": 420e6, "points": min(21, settings.max_band_points)}
    admit(costs.localization_evaluation(
        phantom, capsule, sensors, ranging=req.ranging, model_based=model_based, frequency_hz=req.frequency_hz,
        trials=req.trials, rays=rays, max_interactions=interactions, near_field=req.near_field, band=band,
        grid_cells=_grid_cells(phantom) if model_based else 0, settings=settings), settings)
    try:
        result = evaluate_localization(
            phantom, capsule, list(sensors), ranging=req.ranging, methods=methods, frequency_hz=req.frequency_hz,
            snr_db=req.snr_db, trials=req.trials, seed=req.seed, relative_permittivity=req.relative_permittivity,
            cell_size_m=CELL_SIZE_M, rays=rays, max_interactions=interactions, pdoa_band=band,
            near_field=req.near_field, delay_kind=req.delay_kind, budget=budget, config=settings.tracer_config(),
            field_cache_dir=field_cache_dir(settings))
    except InputError as exc:  # the tracer names its antennas transmitter / receivers[i]
        field = field_text(exc.field).replace("transmitter", "capsule").replace("receivers", "sensors")
        raise type(exc)(exc.reason, field=field) from exc
    names = [s.site or r for s, r in zip(req.sensors, result.sensor_names)]
    stats = []
    for m in result.methods.values():
        err = np.linalg.norm(m.estimates_m - result.capsule_position_m, axis=1)
        stats.append({
            "method": m.method, "mean_error_m": _num(m.mean_error_m), "rmse_m": _num(m.rmse_m),
            "cep50_m": _num(m.cep50_m), "cep90_m": _num(m.cep90_m), "bias_m": _finite_list(m.bias_m),
            "crlb_m": float(m.crlb_m), "gdop": float(m.gdop), "pdop": float(m.pdop),
            "converged_fraction": float(m.converged_fraction), "failures": int(m.failures),
            "errors_m": _finite_list(err),
            "velocity_m_per_s": _num(m.extra["velocity_m_per_s"]) if "velocity_m_per_s" in m.extra else None,
            "relative_permittivity": _num(m.extra["relative_permittivity"]) if "relative_permittivity" in m.extra
            else None,
            "first_path_error_m": _num(m.extra["first_path_error_m"]) if "first_path_error_m" in m.extra else None,
        })
    return {
        "capsule_position_m": _finite_list(result.capsule_position_m),
        "sensor_positions_m": [list(map(float, s)) for s in result.sensor_positions_m],
        "sensor_names": names, "ranging": result.ranging, "frequency_hz": result.frequency_hz,
        "snr_db": result.snr_db, "trials": result.trials, "seed": result.seed,
        "relative_permittivity": result.relative_permittivity, "delay_kind": result.delay_kind,
        "true_distances_m": _finite_list(result.true_distances_m),
        "range_sigma_m": _finite_list(result.range_sigma_m), "methods": stats,
    }
