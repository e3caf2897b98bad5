"""POST /v1/localize and /v1/localize/evaluate: the capsule's position from several sensors
(docs/localization.md, docs/api.md "Localization"). Thin handlers: the models are in
:mod:`service.schemas.localize`, the work in :mod:`service.operations.localize`.
"""

from __future__ import annotations

from fastapi import APIRouter, Request

from raytrace import Budget
from service import costs
from service.admission import declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import error_responses
from service.operations.localize import evaluate, localize
from service.schemas.localize import (
    LocalizeEvaluateRequest,
    LocalizeEvaluateResponse,
    LocalizeRequest,
    LocalizeResponse,
)

router = APIRouter(prefix="/v1/localize", tags=["localization"], route_class=ThreadedJsonRoute)

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
