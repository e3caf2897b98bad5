"""Closed-form Cramér-Rao bounds (docs/science.md "Bounds"): thin handlers over
:mod:`service.operations.bounds` (which wraps estimators.bounds)."""

from __future__ import annotations

from fastapi import APIRouter

from service.admission import declare
from service.bodies import ThreadedJsonRoute
from service.errors import error_responses
from service.operations.bounds import pdoa_bound, rss_bound, toa_bound
from service.schemas.ranging import (
    PdoaBoundRequest,
    PdoaBoundResponse,
    RssBoundRequest,
    RssBoundResponse,
    ToaBoundRequest,
    ToaBoundResponse,
)

router = APIRouter(prefix="/v1/bounds", tags=["bounds"], route_class=ThreadedJsonRoute)

#: A bound's cost: a closed form of a few scalars, O(1) work and memory whatever the (schema-bounded) input.
CLOSED_FORM = "closed form: O(1) work and memory"


@router.post(
    "/toa",
    response_model=ToaBoundResponse,
    operation_id="bound_toa",
    summary="TOA CRLB of a single tone (thesis Eq 4.16-4.17)",
    responses=error_responses(400, 413, 422),
)
@declare(body="max_json_body_bytes", cost=CLOSED_FORM)
async def bound_toa(req: ToaBoundRequest) -> ToaBoundResponse:
    """sigma_tau^2 = Is / (2 SNR W T0 Itau) for A cos(w (t - tau)) observed for T0
    (w = 2 pi f; the thesis listing's f-for-w slip is corrected), sigma_m = v sigma_tau.
    The SNR is `snr_db`, or P_t + G - kTBF over `bandwidth_hz` from `link` and `path_gain_db`."""
    return ToaBoundResponse(**toa_bound(req))


@router.post(
    "/pdoa",
    response_model=PdoaBoundResponse,
    operation_id="bound_pdoa",
    summary="Two-tone PDOA CRLB (thesis Eq 5.16, E/N0 = SNR W T0)",
    responses=error_responses(400, 413, 422),
)
@declare(body="max_json_body_bytes", cost=CLOSED_FORM)
async def bound_pdoa(req: PdoaBoundRequest) -> PdoaBoundResponse:
    """sigma_s = [8 pi^2 (f0^2 + W^2/4) E/N0]^(-1/2) (carrier ambiguity resolved) and the
    phase-difference-only bound from the W^2/4 term; distances by v = c / sqrt(eps_r).
    The SNR is `snr_db`, or P_t + G - kTBF over the tone spacing from `link` and `path_gain_db`."""
    return PdoaBoundResponse(**pdoa_bound(req))


@router.post(
    "/rss",
    response_model=RssBoundResponse,
    operation_id="bound_rss",
    summary="RSS CRLB under log-normal shadowing",
    responses=error_responses(400, 413, 422),
)
@declare(body="max_json_body_bytes", cost=CLOSED_FORM)
async def bound_rss(req: RssBoundRequest) -> RssBoundResponse:
    """sigma_d >= ln(10) sigma d / (10 n)."""
    return RssBoundResponse(**rss_bound(req))
