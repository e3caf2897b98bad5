"""One scaling point, run in a fresh interpreter so its peak memory is its own.

``python -m bench.point --rays N --resolution R --receivers K --interactions M``
prints one JSON line: trace time (warm: the scene and phantom are built and
traced once before timing), phantom build time, triangles, segments, paths,
peak RSS and the RSS before tracing.
"""

from __future__ import annotations

import argparse
import json
import resource
import time

from bench import scenes
from raytrace.tracer import trace_channel


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--resolution", type=int, default=None)
    ap.add_argument("--receivers", type=int, default=None)
    ap.add_argument("--interactions", type=int, default=6)
    ap.add_argument("--frequency", type=float, default=402e6)
    a = ap.parse_args()
    t0 = time.perf_counter()
    phantom = scenes.torso(a.resolution)
    build_s = time.perf_counter() - t0
    tx = scenes.transmitter(phantom)
    rx = scenes.receivers(phantom, a.receivers)
    before_mb = _rss_mb()
    kwargs = dict(rays=a.rays, max_interactions=a.interactions)
    trace_channel(phantom, tx, rx[:1], a.frequency, rays=1000, max_interactions=1)  # warm the scene
    t0 = time.perf_counter()
    result = trace_channel(phantom, tx, rx, a.frequency, **kwargs)
    trace_s = time.perf_counter() - t0
    print(json.dumps({
        "rays": a.rays, "resolution": a.resolution, "receivers": len(rx), "interactions": a.interactions,
        "triangles": phantom.triangle_count, "build_s": build_s, "trace_s": trace_s,
        "ray_segments": result.stats.ray_segments_traced, "paths": result.stats.paths_found,
        "rss_before_trace_mb": before_mb, "peak_rss_mb": _rss_mb(),
    }))


if __name__ == "__main__":
    main()
