"""POST /v1/localize and /v1/localize/evaluate: the capsule's position from several sensors
(docs/localization.md, docs/api.md "Localization").

A thin layer over :mod:`estimators.localization` (the fixes) and
:mod:`evaluation.localization` (trace -> ranges -> fixes -> statistics). The request models
state every rule JSON Schema can (types, bounds, list lengths, which fields go together);
the rules relating several sensors (the same measurement kind for all, sigmas for all or
none, enough distinct non-coplanar sensors, sensors inside the phantom's body) are checked
here or by the estimators, each a 422 whose ``loc`` names the sensor's field.

Work is bounded before it starts: at most :data:`MAX_SENSORS` sensors (64; this server's
``max_receivers`` for an evaluation, which traces them), the model-based grid at most
:data:`MAX_GRID_CELLS` cells, evaluation trials at most :data:`MAX_EVALUATE_TRIALS` (and the
server's ``max_trials``), rays and interactions at most the server's channel limits. The work
runs in a worker thread under the request's Budget, checked between sensors' travel-time fields,
between trials, and inside the trace.

It stays one module (about 500 lines): the two endpoints share the sensor models, their placement
and measurement checks and the mapping of estimator errors to 422s, which service.localize_cli reuses.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
from fastapi import APIRouter, Request
from pydantic import ConfigDict, Field, field_validator, model_validator

from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.link import MICS_EIRP_DBM
from estimators.localization import (
    DEFAULT_DELAY_KIND,
    DELAY_KINDS,
    PositionResult,
    joint_velocity_fix,
    linear_fix,
    model_based_fix,
    nonlinear_fix,
    rss_fix,
)
from estimators.rss import CM2_MODELS
from estimators.toa import METHODS as TOA_METHODS
from raytrace import Budget, Phantom
from raytrace.errors import InputError, InvalidGeometryError, field_text
from service import costs
from service.admission import admit, declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import Unprocessable, error_responses
from service.registry import Registry
from service.schemas import FrequencyHz, Int, Name, Out, PhantomId, Strict, Vec3, alternatives, int_range
from service.settings import MAX_INTERACTIONS, MAX_RAYS, MAX_RECEIVERS, Settings

router = APIRouter(prefix="/v1/localize", tags=["localization"], route_class=ThreadedJsonRoute)

#: Most sensors of one fix (the estimators accept up to 1024; 64 bounds the model-based fields' work).
MAX_SENSORS = 64
#: Cell edge of the model-based travel-time grids [m] (docs/localization.md, "Travel-time fields").
CELL_SIZE_M = 0.004
#: Most cells of a model-based grid (phantom bounds / CELL_SIZE_M plus a margin); the torso has 0.7 M.
MAX_GRID_CELLS = 8_000_000
#: Most Monte Carlo trials of one evaluation (each runs every method's fix).
MAX_EVALUATE_TRIALS = 200
#: Default rays of an evaluation's trace (lowered to the server's max_rays).
DEFAULT_RAYS = 100_000
DEFAULT_PHANTOM = "torso"

Method = Literal["linear", "nonlinear", "joint_velocity", "model_based", "rss"]
Loss = Literal["linear", "soft_l1", "huber", "cauchy", "arctan"]
Ranging = Literal[(*TOA_METHODS, "pdoa", "rss")]  # type: ignore[valid-type]
DelayKind = Literal[DELAY_KINDS]  # type: ignore[valid-type]

_POINT_ONE_OF = [{"required": ["position_m"], "properties": {"position_m": {"type": "array"}}},
                 {"required": ["site"], "properties": {"site": {"type": "string"}}}]
_MEASUREMENT_ONE_OF = [{"required": [k], "properties": {k: {"type": "number"}}}
                       for k in ("range_m", "delay_s", "rss_dbm")]


# ----------------------------------------------------------------- models
class PositionOrSite(Strict):
    """A position: ``position_m`` or a phantom ``site`` (exactly one)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True,
                              json_schema_extra=alternatives(_POINT_ONE_OF))

    position_m: Vec3 | None = Field(None, description="Position [m] (phantom coordinates).")
    site: Name | None = Field(None, description="Name of one of the phantom's sites (GET /v1/phantoms/{id}).")

    @model_validator(mode="after")
    def _one(self) -> "PositionOrSite":
        if (self.position_m is None) == (self.site is None):
            raise ValueError("give exactly one of position_m and site")
        return self


