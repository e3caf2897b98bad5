"""Run every CapsuleRT benchmark, print a table, write bench/results/latest.json.

    python -m bench            # full run (several minutes on 2 cores)
    python -m bench --quick    # small sizes: a smoke run of every benchmark
    python -m bench --skip-http
    python -m bench --skip-vision   # without the visual motion evaluation (bench/vision.py)
    python -m bench --sionna        # also CapsuleRT against Sionna RT on a room (bench/sionna_room.py;
                                    # installs Sionna into its own virtual environment on first use)
    python -m bench --no-readme     # a full run that leaves README.md as it is

A full run (``make bench``) rewrites the table of README.md's PERFORMANCE section (between its
``bench:start`` / ``bench:end`` markers) from the report (bench/readme.py): the README's
numbers are this command's, never typed in.

Every number that matters is printed as a ratio to a reference measured in the
same run (the raw Embree ray rate on the same mesh) or as a growth exponent, in
wall time and in CPU time (less disturbed by other work on a shared machine; the
load average is printed with them); the targets of the performance issue are
printed beside them, never asserted.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import sys
import time

import numpy as np

from bench import (
    ceiling,
    completeness,
    estimators_bench,
    latency,
    localization,
    readme,
    scene_build,
    scenes,
    sweeps_cluster,
    vision,
)
from bench import sweeps as sweeps_bench
from bench.common import ROOT, growth_exponent, run_point
from raytrace.solver.tracer import warm_up


def tracer_throughput(rays: int, interactions: int, repeat: int) -> dict:
    """Ray segments per second of the default all-sensor trace: its best of ``repeat`` runs
    (the least disturbed, as the ceiling's best of as many repeats), and its median; in wall
    time and in CPU time (every thread of this process)."""
    phantom = scenes.torso()
    tx = scenes.transmitter(phantom)
    rx = scenes.receivers(phantom)
    scenes.trace(phantom, tx, rx[:1], 402e6, rays=1000, max_interactions=1)  # build the scene
    times, cpus, result = [], [], None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        result = scenes.trace(phantom, tx, rx, 402e6, rays=rays, max_interactions=interactions)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    elapsed, median = min(times), float(np.median(times))
    seg = result.stats.ray_segments_traced  # the same every run (deterministic)
    return {"rays": rays, "max_interactions": interactions, "receivers": len(rx), "repeat": repeat,
            "elapsed_s": elapsed, "elapsed_median_s": median, "ray_segments": seg, "segments_per_s": seg / elapsed,
            "segments_per_s_median": seg / median, "cpu_s": min(cpus), "cpu_median_s": float(np.median(cpus)),
            "segments_per_cpu_s": seg / min(cpus), "paths": result.stats.paths_found,
            "triangles": phantom.triangle_count}


def scaling(quick: bool) -> dict:
    rays = [10_000, 30_000, 100_000] if quick else [10_000, 30_000, 100_000, 300_000, 1_000_000]
    resolutions = [24, 48, 96] if quick else [24, 48, 96, 160, 256]
    receivers = [1, 8, 32] if quick else [1, 2, 8, 16, 32, 64]
    out = {"rays": [], "triangles": [], "receivers": []}
    for n in rays:
        out["rays"].append(run_point(["--rays", str(n)]))
    for r in resolutions:
        out["triangles"].append(run_point(["--rays", "100000", "--resolution", str(r)]))
    for k in receivers:
        out["receivers"].append(run_point(["--rays", "100000", "--receivers", str(k)]))
    out["exponent_time_vs_rays"] = growth_exponent(rays, [p["trace_s"] for p in out["rays"]])
    out["exponent_time_vs_triangles"] = growth_exponent(
        [p["triangles"] for p in out["triangles"]], [p["trace_s"] for p in out["triangles"]])
    out["exponent_time_vs_receivers"] = growth_exponent(receivers, [p["trace_s"] for p in out["receivers"]])
    return out


def rows(report: dict) -> list[tuple[str, str, str]]:
    """The table of a report, ``(measure, value, target)`` per row: what ``python -m bench``
    prints and what it writes into README.md (bench/readme.py)."""
    out: list[tuple[str, str, str]] = []

    def row(name: str, value: str, target: str = "") -> None:
        out.append((name, value, target))

    c, t, li = report["ceiling"], report["tracer"], report["latency_in_process"]
    row(f"Embree ceiling, {c['threads']} threads [rays/s]", f"{c['rays_per_s']:.3e}")
    row("  same rays, robust scene / embreex run() [rays/s]",
         f"{c['robust_rays_per_s']:.2e} / {c['embreex_rays_per_s']:.2e}")
    row(f"tracer, best / median of {t['repeat']} [ray segments/s]",
         f"{t['segments_per_s']:.2e} / {t['segments_per_s_median']:.2e}")
    row("tracer / ceiling (best / median trace)", f"{t['ratio_to_ceiling']:.2f} / {t['ratio_to_ceiling_median']:.2f}",
         "target >= 0.6")
    row("the same per CPU-second: ceiling [rays/CPU-s] / tracer / ratio",
         f"{c['rays_per_cpu_s']:.2e} / {t['segments_per_cpu_s']:.2e} / {t['ratio_to_ceiling_cpu']:.2f}",
         "target >= 0.75")
    row("all-sensor request CPU / its segments at the ceiling's CPU rate",
         f"{t['cpu_s']:.3f} / {t['floor_cpu_s']:.3f} s = {t['cpu_over_floor']:.2f}", "target <= 1.5")
    cp = report["completeness"]
    row(f"receivers missing the strongest path of {cp['dense_rays']:.0e} rays",
         f"{cp['strongest_missed']} / {cp['receivers']}")
    row("paths within 10 dB of the strongest found", f"{cp['strong_found']} / {cp['strong_paths']}")
    row("in-process channel, all sites p50 / p95 [s], CPU p50",
         f"{li['all_sensor_sites']['p50_s']:.3f} / {li['all_sensor_sites']['p95_s']:.3f}, "
         f"{li['all_sensor_sites']['cpu_p50_s']:.3f}", "target p50 <= 0.5")
    row("in-process channel, one receiver p50 / p95 [s], CPU p50",
         f"{li['one_receiver']['p50_s']:.3f} / {li['one_receiver']['p95_s']:.3f}, "
         f"{li['one_receiver']['cpu_p50_s']:.3f}", "target <= 0.3")
    row("in-process first trace (cold) [s]", f"{li['cold_first_trace_s']:.3f}")
    if "latency_http" in report:
        lh = report["latency_http"]
        row("HTTP channel, all sites p50 / p95 [s]",
             f"{lh['all_sensor_sites']['p50_s']:.3f} / {lh['all_sensor_sites']['p95_s']:.3f}", "target p50 <= 0.5")
        row("HTTP channel, one receiver p50 / p95 [s]",
             f"{lh['one_receiver']['p50_s']:.3f} / {lh['one_receiver']['p95_s']:.3f}", "target <= 0.3")
        row("service cold start to /readyz [s]", f"{lh['cold_start_s']:.2f}", "target <= 5")
        row("HTTP first channel request (cold) [s]", f"{lh['cold_first_request_s']:.3f}")
    if "scaling" in report:
        s = report["scaling"]
        row("time ~ rays^k", f"k = {s['exponent_time_vs_rays']:.2f}", "target ~1 (linear)")
        row("time ~ triangles^k", f"k = {s['exponent_time_vs_triangles']:.2f}", "target < 1 (BVH)")
        row("time ~ receivers^k", f"k = {s['exponent_time_vs_receivers']:.2f}", "target ~0")
        default_point = min(s["rays"], key=lambda p: abs(p["rays"] - 100_000))
        row("peak RSS, default request [MB]", f"{default_point['peak_rss_mb']:.0f}", "target <= 1024")
        for key, label in (("rays", "rays"), ("triangles", "triangles"), ("receivers", "receivers")):
            for p in s[key]:
                x = p["triangles"] if key == "triangles" else p[key]
                row(f"  {label} = {x}", f"{p['trace_s']:.3f} s {p['peak_rss_mb']:.0f} MB")
    for k, v in report["estimators"].items():
        row(k.replace("_", " "), f"{v:.3e}")
    localization.print_rows(report["localization"], row)
    if "sweeps" in report:
        sweeps_bench.print_rows(report["sweeps"], row)
    if "sweeps_cluster" in report:
        sweeps_cluster.print_rows(report["sweeps_cluster"], row)
    if "scene_build" in report:
        scene_build.print_rows(report["scene_build"], row)
    for r in report.get("sionna_room", []):
        found = (f"; oracle paths found {r['capsule_found']} / {r['sionna_found']} of {r['oracle_paths']}"
                 if "oracle_paths" in r else "")
        row(f"vs Sionna RT: {r['scene']}, depth {r['depth']}, {r['receivers']} rx: CPU / wall ratio, paths",
            f"{r['cpu_ratio']:.2f} / {r['ratio']:.2f}; {r['capsule_paths']} / {r['sionna_paths']}{found}",
            "target CPU <= 1")
    if "vision" in report:
        vs = report["vision"]["speed"]
        row("vision: 512 x 512 pair, rotation + scale, p50 [ms]", f"{vs['pair_512_both_s'] * 1e3:.0f}", "target < 100")
        row("vision: render one 256 x 256 frame, p50 [ms]", f"{vs['render_256_s'] * 1e3:.0f}", "target < 50")
    row("load average at the start / end", f"{report['load_start']:.1f} / {report['load_end']:.1f}")
    return out


def _argv_without_out(argv: list[str]) -> list[str]:
    """The options of this run as the README names them (``--out`` and its file left out)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--out":
            skip = True
        elif not a.startswith("--out="):
            out.append(a)
    return out


def _row(name, value, target=""):
    print(f"  {name:<52} {value:>16}  {target}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    ap.add_argument("--skip-http", action="store_true", help="skip the HTTP latency benchmark")
    ap.add_argument("--skip-scaling", action="store_true", help="skip the sub-process scaling sweep")
    ap.add_argument("--skip-sweeps", action="store_true", help="skip the sweep engines' throughput")
    ap.add_argument("--skip-vision", action="store_true", help="skip the visual motion evaluation (minutes)")
    ap.add_argument("--skip-cluster", action="store_true",
                    help="skip the sweep on separately started Dask processes (bench/sweeps_cluster.py)")
    ap.add_argument("--netns", action="store_true",
                    help="the Dask workers in their own network namespaces (root, iproute2)")
    ap.add_argument("--skip-scene-build", action="store_true",
                    help="skip the 1 M-triangle scene build against Embree's (bench/scene_build.py, minutes)")
    ap.add_argument("--no-readme", action="store_true", help="do not rewrite README.md's PERFORMANCE table")
    ap.add_argument("--sionna", action="store_true",
                    help="also the room against Sionna RT (bench/sionna_room.py; optional peer, own venv)")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "latest.json"))
    args = ap.parse_args()
    rays = 20_000 if args.quick else 100_000
    repeat = 3 if args.quick else 10
    report = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "platform": platform.platform()}, "quick": args.quick,
              "argv": _argv_without_out(sys.argv[1:])}

    phantom = scenes.torso()
    origin = phantom.sites[scenes.capsule_site(phantom)].position_m
    # as the service does once started (service/app.py): the start-up objects (numba's
    # compiler, the phantom) leave the cyclic collector's sight, so the in-process numbers
    # are the server's steady state, without a ~70 ms full collection every few traces
    warm_up()
    gc.freeze()
    report["load_start"] = os.getloadavg()[0]
    report["ceiling"] = ceiling.embree_ceiling(phantom, origin, rays, repeat=9)
    report["tracer"] = tracer_throughput(rays, 6, repeat=9)
    t, c = report["tracer"], report["ceiling"]
    t["ratio_to_ceiling"] = t["segments_per_s"] / c["rays_per_s"]
    t["ratio_to_ceiling_median"] = t["segments_per_s_median"] / c["rays_per_s"]
    t["ratio_to_ceiling_cpu"] = t["segments_per_cpu_s"] / c["rays_per_cpu_s"]
    t["floor_cpu_s"] = t["ray_segments"] / c["rays_per_cpu_s"]  # its segments at the ceiling's CPU rate
    t["cpu_over_floor"] = t["cpu_s"] / t["floor_cpu_s"]
    report["completeness"] = completeness.completeness(rays, 6)
    report["latency_in_process"] = latency.in_process(repeat, rays, 6)
    if not args.skip_http:
        report["latency_http"] = latency.over_http(repeat, rays, 6)
    if not args.skip_scaling:
        report["scaling"] = scaling(args.quick)
    report["estimators"] = estimators_bench.throughput(1000)
    report["localization"] = localization.localization(5 if args.quick else 20)
    if not args.skip_sweeps:
        report["sweeps"] = sweeps_bench.run(args.quick)
    if not args.skip_cluster:
        report["sweeps_cluster"] = sweeps_cluster.run(args.quick, netns=args.netns)
    if not args.skip_scene_build:
        report["scene_build"] = scene_build.run(96 if args.quick else 256, repeat=1 if args.quick else 2,
                                                phantom_breakdown=not args.quick)
    if not args.skip_vision:
        report["vision"] = vision.run(args.quick)
    sionna_status = None
    if args.sionna:  # its own table and JSON (bench/results/sionna_room.json); its ratios join the report
        from bench import sionna_room

        sionna_out = os.path.join(os.path.dirname(args.out), "sionna_room.json")
        sionna_status = sionna_room.main((["--repeat", "3"] if args.quick else []) + ["--out", sionna_out])
        if not sionna_status:
            with open(sionna_out) as fh:
                report["sionna_room"] = json.load(fh)["rows"]
    report["load_end"] = os.getloadavg()[0]

    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(report, fh, indent=2, default=float)

    c, t = report["ceiling"], report["tracer"]
    print(f"CapsuleRT benchmarks ({'quick' if args.quick else 'full'}) on {report['machine']['cpus']} CPUs, "
          f"default torso {c['triangles']} triangles, {t['receivers']} sensor sites, max_interactions 6")
    for name, value, target in rows(report):
        _row(name, value, target)
    if "vision" in report:
        print("  vision accuracy tables: python -m bench.vision (or 'vision' in the JSON)")

    print(f"wrote {os.path.relpath(args.out, ROOT)}")
    if not args.quick and not args.no_readme:
        readme.write(report, os.path.join(ROOT, "README.md"))
        print("README.md, PERFORMANCE: the table between its bench markers rewritten")
    if sionna_status:
        print("CapsuleRT vs Sionna RT: not run (see the reason above)")


if __name__ == "__main__":
    main()
