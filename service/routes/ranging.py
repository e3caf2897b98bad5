"""POST /v1/ranging/{toa,pdoa,rss}: Monte Carlo ranging over a channel profile (worker thread)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from raytrace.solver.budget import Budget
from service.admission import declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import error_responses
from service.operations import ranging as ops
from service.schemas.ranging import PdoaRequest, RangingResponse, RssRequest, ToaRequest

router = APIRouter(prefix="/v1/ranging", tags=["ranging"], route_class=ThreadedJsonRoute)

_ERRORS = error_responses(400, 413, 422, 503, 504)


async def _run(request: Request, fn, req) -> RangingResponse:
    st = state(request)
    # the budget reaches the estimators' loops: past the deadline (504), or once the client
    # has gone (the gate cancels it), they stop at their next chunk
    out = await st.gate.run(
        lambda budget: fn(req, st.settings, budget),
        Budget(deadline_s=st.settings.request_deadline_s),
        disconnected=request.is_disconnected,
    )
    return RangingResponse.model_validate(out)


@router.post("/toa", response_model=RangingResponse, operation_id="ranging_toa", summary="TOA ranging",
             responses=_ERRORS)
@declare(body="max_ranging_body_bytes", cost=ops._check_toa_work)
async def ranging_toa(req: ToaRequest, request: Request) -> RangingResponse:
    """Transmit the waveform through the profile, add white Gaussian noise at `snr_db`,
    estimate the delay by first peak (Eq 4.18), all peaks (Eq 4.19-4.21) or generalized
    cross-correlation (Eq 4.22-4.24), and turn it into a distance with
    v = c / sqrt(relative_permittivity). `trials` noise realisations, seeded."""
    return await _run(request, ops.toa, req)


@router.post("/pdoa", response_model=RangingResponse, operation_id="ranging_pdoa", summary="PDOA ranging",
             responses=_ERRORS)
@declare(body="max_ranging_body_bytes", cost=ops.pdoa_cost)
async def ranging_pdoa(req: PdoaRequest, request: Request) -> RangingResponse:
    """Phase of the channel at two tones (Eq 5.3-5.5) or a regression of the unwrapped
    phase over N tones (slope = -2 pi tau), with noise; adds the unambiguous range and
    both bounds."""
    return await _run(request, ops.pdoa, req)


@router.post("/rss", response_model=RangingResponse, operation_id="ranging_rss", summary="RSS ranging",
             responses=_ERRORS)
@declare(body="max_ranging_body_bytes", cost="trials x tones (service.costs.tones): the schema bounds both")
async def ranging_rss(req: RssRequest, request: Request) -> RangingResponse:
    """Invert the IEEE 802.15.6 CM2 path-loss model (thesis Eq 2.2, Table 2.2) for the
    distance, with log-normal shadowing drawn per trial."""
    return await _run(request, ops.rss, req)
