"""Building a large phantom's scene, against Embree's own BVH build: CPU time, wall time, memory.

    python -m bench.scene_build                    # the torso at resolution 256 (0.98 M triangles)
    python -m bench.scene_build --resolution 96 --repeat 3

Each measurement runs in a fresh interpreter, so its memory is its own (peak RSS: ``VmHWM``,
reset before the step measured, so a step's peak is the process's while it ran, everything it
already held included):

- ``phantom``: :meth:`raytrace.body.phantom.Phantom.build` of the torso at ``--resolution``, as
  a whole, then each of its checks again on fresh copies of the meshes, so that the cost of
  every part is known (the phantom module is the anatomy work's; docs/performance-log.md,
  session 11). It pickles the phantom for the others.
- ``embree`` (the reference): Embree building one BVH of the same triangles, robust, from
  float32 arrays made beforehand (:class:`raytrace.engine.embree.EmbreeScene`, one geometry),
  as any user of Embree would.
- ``scene``: everything the tracer builds before its first trace: the face tables and corner
  normals, the robust and the fast Embree scenes, the scene without the surfaces between
  identical materials, the kernels' tables.
- ``trace``: a first all-sensor trace (1e5 rays, 6 interactions) in a fresh process that loads
  the phantom (scene build and the return lengths included), then a second one.

``embree`` and ``scene`` alternate ``--repeat`` times (CPU time is the measure: this VM is
shared; the load average is printed with every number); the medians and their ratio are
printed. Targets (issue 35): scene build within ~3x of Embree's own build, peak under 1 GB.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench.common import ROOT


def _status() -> dict:
    out = {}
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(("VmRSS:", "VmHWM:")):
                out[line.split(":")[0]] = int(line.split()[1]) / 1024.0
    return out


def _reset_peak() -> None:
    """Reset the process's peak RSS to its current RSS (Linux: ``clear_refs`` 5)."""
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")


def measured(fn):
    """Run ``fn()`` and return (its value, {cpu_s, wall_s, rss_before_mb, rss_after_mb, peak_mb})."""
    gc.collect()
    _reset_peak()
    before = _status()["VmRSS"]
    c0, w0 = time.process_time(), time.perf_counter()
    value = fn()
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    after = _status()
    return value, {"cpu_s": cpu, "wall_s": wall, "rss_before_mb": before, "rss_after_mb": after["VmRSS"],
                   "peak_mb": after["VmHWM"], "load": os.getloadavg()[0]}


