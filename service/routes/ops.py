"""Operations: liveness, readiness, Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response

from service.deps import state
from service.metrics import CONTENT_TYPE_LATEST
from service.schemas import Health, Readiness

router = APIRouter(tags=["operations"])


@router.get("/healthz", response_model=Health, operation_id="healthz", summary="Liveness")
async def healthz() -> Health:
    """Answers as long as the event loop runs (never waits for a computation)."""
    return Health(status="ok")


@router.get(
    "/readyz",
    response_model=Readiness,
    operation_id="readyz",
    summary="Readiness",
    responses={503: {"model": Readiness, "description": "Still loading the phantoms."}},
)
async def readyz(request: Request):
    """Ready once the built-in phantoms are built and the ray engine (Embree) is available."""
    st = state(request)
    engine = _ray_engine()
    ready = st.registry.ready and engine != "unavailable"
    body = Readiness(
        status="ready" if ready else "starting",
        phantoms=len(st.registry.builtins) + st.registry.upload_count(),
        scenarios=len(st.registry.scenarios),
        ray_engine=engine,
        errors=list(st.registry.errors),
    )
    if not ready:
        return JSONResponse(body.model_dump(), status_code=503, headers={"Retry-After": "1"})
    return body


def _ray_engine() -> str:
    try:
        import embreex  # noqa: F401
        from trimesh.ray import has_embree

        return "embree" if has_embree else "unavailable"
    except Exception:  # pragma: no cover
        return "unavailable"


@router.get(
    "/metrics",
    operation_id="metrics",
    summary="Prometheus metrics",
    response_class=Response,
    responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}},
                     "description": "Prometheus text format."}},
)
async def metrics(request: Request) -> Response:
    st = state(request)
    st.metrics.phantoms.labels("builtin").set(len(st.registry.builtins))
    st.metrics.phantoms.labels("uploaded").set(st.registry.upload_count())
    return Response(st.metrics.render(), media_type=CONTENT_TYPE_LATEST)
