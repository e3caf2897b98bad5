"""POST /v1/channel: ray-trace a scenario (in a worker thread, under a budget)."""

from __future__ import annotations

import json

from fastapi import APIRouter, Request, Response

from raytrace import Budget, trace_channel
from service import costs
from service.admission import declare
from service.bodies import ThreadedJsonRoute
from service.deps import state
from service.errors import error_responses
from service.operations import channel as channel_ops
from service.schemas.channel import ChannelRequest, ChannelResponse

router = APIRouter(prefix="/v1", tags=["channel"], route_class=ThreadedJsonRoute)


@router.post(
    "/channel",
    response_model=ChannelResponse,
    operation_id="compute_channel",
    summary="Ray-trace the channel from a capsule to skin sensors",
    responses=error_responses(400, 404, 413, 422, 503, 504),
)
@declare(body="max_json_body_bytes", cost=costs.channel)
async def compute_channel(req: ChannelRequest, request: Request) -> Response:
    """Every path (reflections, refractions, total internal reflections up to
    `max_interactions`) from the transmitter to each receiver, with absolute
    delays and complex gains (|a|^2 = power transfer between the antennas),
    sorted by delay. Geometric optics: organs comparable to the wavelength
    (about 100 mm in muscle at 402 MHz) make it an approximation.

    Runs in a worker thread; when all slots are busy the answer is 503 with
    Retry-After at once. A computation that exceeds the server's deadline
    stops itself (504); one over the work budget gets 503 with a message
    saying what to lower."""
    st = state(request)

    def work(budget: Budget) -> tuple[dict, bytes]:
        spec, phantom = channel_ops.to_spec(req, st.registry, st.settings)
        result = trace_channel(spec, phantom, budget=budget, config=st.settings.tracer_config())
        out = channel_ops.result_to_dict(result, req.scenario, req.outputs)
        # serialised here, in the worker: a 12-sensor answer is ~0.75 MB, and building the pydantic
        # model of its ~500 paths took 0.12 s that would block the event loop; result_to_dict
        # writes exactly ChannelResponse's fields (finite numbers only: allow_nan=False raises
        # rather than send NaN), checked against the model in tests/service/test_api.py
        return out["stats"], json.dumps(out, allow_nan=False, separators=(",", ":")).encode()

    budget = Budget(deadline_s=st.settings.request_deadline_s, max_ray_segments=st.settings.max_ray_segments,
                    max_bytes=st.settings.compute_memory_share_bytes)
    stats, body = await st.gate.run(work, budget, disconnected=request.is_disconnected)
    st.metrics.rays.inc(stats["rays_launched"])
    st.metrics.segments.inc(stats["ray_segments_traced"])
    st.metrics.paths.inc(stats["paths_found"])
    return Response(content=body, media_type="application/json")
