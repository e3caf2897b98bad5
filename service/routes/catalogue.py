"""Catalogue: tissues at a frequency, built-in scenarios."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, Query, Request

from raytrace.physics import em
from raytrace.physics.tissues import TISSUE_NAMES, dielectric
from service.deps import state
from service.errors import error_responses
from service.schemas import FREQUENCY_MAX_HZ, FREQUENCY_MIN_HZ
from service.schemas.phantoms import ScenarioOut, ScenariosResponse, TissueOut, TissuesResponse

router = APIRouter(prefix="/v1", tags=["catalogue"])


@router.get(
    "/tissues",
    response_model=TissuesResponse,
    operation_id="list_tissues",
    summary="Dielectric properties of every tissue at a frequency",
    responses=error_responses(422),
)
async def list_tissues(
    frequency_hz: float = Query(
        ...,
        ge=FREQUENCY_MIN_HZ,
        le=FREQUENCY_MAX_HZ,
        allow_inf_nan=False,
        description="Frequency [Hz], within the Gabriel 1996 model's 10 Hz - 20 GHz.",
        examples=[402e6],
    ),
) -> TissuesResponse:
    """Gabriel 1996 relative permittivity, conductivity and loss tangent of every
    tissue (plus air), and the propagation constants they imply: phase velocity,
    attenuation and wavelength of a plane wave in the tissue."""
    tissues = []
    for name in TISSUE_NAMES:
        d = dielectric(name, frequency_hz)
        eps = d.complex_relative_permittivity
        tissues.append(
            TissueOut(
                name=name,
                relative_permittivity=float(d.relative_permittivity),
                conductivity_s_per_m=float(d.conductivity_s_per_m),
                loss_tangent=float(d.loss_tangent),
                phase_velocity_m_per_s=float(np.asarray(em.phase_velocity_m_per_s(eps, frequency_hz))),
                attenuation_db_per_m=float(np.asarray(em.attenuation_db_per_m(eps, frequency_hz))) + 0.0,
                wavelength_m=float(np.asarray(em.wavelength_m(eps, frequency_hz))),
            )
        )
    return TissuesResponse(frequency_hz=frequency_hz, tissues=tissues)


@router.get(
    "/scenarios",
    response_model=ScenariosResponse,
    operation_id="list_scenarios",
    summary="Built-in scenarios",
)
async def list_scenarios(request: Request) -> ScenariosResponse:
    """Built-in scenarios: each supplies a phantom, antennas and a frequency for
    POST /v1/channel (`{"scenario": "<id>"}`); explicit request fields override it."""
    reg = state(request).registry
    return ScenariosResponse(
        scenarios=[
            ScenarioOut(
                id=s.id,
                description=s.description,
                phantom=s.spec.phantom,
                frequency_hz=s.spec.frequency_hz,
                notes=s.notes,
                request=s.spec.to_dict(),
            )
            for s in sorted(reg.scenarios.values(), key=lambda s: s.id)
        ]
    )
