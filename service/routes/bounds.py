"""Closed-form Cramér-Rao bounds (docs/science.md "Bounds"): thin wrappers over estimators.bounds."""

from __future__ import annotations

import math

from fastapi import APIRouter

from estimators import bounds
from estimators.link import LinkBudget
from service.admission import declare
from service.bodies import ThreadedJsonRoute
from service.errors import Unprocessable, error_responses
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


def _snr_db(req: ToaBoundRequest | PdoaBoundRequest, bandwidth_hz: float) -> float:
    """The request's snr_db, or the one its link gives over ``bandwidth_hz`` (docs/science.md (S24))."""
    if req.link is None:
        if req.snr_db is None:
            raise Unprocessable("give snr_db, or link with path_gain_db", loc=["body", "snr_db"])
        return req.snr_db
    if req.snr_db is not None:
        raise Unprocessable("give snr_db or link, not both (the link budget sets the SNR)", loc=["body", "link"])
    if req.path_gain_db is None:
        raise Unprocessable("required with link (the channel's power gain, a profile's path_gain_db)",
                            loc=["body", "path_gain_db"])
    return LinkBudget(**req.link.model_dump()).snr_db(req.path_gain_db, bandwidth_hz)


def _finite(values: dict[str, float]) -> dict[str, float]:
    for key, value in values.items():
        if not math.isfinite(value):
            raise Unprocessable(
                f"these inputs give a non-finite bound ({key} = {value}); use a larger snr_db or duration_s",
                loc=["body", "snr_db"],
            )
    return values


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
    snr = _snr_db(req, req.bandwidth_hz)
    b = bounds.toa_crlb(req.carrier_hz, req.duration_s, req.bandwidth_hz, snr, req.relative_permittivity, req.delay_s)
    return ToaBoundResponse(**_finite({"sigma_s": b.sigma_s, "sigma_m": b.sigma_m}), snr_db=snr)


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
    snr = _snr_db(req, req.tone_spacing_hz)
    b = bounds.pdoa_crlb(req.center_hz, req.tone_spacing_hz, snr, req.duration_s, req.relative_permittivity)
    return PdoaBoundResponse(
        **_finite(
            {
                "sigma_s": b.sigma_s,
                "sigma_m": b.sigma_m,
                "sigma_phase_difference_s": b.sigma_phase_difference_s,
                "sigma_phase_difference_m": b.sigma_phase_difference_m,
            }
        ),
        snr_db=snr,
    )


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
    b = bounds.rss_crlb(req.shadowing_db, req.path_loss_exponent, req.distance_m)
    return RssBoundResponse(**_finite({"sigma_m": b.sigma_m}))
