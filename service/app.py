"""The CapsuleRT FastAPI application (``service.app:app``) and its factory.

``create_app(settings)`` builds an independent app (own registry, metrics,
compute gate); tests build several with different limits.
"""

from __future__ import annotations

import copy
import gc
import logging
from contextlib import asynccontextmanager

import anyio.to_thread
from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware

from raytrace.solver.tracer import warm_up
from service import __version__
from service.admission import Gate, Table
from service.compute import ComputeGate
from service.deps import AppState
from service.design_jobs import CoverageJobs, DesignEngine, LayoutJobs
from service.errors import install_error_handlers
from service.fullwave_jobs import FullwaveJobs
from service.jobs import JobRunner
from service.limits import Limits
from service.logs import configure_logging
from service.metrics import Metrics
from service.middleware import AllowedMethods, RequestContextMiddleware
from service.phantom_builds import PhantomBuilds
from service.registry import Registry
from service.routes import (
    bounds,
    catalogue,
    channel,
    design,
    fullwave,
    localize,
    ops,
    pages,
    phantoms,
    plots,
    ranging,
    sweeps,
    tracking,
    vision,
)
from service.security import API_KEY_HEADER, OriginGuard
from service.settings import Settings
from service.storage import PhantomStore
from service.sweep_jobs import SweepJobs

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

#: Every router of the API, in the order the app includes them.
ROUTERS = (channel, ranging, localize, bounds, plots, catalogue, phantoms, sweeps, fullwave, design, vision, tracking,
           ops)

TAGS = [
    {"name": "channel", "description": "Ray-traced channel impulse responses."},
    {"name": "ranging", "description": "Monte Carlo TOA / PDOA / RSS ranging over a channel profile."},
    {"name": "localization", "description": "The capsule's position from several sensors, with position bounds."},
    {"name": "bounds", "description": "Closed-form Cramér-Rao bounds."},
    {"name": "catalogue", "description": "Tissues and built-in scenarios."},
    {"name": "phantoms", "description": "Built-in and uploaded phantoms."},
    {"name": "plots", "description": "Figures of channels, bounds and ranging errors (PNG, SVG, PDF)."},
    {"name": "vision", "description": "The capsule camera's frames and MI motion tracking (thesis Ch. 3)."},
    {"name": "sweeps", "description": "Sweep jobs: positions x receivers x frequencies, run in worker processes."},
    {"name": "fullwave", "description": "Full-wave (gprMax FDTD) cross-checks of the tracer, as jobs on the sweeps' "
                                        "queue."},
    {"name": "design", "description": "Sensor-layout design: coverage over the skin and optimised sensor positions "
                                      "along the GI tract, as jobs on the one queue."},
    {"name": "operations", "description": "Health, readiness, metrics."},
]


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    configure_logging(settings.log_level, settings.log_json)
    metrics = Metrics()
    registry = Registry(store=PhantomStore(settings.data_dir))
    gate = ComputeGate(settings.max_concurrency, settings.max_queue, settings.retry_after_s, metrics)
    jobs = JobRunner(settings.data_dir)  # one queue and one runner for every kind of job
    sweep_jobs = SweepJobs(settings, registry, jobs)
    fullwave_jobs = FullwaveJobs(settings, registry, jobs)
    phantom_builds = PhantomBuilds(settings, registry, jobs)
    design_engine = DesignEngine(settings)  # one warm pool for both design kinds (docs/design.md)
    coverage_jobs = CoverageJobs(settings, registry, jobs, design_engine)
    layout_jobs = LayoutJobs(settings, registry, jobs, design_engine, coverage_jobs)

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
        jobs.start()
        log.info(
            "ready",
            extra={"phantoms": registry.ids(), "scenarios": sorted(registry.scenarios),
                   "data_dir": str(settings.data_dir), "kernels_warm_up_s": round(warm_up_s, 3),
                   "gc_frozen_objects": gc.get_freeze_count()},
        )
        try:
            yield
        finally:
            gate.cancel_all()
            await anyio.to_thread.run_sync(jobs.stop)

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
    app.state.fullwave = fullwave_jobs
    app.state.phantom_builds = phantom_builds
    app.state.coverage = coverage_jobs
    app.state.layout = layout_jobs
    install_error_handlers(app, settings.retry_after_s)
    for module in ROUTERS:
        app.include_router(module.router)
    pages.install(app)
    table = Table.of(app.router.routes)  # every route the app serves, whatever included it
    app.state.declarations = table
    # outermost last: request id and metrics see every answer, CORS answers its preflights,
    # then foreign-origin writes are refused, every write gets its declaration (service.admission:
    # the API key, then its body capped while it streams in), and OPTIONS / 405 get the contract's Allow
    app.add_middleware(AllowedMethods, openapi=lambda: app.openapi())  # the documented one, see _document
    app.add_middleware(Gate, table=lambda: table, settings=settings)
    app.add_middleware(OriginGuard, settings=settings)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "DELETE"],
            allow_headers=["Content-Type", API_KEY_HEADER, "X-Request-ID"],
            expose_headers=["X-Request-ID", "Retry-After", "Location"],
        )
    app.add_middleware(RequestContextMiddleware, metrics=metrics)
    _document(app, settings, table)
    return app


def _document(app: FastAPI, settings: Settings, table: Table) -> None:
    """The served OpenAPI document says what this server enforces: the manifest's schema is
    added to the components (the multipart part is JSON text, so no route references the
    model); limits lowered by settings replace the schema's ceilings (examples follow;
    service.limits); with
    API keys configured, the operations they guard (service.admission: uploads, jobs, deletes)
    declare the key."""
    from service.schemas.phantoms import Manifest

    generate = app.openapi

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = copy.deepcopy(generate())  # route-level dicts (the sweep spec's) are shared by every app
            model = Manifest.model_json_schema(ref_template="#/components/schemas/{model}")
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            components.update(model.pop("$defs", {}))
            components["Manifest"] = model
            Limits.of(settings).lower_schema(schema)  # every bound a setting lowers (service.limits)
            if settings.api_keys:
                schema["components"]["securitySchemes"] = {
                    "ApiKey": {"type": "apiKey", "in": "header", "name": API_KEY_HEADER}}
                for path, method in table.keyed():
                    operation = schema["paths"].get(path, {}).get(method.lower())
                    if operation is not None:
                        operation["security"] = [{"ApiKey": []}]
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _default_app() -> FastAPI:
    return create_app(Settings())


app = _default_app()
