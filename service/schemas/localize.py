"""Request and response models of POST /v1/localize and /v1/localize/evaluate (docs/api.md
"Localization"; the work: :mod:`service.operations.localize`).

The models state every rule JSON Schema can (types, bounds, list lengths, which fields go
together); the rules relating several sensors are checked by the operation.
"""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY
from estimators.link import MICS_EIRP_DBM
from estimators.localization import DEFAULT_DELAY_KIND, DELAY_KINDS, POSITION_METHODS
from estimators.rss import CM2_MODELS
from estimators.toa import METHODS as TOA_METHODS
from service.limits import MAX_INTERACTIONS, MAX_RAYS, MAX_RECEIVERS, capped
from service.schemas import FrequencyHz, Int, Name, Out, PhantomId, Strict, Vec3, alternatives, int_range

#: Most sensors of one fix (the estimators accept up to 1024; 64 bounds the model-based fields' work).
MAX_SENSORS = 64
#: Most Monte Carlo trials of one evaluation (each runs every method's fix).
MAX_EVALUATE_TRIALS = 200
#: Default rays of an evaluation's trace (lowered to the server's max_rays).
DEFAULT_RAYS = 100_000
DEFAULT_PHANTOM = "torso"

Method = Literal[POSITION_METHODS]  # type: ignore[valid-type]  # the registry's (estimators.localization.methods)
Loss = Literal["linear", "soft_l1", "huber", "cauchy", "arctan"]
Ranging = Literal[(*TOA_METHODS, "pdoa", "rss")]  # type: ignore[valid-type]
DelayKind = Literal[DELAY_KINDS]  # type: ignore[valid-type]

_POINT_ONE_OF = [{"required": ["position_m"], "properties": {"position_m": {"type": "array"}}},
                 {"required": ["site"], "properties": {"site": {"type": "string"}}}]
_MEASUREMENT_ONE_OF = [{"required": [k], "properties": {k: {"type": "number"}}}
                       for k in ("range_m", "delay_s", "rss_dbm")]


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
    path_loss_model: Literal[tuple(CM2_MODELS)] = Field(  # type: ignore[valid-type]  # estimators.rss's
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
                                   f"sites), 4..{MAX_RECEIVERS} (this server's max_receivers), inside the body.",
                                   json_schema_extra=capped("max_receivers"))
    ranging: Ranging = Field("gcc", description="Ranging: a TOA method (`gcc`, `first_peak`, `all_peaks`, "
                             "`envelope`), `pdoa` (400-420 MHz regression) or `rss` (CM2 with shadowing).")
    methods: list[Method] | None = Field(None, min_length=1, max_length=5, json_schema_extra={"uniqueItems": True},
                                         description="Position methods (default: linear, nonlinear, joint_velocity, "
                                         "model_based; rss ranging: rss). rss ranging takes linear, nonlinear, rss.")
    frequency_hz: FrequencyHz = Field(402e6, description="Carrier [Hz].")
    snr_db: float | None = Field(30.0, ge=-50.0, le=200.0, description="SNR of the ranging [dB]; null: noiseless "
                                 "(rss: no shadowing).")
    trials: Int = Field(20, ge=1, le=MAX_EVALUATE_TRIALS, description=f"Monte Carlo trials (<= {MAX_EVALUATE_TRIALS} "
                        "and this server's max_trials).", json_schema_extra=capped("max_trials"))
    seed: Int = Field(0, ge=0, le=2**53 - 1, description="Seed of the noise [-].")
    relative_permittivity: float = Field(DEFAULT_RELATIVE_PERMITTIVITY, ge=1.0, le=1000.0,
                                         description="Assumed relative permittivity of the constant-velocity "
                                         "methods [-].")
    rays: int_range(1, MAX_RAYS) | None = Field(None, description=f"Rays of the trace (default {DEFAULT_RAYS}, or "
                                                 "this server's max_rays if lower).",
                                                 json_schema_extra=capped("max_rays"))
    max_interactions: int_range(1, MAX_INTERACTIONS) | None = Field(None, description="Max interactions per path "
                                                                      "(default 6, or this server's limit).",
                                                                      json_schema_extra=capped("max_interactions"))
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
