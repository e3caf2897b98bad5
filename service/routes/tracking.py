"""POST /v1/track (measured sequences -> trajectory along the GI tract with uncertainty) and
POST /v1/track/evaluate (the built-in journey experiment), docs/tracking.md. Thin handlers: the
models are in :mod:`service.schemas.tracking`, the work (in a worker thread under the server's
deadline, bounds checked before any work) in :mod:`service.operations.tracking`."""

from __future__ import annotations

from fastapi import APIRouter, Request

from raytrace.solver.budget import Budget
from service.admission import declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import error_responses
from service.operations.tracking import evaluate, run_track, track_cost, track_evaluate_cost
from service.schemas.tracking import EvaluateRequest, EvaluateResponse, TrackRequest, TrackResponse

router = APIRouter(prefix="/v1/track", tags=["tracking"], route_class=ThreadedJsonRoute)
_ERRORS = error_responses(400, 404, 413, 422, 503, 504)


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
    out = await st.gate.run(lambda budget: evaluate(req, st.registry, st.settings, budget),
                            Budget(deadline_s=st.settings.request_deadline_s), disconnected=request.is_disconnected)
    return EvaluateResponse.model_validate(out)
