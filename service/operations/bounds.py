"""The work of POST /v1/bounds/{toa,pdoa,rss}: closed-form Cramér-Rao bounds (docs/science.md "Bounds"),
thin wrappers over :mod:`estimators.bounds` (the SNR from the request or its link budget)."""

from __future__ import annotations

import math

from estimators import bounds
from estimators.link import LinkBudget
from service.errors import Unprocessable
from service.schemas.ranging import PdoaBoundRequest, RssBoundRequest, ToaBoundRequest


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


def toa_bound(req: ToaBoundRequest) -> dict:
    """A ToaBoundResponse's fields (thesis Eq 4.16-4.17)."""
    snr = _snr_db(req, req.bandwidth_hz)
    b = bounds.toa_crlb(req.carrier_hz, req.duration_s, req.bandwidth_hz, snr, req.relative_permittivity, req.delay_s)
    return {**_finite({"sigma_s": b.sigma_s, "sigma_m": b.sigma_m}), "snr_db": snr}


def pdoa_bound(req: PdoaBoundRequest) -> dict:
    """A PdoaBoundResponse's fields (thesis Eq 5.16)."""
    snr = _snr_db(req, req.tone_spacing_hz)
    b = bounds.pdoa_crlb(req.center_hz, req.tone_spacing_hz, snr, req.duration_s, req.relative_permittivity)
    return {**_finite({"sigma_s": b.sigma_s, "sigma_m": b.sigma_m,
                       "sigma_phase_difference_s": b.sigma_phase_difference_s,
                       "sigma_phase_difference_m": b.sigma_phase_difference_m}), "snr_db": snr}


def rss_bound(req: RssBoundRequest) -> dict:
    """A RssBoundResponse's fields: sigma_d >= ln(10) sigma d / (10 n)."""
    b = bounds.rss_crlb(req.shadowing_db, req.path_loss_exponent, req.distance_m)
    return _finite({"sigma_m": b.sigma_m})
