"""The CapsuleRT FastAPI application (``service.app:app``) and its factory.

``create_app(settings)`` builds an independent app (own registry, metrics,
compute gate); tests build several with different limits.
"""

from __future__ import annotations

import gc
import logging
from contextlib import asynccontextmanager

import anyio.to_thread
from fastapi import FastAPI

from raytrace.solver.tracer import warm_up
from service import __version__
from service.compute import ComputeGate
from service.deps import AppState
from service.errors import install_error_handlers
from service.jobs import SweepJobs
from service.logs import configure_logging
from service.metrics import Metrics
from service.middleware import RequestContextMiddleware
from service.registry import Registry
from service.routes import bounds, catalogue, channel, ops, pages, phantoms, plots, ranging, sweeps
from service.settings import Settings
from service.storage import PhantomStore

log = logging.getLogger("capsule_rt.app")

DESCRIPTION = """\
CapsuleRT emulates in-body radio channels for locating a wireless capsule
endoscope: it ray-traces a torso phantom of lossy tissue meshes (Gabriel 1996
dielectric model, Fresnel/Snell at every organ boundary) and estimates the
capsule-to-sensor range by TOA, PDOA and RSS, with Cramér-Rao bounds.

Conventions: SI units, the unit in every field name; complex numbers are
`{"re": .., "im": ..}`; `NaN`/`Infinity` are rejected in requests and never
emitted (a zero gain is reported as -400 dB). Every error has a body
`{"detail": [{"loc": [...], "msg": "...", "type": "..."}]}` whose `loc`
names the offending field. Heavy requests (channel, ranging, uploads) run in
worker threads; a saturated server answers 503 with `Retry-After` at once.
"""

TAGS = [
    {"name": "channel", "description": "Ray-traced channel impulse responses."},
    {"name": "ranging", "description": "Monte Carlo TOA / PDOA / RSS ranging over a channel profile."},
    {"name": "bounds", "description": "Closed-form Cramér-Rao bounds."},
    {"name": "catalogue", "description": "Tissues and built-in scenarios."},
    {"name": "phantoms", "description": "Built-in and uploaded phantoms."},
    {"name": "plots", "description": "Figures of channels, bounds and ranging errors (PNG, SVG, PDF)."},
    {"name": "sweeps", "description": "Sweep jobs: positions x receivers x frequencies, run in worker processes."},
    {"name": "operations", "description": "Health, readiness, metrics."},
]


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    configure_logging(settings.log_level, settings.log_json)
    metrics = Metrics()
    registry = Registry(store=PhantomStore(settings.data_dir))
    gate = ComputeGate(settings.max_concurrency, settings.max_queue, settings.retry_after_s, metrics)
    sweep_jobs = SweepJobs(settings, registry)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if not registry.ready:
            await anyio.to_thread.run_sync(registry.load_builtins, settings.load_builtins)
        # compile (or load from cache) the tracer's kernels before /readyz says ready
        warm_up_s = await anyio.to_thread.run_sync(warm_up)
        # the ~140k objects of the start-up (numba's compiler, the phantoms, the app) never die:
        # move them out of the cyclic collector's sight, or each full collection walks them all
        # (~70 ms with the GIL held, about every fifth channel request; docs/tracer.md)
        gc.freeze()
        sweep_jobs.start()
        log.info(
            "ready",
            extra={"phantoms": registry.ids(), "scenarios": sorted(registry.scenarios), "data_dir": str(settings.data_dir),
                   "kernels_warm_up_s": round(warm_up_s, 3), "gc_frozen_objects": gc.get_freeze_count()},
        )
        try:
            yield
        finally:
            gate.cancel_all()
            await anyio.to_thread.run_sync(sweep_jobs.stop)

    app = FastAPI(
        title="CapsuleRT",
        version=__version__,
        description=DESCRIPTION,
        openapi_tags=TAGS,
        lifespan=lifespan,
        docs_url=None,  # /docs is served from packaged assets (service.routes.pages), redoc dropped
        redoc_url=None,
    )
    app.state.capsule = AppState(settings=settings, registry=registry, gate=gate, metrics=metrics)
    app.state.sweeps = sweep_jobs
    install_error_handlers(app, settings.retry_after_s)
    for module in (channel, ranging, bounds, plots, catalogue, phantoms, sweeps, ops):
        app.include_router(module.router)
    pages.install(app)
    app.add_middleware(RequestContextMiddleware, metrics=metrics)
    _document_manifest(app)
    return app


def _document_manifest(app: FastAPI) -> None:
    """Add the upload manifest's schema to the OpenAPI components (the multipart
    part is JSON text, so no route references the model directly)."""
    from service.schemas import Manifest

    generate = app.openapi

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = generate()
            model = Manifest.model_json_schema(ref_template="#/components/schemas/{model}")
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            components.update(model.pop("$defs", {}))
            components["Manifest"] = model
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _default_app() -> FastAPI:
    return create_app(Settings())


app = _default_app()
