"""POST /v1/track (measured sequences -> trajectory along the GI tract with uncertainty) and
POST /v1/track/evaluate (the built-in journey experiment), docs/tracking.md. CPU work in a worker
thread under the server's deadline; bounds checked before any work."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, Field

from raytrace.solver.budget import Budget
from service import costs
from service.admission import admit, declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import error_responses
from service.schemas import Int, int_range

router = APIRouter(prefix="/v1/track", tags=["tracking"], route_class=ThreadedJsonRoute)

_ERRORS = error_responses(400, 404, 413, 422, 503, 504)
#: Observations per request; particles x observations per request (work bound).
MAX_OBSERVATIONS = 5000
MAX_PARTICLE_STEPS = 20_000_000
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
                          "at most the server's max_rays.")
    max_interactions: int_range(1, 6) | None = Field(
        None, description="Interactions per trace (default 4, or this server's max_interactions if lower); at most "
                          "the server's.")
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


def track_cost(req: TrackRequest, settings) -> costs.Cost:
    """The particle filter's particles x observations steps (:func:`service.costs.particles`); a Kalman
    track is linear in the (schema-bounded) observations."""
    return costs.particles(req.config.particles, len(req.observations), settings, MAX_PARTICLE_STEPS)


def run_track(req: TrackRequest, registry, budget: Budget, settings=None) -> dict:
    from tracking import (
        Observation,
        RfFix,
        TrackerConfig,
        TrackingInputError,
        VisualMotion,
        kalman_track,
        particle_track,
    )

    if req.tracker == "particle":
        from service.settings import Settings

        settings = settings if settings is not None else Settings()
        admit(track_cost(req, settings), settings)
    phantom = registry.get(req.phantom, field_loc=["body", "phantom"])
    line = phantom.centrelines.get(req.centreline)
    if line is None:
        raise TrackingInputError(f"phantom {req.phantom!r} has no centreline {req.centreline!r}", "centreline")
    obs = [Observation(o.t_s, None if o.rf is None else RfFix(o.rf.position_m, o.rf.covariance_m2,
                                                              o.rf.bias_covariance_m2),
                       None if o.visual is None else VisualMotion(**o.visual.model_dump()))
           for o in req.observations]
    conf = req.config.model_dump()
    if conf["speed_range_m_per_s"] is not None:
        conf["speed_range_m_per_s"] = tuple(conf["speed_range_m_per_s"])
    cfg = TrackerConfig(**conf)
    budget.charge()
    if req.tracker == "particle":  # checked at every step: past the deadline, or once the client left, it stops
        out = particle_track(line, obs, cfg, name=req.tracker, check=budget.charge)
    else:
        out = kalman_track(line, obs, cfg, name=req.tracker)
    budget.charge()
    return out.to_dict()


def _finite_or_none(x: float | None) -> float | None:
    """NaN (no RF fix made) as null: JSON has no NaN, and pydantic would write it as null anyway."""
    return None if x is None or not math.isfinite(x) else float(x)


def track_evaluate_cost(req: EvaluateRequest, phantom, rays: int, interactions: int, settings) -> costs.Cost:
    """The journey's RF traces (one per RF grid position it visits: at most 200, the journey's steps, the
    tract's length over rf_grid_m), each a channel request's cost to the phantom's sensor sites
    (:func:`service.costs.channel`); their shootings add up against the work budget, one is held at a time."""
    from evaluation.tracking import MAX_RF_POSITIONS
    from raytrace.spec import Antenna, ChannelSpec

    if all(t == "video" for t in req.trackers):
        return costs.Cost()
    line = phantom.centrelines.get("gi_tract")
    length = line.length_m if line is not None else 0.0
    positions = min(MAX_RF_POSITIONS, req.journey.steps, int(length / req.rf_grid_m) + 1)
    sensors = tuple(Antenna(site=n, name=n) for n, s in phantom.sites.items() if s.kind == "sensor")
    spec = ChannelSpec(Antenna(position_m=[0.0, 0.0, 0.0]), sensors or (Antenna(position_m=[0.0, 0.0, 0.1]),),
                       rays=rays, max_interactions=interactions)
    trace = costs.channel(spec, settings, {"receivers": ("rays",), "band.points": ("rays",)})
    return costs.repeat(trace, positions, what="RF grid positions")


def _evaluate(req: EvaluateRequest, registry, settings, budget: Budget) -> dict:
    from evaluation.tracking import evaluate_tracking
    from service.routes.localize import field_cache_dir
    from tracking import JourneySpec, TrackingInputError

    if req.runs * req.journey.steps > MAX_EVALUATE_RUN_STEPS:
        raise TrackingInputError(f"runs x steps must be <= {MAX_EVALUATE_RUN_STEPS}", "runs")
    rays, interactions = settings.trace_knobs(req.rays, req.max_interactions, default_rays=DEFAULT_EVALUATE_RAYS,
                                              default_interactions=6)
    phantom = registry.get(req.phantom, field_loc=["body", "phantom"])
    admit(track_evaluate_cost(req, phantom, rays, interactions, settings), settings)
    ev = evaluate_tracking(JourneySpec(**req.journey.model_dump()), req.trackers, phantom=phantom,
                           rf_grid_m=req.rf_grid_m, rays=rays, max_interactions=interactions, runs=req.runs,
                           check=budget.charge, field_cache_dir=field_cache_dir(settings))
    j = ev.journey
    truth = [{"t_s": float(j.t_s[k]), "s_m": float(j.s_m[k]), "position_m": j.position_m[k].tolist(),
              "roll_deg": float(j.roll_deg[k]), "organ": j.organ[k]} for k in range(len(j.t_s))]
    consistency = {n: {k: {key: (_finite_or_none(val) if isinstance(val, float) else val)
                           for key, val in band.to_dict().items()} for k, band in c.items()}
                   for n, c in ev.consistency.items()}
    return {"rmse_m": ev.rmse_along_m, "rmse_3d_m": ev.rmse_3d_m, "consistency": consistency, "runs": ev.runs,
            "rf_fix_rmse_3d_m": _finite_or_none(ev.rf_fix_rmse_3d_m),
            "rf_positions_traced": ev.rf_positions_traced, "truth": truth if req.include_trajectory else [],
            "trajectory": {n: t.to_dict()["steps"] for n, t in ev.tracks.items()} if req.include_trajectory else {}}


@router.post("", response_model=TrackResponse, operation_id="track", summary="Track the capsule along the tract",
             responses=_ERRORS)
@declare(body="max_ranging_body_bytes", cost=track_cost)
async def track(req: TrackRequest, request: Request) -> TrackResponse:
    """RF position fixes (with covariance) and frame-pair motion (advance, roll) per time step in;
    the trajectory along the centreline out: arc length, rate, roll and the 3-D point, each with its
    uncertainty. `kalman`: state (s, ds/dt, roll), fixes projected onto the centreline; `particle`:
    particles on the centreline weighted by the fixes' 3-D likelihood (keeps both loops where the
    tract folds back)."""
    st = state(request)
    out = await st.gate.run(lambda budget: run_track(req, st.registry, budget, st.settings),
                            Budget(deadline_s=st.settings.request_deadline_s), disconnected=request.is_disconnected)
    return TrackResponse.model_validate(out)


@router.post("/evaluate", response_model=EvaluateResponse, operation_id="track_evaluate",
             summary="The journey experiment: RMSE per tracker", responses=_ERRORS)
@declare(body="max_json_body_bytes", cost=track_evaluate_cost)
async def track_evaluate(req: EvaluateRequest, request: Request) -> EvaluateResponse:
    """A seeded journey along the default torso's GI tract; RF fixes from the sweep engine and the
    model-based fix (positions traced once per grid position and kept in memory), calibrated and declared
    with the RF error model measured on the torso; visual motion from the MI estimator's error model
    measured on rendered frames of the torso; RMSE along the tract and in 3-D per tracker, and its NEES /
    NIS against their 95 % bands (docs/tracking.md). Bounded: at most 1000 steps, 20 runs (runs x steps
    <= 5000) and 200 traced grid positions, under the server's deadline (504 past it)."""
    st = state(request)
    out = await st.gate.run(lambda budget: _evaluate(req, st.registry, st.settings, budget),
                            Budget(deadline_s=st.settings.request_deadline_s), disconnected=request.is_disconnected)
    return EvaluateResponse.model_validate(out)


# ----------------------------------------------------------------------- CLI: capsule-rt track