class LocalizeSensor(PositionOrSite):
    """One sensor: where (``position_m`` or ``site``) and what it measured (exactly one of
    ``range_m``, ``delay_s``, ``rss_dbm``; every sensor of a request the same kind)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True,
                              json_schema_extra=alternatives(_POINT_ONE_OF, _MEASUREMENT_ONE_OF))

    range_m: float | None = Field(None, ge=0.0, le=100.0, description="Measured range [m] (constant-velocity "
                                  "methods: linear, nonlinear).")
    delay_s: float | None = Field(None, gt=0.0, le=1e-6, description="Measured delay [s] (every delay method; "
                                  "linear / nonlinear turn it into a range with relative_permittivity), of the "
                                  "request's delay_kind (default group).")
    rss_dbm: float | None = Field(None, ge=-300.0, le=100.0, description="Received power [dBm] (method rss).")
    sigma_m: float | None = Field(None, ge=1e-12, le=100.0, description="Standard deviation of the measurement as "
                                  "a range [m] (a delay's is sigma_m / v at relative_permittivity), at least 1 pm (no "
                                  "ranging resolves less; below ~1e-150 the 1 / sigma^2 weights overflow). Give it for "
                                  "every sensor or none; without it the fit weighs sensors equally and crlb_m is null.")

    @model_validator(mode="after")
    def _measured(self) -> "LocalizeSensor":
        given = [k for k in ("range_m", "delay_s", "rss_dbm") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of range_m, delay_s and rss_dbm")
        return self


class LocalizeRequest(Strict):
    """One position fix (docs/api.md "Localization")."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [
        {"method": "nonlinear", "sensors": [
            {"position_m": [0.1, 0.0, 0.0], "range_m": 0.1, "sigma_m": 0.002},
            {"position_m": [-0.1, 0.0, 0.0], "range_m": 0.1, "sigma_m": 0.002},
            {"position_m": [0.0, 0.1, 0.0], "range_m": 0.1, "sigma_m": 0.002},
            {"position_m": [0.0, -0.1, 0.0], "range_m": 0.1, "sigma_m": 0.002},
            {"position_m": [0.0, 0.0, 0.1], "range_m": 0.1, "sigma_m": 0.002},
            {"position_m": [0.0, 0.0, -0.1], "range_m": 0.1, "sigma_m": 0.002}]},
        {"method": "model_based", "phantom": "torso", "frequency_hz": 402e6, "sensors": [
            {"site": s, "delay_s": 2.0e-9} for s in ("belt_anterior", "belt_left", "belt_posterior", "upper_right",
                                                     "upper_anterior_left", "upper_left")]},
    ]})

    sensors: list[LocalizeSensor] = Field(min_length=4, max_length=MAX_SENSORS, description=f"The sensors, "
                                          f"4..{MAX_SENSORS} (joint_velocity needs 5), not coplanar, none closer "
                                          "than 0.1 mm to another.")
    method: Method = Field("nonlinear", description="`linear` (closed form), `nonlinear` (weighted least squares), "
                           "`joint_velocity` (position and an unknown velocity, delays), `model_based` (travel-time "
                           "fields through the phantom, delays), `rss` (path-loss inversion, rss_dbm).")
    phantom: PhantomId | None = Field(None, description="Phantom (GET /v1/phantoms) for sites and the model-based "
                                      f"travel times; default `{DEFAULT_PHANTOM}` when needed. When a phantom is in "
                                      "use, every sensor must lie inside its body.")
    frequency_hz: FrequencyHz = Field(402e6, description="Carrier [Hz] of the model-based refractive indices.")
    relative_permittivity: float = Field(DEFAULT_RELATIVE_PERMITTIVITY, ge=1.0, le=1000.0, description="Assumed "
                                         "relative permittivity [-]: delays <-> ranges for the constant-velocity "
                                         "methods and the sigmas of delays.")
    delay_kind: DelayKind = Field(DEFAULT_DELAY_KIND, description="What the delays are: `group` (the default: "
                                  "what a TOA receiver timing an envelope or a correlation peak measures, and PDOA; "
                                  "a traced path's group_delay_s) or `phase` (the carrier phase's delay, what the "
                                  "carrier-phase TOA methods gcc / all_peaks / first_peak measure; a traced path's "
                                  "delay_s). model_based builds its travel-time fields with the matching index "
                                  "(group index or Re n); the other methods ignore it.")
    loss: Loss | None = Field(None, description="Robust loss of the least-squares methods (default linear; "
                              "model_based soft_l1).")
    transmit_power_dbm: float = Field(MICS_EIRP_DBM, ge=-100.0, le=100.0, description="rss: transmit power [dBm] "
                                      "(path loss = transmit_power_dbm - rss_dbm).")
    path_loss_model: Literal["cm2_deep_tissue", "cm2_near_surface"] = Field(
        "cm2_deep_tissue", description="rss: the IEEE 802.15.6 CM2 path-loss model inverted.")


