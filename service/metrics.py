"""Prometheus metrics of one app instance (own registry, so tests can build many apps).

With several uvicorn workers each process has its own counters; scrape each
worker or run one worker per container (the default).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST

__all__ = ["Metrics", "CONTENT_TYPE_LATEST"]


@dataclass
class Metrics:
    registry: CollectorRegistry = field(default_factory=lambda: CollectorRegistry(auto_describe=True))

    def __post_init__(self) -> None:
        r = self.registry
        self.requests = Counter(
            "capsule_rt_http_requests_total", "HTTP requests by route template and status.",
            ["method", "route", "status"], registry=r,
        )
        self.latency = Histogram(
            "capsule_rt_http_request_duration_seconds", "HTTP request latency by route template [s].",
            ["method", "route"], registry=r,
            buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120),
        )
        self.rays = Counter("capsule_rt_rays_launched_total", "Rays launched by channel computations.", registry=r)
        self.segments = Counter(
            "capsule_rt_ray_segments_traced_total", "Ray segments (ray casts) traced.", registry=r
        )
        self.paths = Counter("capsule_rt_paths_found_total", "Propagation paths found.", registry=r)
        self.in_flight = Gauge(
            "capsule_rt_compute_in_flight", "Heavy computations running in worker threads.", registry=r
        )
        self.waiting = Gauge(
            "capsule_rt_compute_queue_depth", "Heavy computations admitted and waiting for a thread.", registry=r
        )
        self.rejected = Counter(
            "capsule_rt_compute_rejected_total", "Heavy requests answered 503 because the server was saturated.",
            registry=r,
        )
        self.budget_exceeded = Counter(
            "capsule_rt_budget_exceeded_total", "Computations stopped by their budget.", ["kind"], registry=r
        )
        self.phantoms = Gauge("capsule_rt_phantoms", "Phantoms available.", ["kind"], registry=r)

    def render(self) -> bytes:
        return generate_latest(self.registry)
