"""Request and response models of POST /v1/track and /v1/track/evaluate (docs/tracking.md; the
work: :mod:`service.operations.tracking`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from service.limits import capped
from service.schemas import Int, int_range

#: Observations per request.
MAX_OBSERVATIONS = 5000
#: The evaluation's bounds: journey steps and rays per trace.
MAX_EVALUATE_STEPS = 1000
MAX_EVALUATE_RAYS = 50_000
DEFAULT_EVALUATE_RAYS = 20_000
#: Monte Carlo runs of one evaluation, and runs x steps (each step a Kalman and a particle-filter update).
MAX_EVALUATE_RUNS = 20
MAX_EVALUATE_RUN_STEPS = 5000
Vec3 = Annotated[list[Annotated[float, Field(ge=-10.0, le=10.0)]], Field(min_length=3, max_length=3)]
Row3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


Cov3 = Annotated[list[Row3], Field(min_length=3, max_length=3)]


class RfFixIn(_Strict):
    position_m: Vec3 = Field(description="The RF position fix [m], phantom frame.")
    covariance_m2: Cov3 = Field(description="Its 3 x 3 covariance [m^2], symmetric positive definite: its white "
                                "error (with no bias_covariance_m2, include the fix's bias here).")
    bias_covariance_m2: Cov3 | None = Field(None, description="Optional: the stationary 3 x 3 covariance [m^2] of "
                                            "the part of its error the fixes nearby share (the body's bias at that "
                                            "spot; positive semi-definite). Correlated along the tract when "
                                            "config.rf_correlation_length_m is set, else added to covariance_m2.")


class VisualIn(_Strict):
    advance_m: float = Field(ge=-0.1, le=0.1, description="Advance along the lumen since the previous step [m].")
    advance_sigma_m: float = Field(gt=0.0, le=0.1, description="Its standard deviation [m].")
    roll_deg: float | None = Field(None, ge=-180.0, le=180.0, description="Roll increment [deg] (optional).")
    roll_sigma_deg: float | None = Field(None, gt=0.0, le=180.0, description="Its standard deviation [deg].")


class ObservationIn(_Strict):
    t_s: float = Field(ge=0.0, le=1e7, description="Time [s]; strictly increasing.")
    rf: RfFixIn | None = None
    visual: VisualIn | None = Field(None, description="Frame-pair motion from the previous step (ignored at "
                                                      "the first).")


class TrackerConfigIn(_Strict):
    accel_psd_m2_per_s3: float = Field(4e-6, gt=0.0, le=1.0)
    roll_psd_deg2_per_s: float = Field(20.0, gt=0.0, le=1e5)
    initial_s_m: float | None = Field(None, ge=0.0, le=100.0, description="Prior arc length [m]; null: anywhere.")
    initial_s_sigma_m: float = Field(5e-3, gt=0.0, le=100.0)
    initial_v_m_per_s: float = Field(0.0, ge=-1.0, le=1.0)
    initial_v_sigma_m_per_s: float = Field(3e-3, gt=0.0, le=1.0)
    gate_probability: float | None = Field(0.9999, gt=0.5, lt=1.0)
    visual_gate_probability: float | None = Field(None, gt=0.5, lt=1.0, description="Both filters ignore an advance "
                                                  "beyond this chi-square(1) quantile of their prediction.")
    lateral_sigma_m: float = Field(0.0, ge=0.0, le=1.0)
    rf_correlation_length_m: float | None = Field(None, ge=1e-4, le=10.0, description="Length along the tract over "
                                                  "which the fixes' bias decorrelates (a smooth Gauss-Markov state; "
                                                  "docs/tracking.md); null: their errors are white.")
    rf_min_spacing_m: float = Field(0.0, ge=0.0, le=1.0, description="Use a fix only once the estimate or the fix "
                                    "has moved this far along the tract from the last used one.")
    speed_range_m_per_s: Annotated[list[Annotated[float, Field(ge=-1.0, le=1.0)]],
                                   Field(min_length=2, max_length=2)] | None = Field(
        None, description="[lowest <= 0, highest >= 0] speed along the tract [m/s]: an advance outside it times "
                          "dt is dropped.")
    max_consecutive_gated: Int = Field(5, ge=1, le=10_000, description="After this many refusals in a row a gate "
                                       "lets the next measurement in (it cannot starve the filter).")
    particles: Int = Field(2000, ge=10, le=100_000)
    seed: Int = Field(0, ge=0, le=2**53 - 1)  # a JSON number holds integers exactly to 2^53


class TrackRequest(_Strict):
    """Measured sequences along a phantom's centreline."""

    phantom: str = Field("torso", min_length=1, max_length=64)
    centreline: str = Field("gi_tract", min_length=1, max_length=64)
    tracker: Literal["kalman", "particle"] = "kalman"
    config: TrackerConfigIn = Field(default_factory=TrackerConfigIn)
    observations: list[ObservationIn] = Field(min_length=1, max_length=MAX_OBSERVATIONS)