# ------------------------------------------------------------------ children
def _phantom(resolution: int, path: str) -> dict:
    from raytrace.body import phantom as ph
    from raytrace.body import torso
    from raytrace.body.selfintersect import self_intersections

    def meshes():
        rings = max(resolution // 2, 8)
        organs = []
        for spec in torso._body_specs() + torso._organ_specs():
            center = torso._to_model_m(spec.center_mird_mm)
            semi = np.asarray(spec.semi_axes_mm) * torso._MM
            if spec.rim is None:
                mesh = torso.superquadric(center, semi, spec.exponent, segments=resolution, rings=rings,
                                          axis=spec.axis)
            else:
                mesh = torso.rounded_cylinder(center, semi, rim_height_m=spec.rim[0] * torso._MM,
                                              rim_fraction=spec.rim[1], segments=resolution, rings=rings,
                                              axis=spec.axis)
            organs.append(ph.Organ(spec.name, ph.Material(tissue=spec.tissue), mesh))
        return organs

    out = {}
    phantom, out["build_torso"] = measured(lambda: torso.build_torso(resolution))
    triangles = phantom.triangle_count
    with open(path, "wb") as fh:
        pickle.dump(phantom, fh, protocol=5)
    del phantom

    def each(check):
        organs = meshes()  # fresh meshes: no trimesh cache from an earlier check
        return measured(lambda: [check(o) for o in organs])[1]

    out["meshes"] = measured(meshes)[1]
    out["checks"] = {
        "degenerate (area_faces)": each(lambda o: o.mesh.area_faces),
        "watertight": each(lambda o: o.mesh.is_watertight),
        "winding consistent": each(lambda o: o.mesh.is_winding_consistent),
        "volume": each(lambda o: o.mesh.volume),
        "self-intersections": each(lambda o: self_intersections(o.mesh.vertices, o.mesh.faces, limit=1000)),
        "vertex normals": each(lambda o: o.mesh.vertex_normals),
    }
    with open(path, "rb") as fh:  # the containment tree casts through a built phantom's scene of every face
        built = pickle.load(fh)
    built.intersector, built.volumes_m3  # noqa: B018 (built before the measurement, as Phantom.build has them)
    out["checks"]["containment tree"] = measured(lambda: ph._containment_tree(built, built.volumes_m3))[1]
    return {"triangles": triangles, **out}


def _load(path: str):
    from raytrace.solver.tracer import warm_up

    warm_up()  # the kernels (loaded from numba's cache) are not the scene build's cost
    gc.freeze()
    with open(path, "rb") as fh:
        return pickle.load(fh)


def _embree(path: str) -> dict:
    phantom = _load(path)
    from raytrace.engine.embree import EmbreeScene, buffers

    vertices = np.asarray(phantom.vertices, float)
    center = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    vbuf, fbuf = buffers(vertices - center, phantom.faces)
    scene, robust = measured(lambda: EmbreeScene(vbuf, fbuf))
    del scene
    scene, fast = measured(lambda: EmbreeScene(vbuf, fbuf, robust=False))
    return {"triangles": phantom.triangle_count, "robust": robust, "fast": fast}


def _scene(path: str) -> dict:
    phantom = _load(path)
    from raytrace.engine.scene import scene_for
    from raytrace.solver.media import MediaTable

    def build():
        full = scene_for(phantom)
        media = MediaTable.build(phantom, np.array([402e6]))
        visible = scene_for(phantom, ~media.face_transparent)
        full.kernel_tables
        visible.kernel_tables
        visible.shot_tables
        return full, visible

    (full, visible), out = measured(build)
    return {"triangles": phantom.triangle_count, "scene": out, "separate_embree_scenes": int(visible._own is not None)}


def _trace(path: str) -> dict:
    phantom = _load(path)
    from bench import scenes

    tx, rx = scenes.transmitter(phantom), scenes.receivers(phantom)

    def trace():
        return scenes.trace(phantom, tx, rx, 402e6, rays=100_000, max_interactions=6)

    _result, first = measured(trace)
    result, second = measured(trace)
    return {"triangles": phantom.triangle_count, "first": first, "second": second,
            "segments": result.stats.ray_segments_traced, "paths": result.stats.paths_found,
            "process_peak_mb": max(first["peak_mb"], second["peak_mb"])}


CHILDREN = {"phantom": _phantom, "embree": _embree, "scene": _scene, "trace": _trace}


def _child(kind: str, *args) -> dict:
    cmd = [sys.executable, "-m", "bench.scene_build", "--child", kind, *map(str, args)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"bench.scene_build --child {kind} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(resolution: int = 256, repeat: int = 3, phantom_breakdown: bool = True) -> dict:
    """Every measurement of the module doc; returns the report (medians, ratios)."""
    with tempfile.TemporaryDirectory(prefix="capsule-rt-scene-build-") as tmp:
        path = os.path.join(tmp, "phantom.pkl")
        phantom = _child("phantom", resolution, path, int(phantom_breakdown))
        embree, scene = [], []
        for k in range(repeat):  # alternate, which goes first too
            pair = (("embree", embree), ("scene", scene)) if k % 2 == 0 else (("scene", scene), ("embree", embree))
            for kind, into in pair:
                into.append(_child(kind, path))
        trace = _child("trace", path)
    med = lambda xs: float(np.median(xs))  # noqa: E731
    ref_cpu, ref_wall = med([e["robust"]["cpu_s"] for e in embree]), med([e["robust"]["wall_s"] for e in embree])
    cpu, wall = med([s["scene"]["cpu_s"] for s in scene]), med([s["scene"]["wall_s"] for s in scene])
    return {
        "resolution": resolution, "triangles": phantom["triangles"], "repeat": repeat,
        "phantom": phantom, "embree": embree, "scene": scene, "trace": trace,
        "embree_build_cpu_s": ref_cpu, "embree_build_wall_s": ref_wall,
        "embree_fast_build_cpu_s": med([e["fast"]["cpu_s"] for e in embree]),
        "scene_build_cpu_s": cpu, "scene_build_wall_s": wall,
        "ratio_cpu": cpu / ref_cpu, "ratio_wall": wall / ref_wall,
        "scene_peak_mb": max(s["scene"]["peak_mb"] for s in scene),
        "scene_added_mb": med([s["scene"]["rss_after_mb"] - s["scene"]["rss_before_mb"] for s in scene]),
        "scene_peak_added_mb": med([s["scene"]["peak_mb"] - s["scene"]["rss_before_mb"] for s in scene]),
        "trace_process_peak_mb": trace["process_peak_mb"],
    }


def print_rows(r: dict, row) -> None:
    p = r["phantom"]
    tri = r["triangles"]
    row(f"scene build, torso {tri} triangles: Embree's own BVH build CPU / wall [s]",
        f"{r['embree_build_cpu_s']:.2f} / {r['embree_build_wall_s']:.2f}")
    row("  the tracer's scene build CPU / wall [s]", f"{r['scene_build_cpu_s']:.2f} / {r['scene_build_wall_s']:.2f}")
    row("  ratio to Embree's build, CPU / wall", f"{r['ratio_cpu']:.2f} / {r['ratio_wall']:.2f}", "target <= ~3")
    row("  peak RSS of the process while it builds [MB]", f"{r['scene_peak_mb']:.0f}", "target <= 1024")
    row("  memory the scene keeps / its peak above the process [MB]",
        f"{r['scene_added_mb']:.0f} / {r['scene_peak_added_mb']:.0f}")
    t = r["trace"]
    row("  first / second all-sensor trace CPU [s]", f"{t['first']['cpu_s']:.2f} / {t['second']['cpu_s']:.2f}")
    row("  peak RSS of a process tracing it [MB]", f"{t['process_peak_mb']:.0f}", "target <= 1024")
    row("  Phantom.build (anatomy) CPU / wall [s], peak [MB]",
        f"{p['build_torso']['cpu_s']:.1f} / {p['build_torso']['wall_s']:.1f}, {p['build_torso']['peak_mb']:.0f}")
    for name, m in p.get("checks", {}).items():
        row(f"    {name}: CPU [s], peak above the process [MB]",
            f"{m['cpu_s']:.2f}, {m['peak_mb'] - m['rss_before_mb']:.0f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=256, help="torso resolution (256: 0.98 M triangles)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-phantom-breakdown", action="store_true", help="Phantom.build as a whole only")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "scene_build.json"))
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        kind, rest = args.child[0], args.child[1:]
        if kind == "phantom":
            result = _phantom(int(rest[0]), rest[1]) if int(rest[2]) else _phantom_whole(int(rest[0]), rest[1])
        else:
            result = CHILDREN[kind](*rest)
        print(json.dumps(result, default=float))
        return
    print(f"load average {os.getloadavg()[0]:.2f} at the start", flush=True)
    report = run(args.resolution, args.repeat, not args.no_phantom_breakdown)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(report, fh, indent=2, default=float)
    print_rows(report, lambda name, value, target="": print(f"  {name:<72} {value:>18}  {target}"))
    print(f"load average {os.getloadavg()[0]:.2f} at the end; wrote {os.path.relpath(args.out, ROOT)}")


def _phantom_whole(resolution: int, path: str) -> dict:
    from raytrace.body import torso

    phantom, build = measured(lambda: torso.build_torso(resolution))
    with open(path, "wb") as fh:
        pickle.dump(phantom, fh, protocol=5)
    return {"triangles": phantom.triangle_count, "build_torso": build}


if __name__ == "__main__":
    main()
