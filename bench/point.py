"""One scaling point, run in a fresh interpreter so its peak memory is its own.

``python -m bench.point --rays N --resolution R --receivers K --interactions M``
prints one JSON line: trace time (warm: the scene and phantom are built and
traced once before timing), phantom build time, triangles, segments, paths,
peak RSS and the RSS before tracing.
"""

from __future__ import annotations

import argparse
import gc
import json
import resource
import sys
import time

from bench import scenes


def peak_rss_mb() -> float:
    """Peak resident memory of this process's own address space [MB].

    Linux: ``VmHWM`` from /proc/self/status. Not ``getrusage().ru_maxrss``: the
    kernel folds the parent's high-water mark into it at ``execve`` (the forked
    copy of the parent's memory counts), so a point launched from a bench that
    had grown to 460 MB reported at least 460 MB whatever it used. Elsewhere
    ``ru_maxrss`` is the fallback (kilobytes on Linux/BSD, bytes on macOS)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    scale = 1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale


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
    before_mb = peak_rss_mb()
    kwargs = dict(rays=a.rays, max_interactions=a.interactions)
    scenes.trace(phantom, tx, rx[:1], a.frequency, rays=1000, max_interactions=1)  # warm the scene
    gc.freeze()  # as the service does after start-up (bench/__main__.py)
    t0 = time.perf_counter()
    result = scenes.trace(phantom, tx, rx, a.frequency, **kwargs)
    trace_s = time.perf_counter() - t0
    print(json.dumps({
        "rays": a.rays, "resolution": a.resolution, "receivers": len(rx), "interactions": a.interactions,
        "triangles": phantom.triangle_count, "build_s": build_s, "trace_s": trace_s,
        "ray_segments": result.stats.ray_segments_traced, "paths": result.stats.paths_found,
        "rss_before_trace_mb": before_mb, "peak_rss_mb": peak_rss_mb(),
    }))


if __name__ == "__main__":
    main()