class TrackStep(BaseModel):
    t_s: float
    s_m: float
    s_sigma_m: float
    v_m_per_s: float
    v_sigma_m_per_s: float
    roll_deg: float
    roll_sigma_deg: float
    position_m: list[float]
    position_cov_m2: list[list[float]]
    rf_used: bool


class TrackResponse(BaseModel):
    tracker: str
    steps: list[TrackStep]


class JourneyIn(_Strict):
    steps: Int = Field(120, ge=2, le=MAX_EVALUATE_STEPS)
    seed: Int = Field(0, ge=0, le=2**53 - 1)  # a JSON number holds integers exactly to 2^53
    dt_s: float = Field(0.5, gt=1e-3, le=60.0)
    start_m: float = Field(0.20, ge=0.0, le=100.0)
    mean_speed_m_per_s: float = Field(1.5e-3, ge=0.0, le=0.05)
    peristalsis_amplitude_m: float = Field(1.5e-3, ge=0.0, le=0.05)
    peristalsis_period_s: float = Field(8.0, gt=0.1, le=3600.0)  # the journey refuses 0.1 itself
    roll_step_deg: float = Field(3.0, ge=0.0, le=45.0)


class EvaluateRequest(_Strict):
    """The built-in journey experiment (docs/tracking.md, Evaluation)."""

    phantom: Literal["torso"] = "torso"
    journey: JourneyIn = Field(default_factory=JourneyIn)
    trackers: list[Literal["rf", "video", "fused", "fused_pf"]] = Field(
        default_factory=lambda: ["rf", "video", "fused"], min_length=1, max_length=4)
    rays: int_range(1000, MAX_EVALUATE_RAYS) | None = Field(
        None, description=f"Rays per trace (default {DEFAULT_EVALUATE_RAYS}, or this server's max_rays if lower); "
                          "at most the server's max_rays.", json_schema_extra=capped("max_rays"))
    max_interactions: int_range(1, 6) | None = Field(
        None, description="Interactions per trace (default 4, or this server's max_interactions if lower); at most "
                          "the server's.", json_schema_extra=capped("max_interactions"))
    rf_grid_m: float = Field(5e-3, ge=1e-3, le=0.05)
    runs: Int = Field(1, ge=1, le=MAX_EVALUATE_RUNS, description="Monte Carlo runs of the journey (each its own "
                      "prior draw, RF noise and visual errors); runs x steps at most "
                      f"{MAX_EVALUATE_RUN_STEPS}.")
    include_trajectory: bool = Field(True, description="Return every tracker's trajectory (of the first run), and "
                                     "the truth.")


class Consistency(BaseModel):
    average: float | None = Field(description="Averaged NEES / NIS (null: no value).")
    lower: float | None = Field(description="Lower end of its two-sided 95 % chi-square band.")
    upper: float | None = Field(description="Upper end of the band.")
    dof: int = Field(description="Degrees of freedom of one value.")
    samples: int = Field(description="Values averaged.")
    effective: float = Field(description="Independent values the band counts.")
    inside: bool = Field(description="The average lies inside its band.")


class EvaluateResponse(BaseModel):
    rmse_m: dict[str, float] = Field(description="RMSE along the tract per tracker [m] (pooled over runs).")
    rmse_3d_m: dict[str, float] = Field(description="RMSE of the 3-D point per tracker [m] (pooled over runs).")
    consistency: dict[str, dict[str, Consistency]] = Field(description="Per tracker its averaged NEES of s "
                                                           "(`nees`) and NIS of the used RF fixes (`nis_rf`) and "
                                                           "advances (`nis_visual`) against their 95 % bands.")
    runs: int
    rf_fix_rmse_3d_m: float | None = Field(description="3-D RMSE of the RF fixes themselves [m] (null: no RF "
                                                       "tracker was asked for, so no fix was made).")
    rf_positions_traced: int
    truth: list[dict] = Field(description="Per step: t_s, s_m, position_m, roll_deg, organ.")
    trajectory: dict[str, list[TrackStep]]