class LocalizeResponse(Out):
    method: str
    position_m: list[float] = Field(description="Estimated position [m].")
    covariance_m2: list[list[float]] = Field(description="3x3 covariance of the estimate [m^2] (inverse Fisher "
                                             "information at the estimate; with no sigma_m: for unit weights).")
    crlb_m: float | None = Field(None, description="Bound on the 3-D RMS position error, sqrt(trace CRLB) [m], at "
                                 "the estimate; null without sigma_m (rss: from the model's shadowing).")
    crlb_sigma_m: list[float] | None = Field(None, description="Per-axis CRLB standard deviations [m].")
    gdop: float = Field(description="Geometric dilution of precision [-] (every parameter).")
    pdop: float = Field(description="Position dilution of precision [-].")
    residuals_m: list[float] = Field(description="Measurement minus model per sensor, as ranges [m].")
    iterations: int = Field(description="Solver function evaluations (0: closed form).")
    converged: bool
    message: str
    sensor_positions_m: list[list[float]] = Field(description="The sensors' positions (sites resolved) [m].")
    velocity_m_per_s: float | None = Field(None, description="joint_velocity: the estimated velocity [m/s].")
    velocity_sigma_m_per_s: float | None = Field(None, description="joint_velocity: its bound [m/s].")
    relative_permittivity: float | None = Field(None, description="joint_velocity: (c / v)^2 [-].")
    inside_domain: bool | None = Field(None, description="model_based: the estimate lies in the phantom's body.")
    delay_kind: str | None = Field(None, description="model_based: the kind of delay its fields were built for.")


