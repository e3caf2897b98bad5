"""The work of POST /v1/track (measured sequences -> trajectory along the GI tract with
uncertainty) and POST /v1/track/evaluate (the built-in journey experiment), docs/tracking.md;
shared by the routes (service.routes.tracking) and the CLI (``capsule-rt track``). Bounds are
checked before any work (:mod:`service.admission`); the work checks its Budget as it runs."""

from __future__ import annotations

import math

from raytrace.solver.budget import Budget
from service import costs
from service.admission import admit, trace_knobs
from service.schemas.tracking import DEFAULT_EVALUATE_RAYS, MAX_EVALUATE_RUN_STEPS, EvaluateRequest, TrackRequest

#: Particles x observations per request (work bound).
MAX_PARTICLE_STEPS = 20_000_000


def track_cost(req: TrackRequest, settings) -> costs.Cost:
    """The particle filter's particles x observations steps (:func:`service.costs.particles`); a Kalman
    track is linear in the (schema-bounded) observations."""
    return costs.particles(req.config.particles, len(req.observations), settings, MAX_PARTICLE_STEPS)


def run_track(req: TrackRequest, registry, budget: Budget, settings=None) -> dict:
    from tracking import (
        TRACKERS,
        Observation,
        RfFix,
        TrackerConfig,
        TrackingInputError,
        VisualMotion,
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
    # the particle filter checks the budget at every step: past the deadline, or once the client left, it stops
    out = TRACKERS[req.tracker](line, obs, cfg, name=req.tracker, check=budget.charge)
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


def evaluate(req: EvaluateRequest, registry, settings, budget: Budget) -> dict:
    from evaluation.tracking import evaluate_tracking
    from service.operations.localize import field_cache_dir
    from tracking import JourneySpec, TrackingInputError

    if req.runs * req.journey.steps > MAX_EVALUATE_RUN_STEPS:
        raise TrackingInputError(f"runs x steps must be <= {MAX_EVALUATE_RUN_STEPS}", "runs")
    rays, interactions = trace_knobs(req.rays, req.max_interactions, settings, default_rays=DEFAULT_EVALUATE_RAYS,
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