class LocalizeEvaluateRequest(Strict):
    """Trace -> ranges -> positions, with statistics (docs/api.md "Localization")."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [
        {"phantom": "torso", "capsule": {"site": "small_intestine_1"},
         "sensors": [{"site": s} for s in ("belt_anterior", "belt_left", "belt_posterior", "upper_right",
                                           "upper_anterior_left", "upper_left")],
         "ranging": "gcc", "methods": ["nonlinear", "joint_velocity", "model_based"], "snr_db": 30, "trials": 10,
         "rays": 20000}]})

    phantom: PhantomId = Field(DEFAULT_PHANTOM, description="Phantom (GET /v1/phantoms).")
    capsule: PositionOrSite = Field(description="True capsule position (or site).")
    sensors: list[PositionOrSite] = Field(min_length=4, max_length=MAX_RECEIVERS, description="Sensors (positions or "
                                   f"sites), 4..{MAX_RECEIVERS} (this server's max_receivers), inside the body.")
    ranging: Ranging = Field("gcc", description="Ranging: a TOA method (`gcc`, `first_peak`, `all_peaks`, "
                             "`envelope`), `pdoa` (400-420 MHz regression) or `rss` (CM2 with shadowing).")
    methods: list[Method] | None = Field(None, min_length=1, max_length=5, json_schema_extra={"uniqueItems": True},
                                         description="Position methods (default: linear, nonlinear, joint_velocity, "
                                         "model_based; rss ranging: rss). rss ranging takes linear, nonlinear, rss.")
    frequency_hz: FrequencyHz = Field(402e6, description="Carrier [Hz].")
    snr_db: float | None = Field(30.0, ge=-50.0, le=200.0, description="SNR of the ranging [dB]; null: noiseless "
                                 "(rss: no shadowing).")
    trials: Int = Field(20, ge=1, le=MAX_EVALUATE_TRIALS, description=f"Monte Carlo trials (<= {MAX_EVALUATE_TRIALS} "
                        "and this server's max_trials).")
    seed: Int = Field(0, ge=0, le=2**53 - 1, description="Seed of the noise [-].")
    relative_permittivity: float = Field(DEFAULT_RELATIVE_PERMITTIVITY, ge=1.0, le=1000.0,
                                         description="Assumed relative permittivity of the constant-velocity "
                                         "methods [-].")
    rays: int_range(1, MAX_RAYS) | None = Field(None, description=f"Rays of the trace (default {DEFAULT_RAYS}, or "
                                                 "this server's max_rays if lower).")
    max_interactions: int_range(1, MAX_INTERACTIONS) | None = Field(None, description="Max interactions per path "
                                                                      "(default 6, or this server's limit).")
    near_field: bool = Field(True, description="The dipole near-field term on direct paths (ChannelSpec.near_field).")
    delay_kind: DelayKind | None = Field(None, description="The kind of delay the model-based fix's travel-time "
                                         "fields are built for; default (null): the kind the ranging measures "
                                         "(`group` for envelope and pdoa, `phase` for gcc, all_peaks, first_peak; "
                                         "docs/localization.md, \"Delay kinds\"). The other kind shows what the "
                                         "mismatch costs.")

    @field_validator("methods")
    @classmethod
    def _distinct(cls, methods: list[str] | None) -> list[str] | None:
        if methods is not None and len(set(methods)) != len(methods):
            raise ValueError("methods must be distinct")
        return methods


class LocalizationMethodStatistics(Out):
    method: str
    mean_error_m: float | None = Field(description="Mean 3-D position error [m] (null: every trial failed).")
    rmse_m: float | None = Field(description="RMS 3-D error [m].")
    cep50_m: float | None = Field(description="Median 3-D error (spherical error probable) [m].")
    cep90_m: float | None = Field(description="90th percentile of the 3-D error [m].")
    bias_m: list[float | None] = Field(description="Mean error vector [m].")
    crlb_m: float = Field(description="Position bound sqrt(trace CRLB) at the true position [m].")
    gdop: float
    pdop: float
    converged_fraction: float = Field(description="Share of trials whose solver reported convergence [-].")
    failures: int = Field(description="Trials without a fix.")
    errors_m: list[float | None] = Field(description="3-D error of every trial [m] (null: no fix).")
    velocity_m_per_s: float | None = Field(None, description="joint_velocity: the median estimated velocity [m/s].")
    relative_permittivity: float | None = Field(None, description="joint_velocity: (c / v)^2 [-].")
    first_path_error_m: float | None = Field(None, description="model_based: the fix from the traced first-path "
                                             "delays (the model's own error, no ranging) [m].")


class LocalizeEvaluateResponse(Out):
    capsule_position_m: list[float]
    sensor_positions_m: list[list[float]]
    sensor_names: list[str]
    ranging: str
    frequency_hz: float
    snr_db: float | None
    trials: int
    seed: int
    relative_permittivity: float
    delay_kind: str | None = Field(description="The kind of delay of the model-based fields (null: rss ranging).")
    true_distances_m: list[float] = Field(description="Capsule-sensor distances [m].")
    range_sigma_m: list[float] = Field(description="Per-sensor range sigma used as weight (bound or spread) [m].")
    methods: list[LocalizationMethodStatistics]


# ----------------------------------------------------------------- work
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
    needs = {"rss": ("rss_dbm",), "joint_velocity": ("delay_s",), "model_based": ("delay_s",)}.get(
        req.method, ("range_m", "delay_s"))
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
    uses_phantom = req.phantom is not None or req.method == "model_based" or any(s.site for s in req.sensors)
    phantom = _phantom(registry, req.phantom) if uses_phantom else None
    sensors = np.array([_place(phantom, s, f"sensors[{i}]") for i, s in enumerate(req.sensors)])
    _stop(budget)
    v = velocity_m_per_s(req.relative_permittivity)
    loss = {"loss": req.loss} if req.loss is not None else {}
    try:
        if req.method in ("linear", "nonlinear"):
            ranges = values if kind == "range_m" else values * v
            if req.method == "linear":
                fix = linear_fix(sensors, ranges, sigma_m)
            else:
                fix = nonlinear_fix(sensors, ranges, sigma_m, **loss)
        elif req.method == "joint_velocity":
            fix = joint_velocity_fix(sensors, values, None if sigma_m is None else sigma_m / v, **loss)
        elif req.method == "rss":
            fix = rss_fix(sensors, req.transmit_power_dbm - values, CM2_MODELS[req.path_loss_model], **loss)
        else:
            from estimators.localization._validate import sensor_positions
            from evaluation.fields import sensor_fields

            sensor_positions(sensors)  # duplicates / coplanar refused before any grid is built
            _check_grid(phantom)
            admit(costs.travel_time_fields(_grid_cells(phantom), len(sensors)), settings)
            fields = sensor_fields(phantom, sensors, req.frequency_hz, CELL_SIZE_M, delay_kind=req.delay_kind,
                                   check=lambda: _stop(budget), cache_dir=field_cache_dir(settings))
            _stop(budget)
            fix = model_based_fix(fields, values, None if sigma_m is None else sigma_m / v, **loss)
    except EstimatorInputError as exc:
        raise _with_sensor_loc(exc, kind) from exc
    out = _fix_dict(fix, sensors, bounded=sigma_m is not None or req.method == "rss")
    out["delay_kind"] = req.delay_kind if req.method == "model_based" else None
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
    trials_cap = min(MAX_EVALUATE_TRIALS, settings.max_trials)
    if req.trials > trials_cap:
        raise Unprocessable(f"{req.trials} exceeds this server's limit of {trials_cap}", loc=["body", "trials"])
    rays, interactions = settings.trace_knobs(req.rays, req.max_interactions, default_rays=DEFAULT_RAYS,
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


# ----------------------------------------------------------------- routes
_ERRORS = error_responses(400, 404, 413, 422, 503, 504)


@router.post("", response_model=LocalizeResponse, operation_id="localize", summary="Position fix from sensors' "
             "ranges, delays or received powers", responses=_ERRORS)
@declare(body="max_json_body_bytes", cost=costs.travel_time_fields)
async def localize_route(req: LocalizeRequest, request: Request) -> LocalizeResponse:
    """The capsule's position from at least four sensors (five for joint_velocity), each with a
    range, a delay or a received power: closed-form or weighted nonlinear least squares at a constant
    velocity, joint position-and-velocity, heterogeneity-aware travel-time fields through the phantom
    (model_based: eikonal, 4 mm cells, cached per phantom, sensor and frequency), or path-loss inversion
    (rss). Returns the estimate, its covariance, the position Cramér-Rao bound and GDOP/PDOP beside it,
    the residuals and the solver's convergence (docs/localization.md)."""
    st = state(request)
    out = await st.gate.run(lambda budget: localize(req, st.registry, st.settings, budget),
                            Budget(deadline_s=st.settings.request_deadline_s), disconnected=request.is_disconnected)
    return LocalizeResponse.model_validate(out)


@router.post("/evaluate", response_model=LocalizeEvaluateResponse, operation_id="localize_evaluate",
             summary="Trace, range and locate: position error statistics beside the bound", responses=_ERRORS)
@declare(body="max_json_body_bytes", cost=costs.localization_evaluation)
async def localize_evaluate_route(req: LocalizeEvaluateRequest, request: Request) -> LocalizeEvaluateResponse:
    """One trace from the capsule to the sensors, a seeded Monte Carlo ranging run per sensor
    (TOA, PDOA or RSS), a fix per trial and method; per method the mean error, RMSE, CEP50/CEP90 and
    every trial's error beside the position CRLB and GDOP/PDOP at the true position
    (docs/localization.md, "End-to-end evaluation")."""
    st = state(request)
    budget = Budget(deadline_s=st.settings.request_deadline_s, max_ray_segments=st.settings.max_ray_segments,
                    max_bytes=st.settings.compute_memory_share_bytes)
    out = await st.gate.run(lambda b: evaluate(req, st.registry, st.settings, b), budget,
                            disconnected=request.is_disconnected)
    return LocalizeEvaluateResponse.model_validate(out)
