"""Building a phantom of ~1 M triangles against the raw Embree BVH build of the same triangles.

    python -m bench.phantom_build                  # the torso at resolution 256: 0.98 M triangles, 15 organs
    python -m bench.phantom_build --resolution 96  # a quick run
    python -m bench.phantom_build --inputs DIR     # keep the written inputs in DIR (reused when present)

The inputs are written to disk first, by this process: the default torso's organs at the given resolution, as
one PLY file per organ with a build manifest (the pipeline's input) and as one ``.npz`` of the same triangles
(the other steps' input). Each measurement then runs in a child process of its own that reads its input before
the clock starts, so neither making the torso nor decoding files is counted where it is not the step measured
(the pipeline's row counts its reading, as a user's build does); the Embree binding and its compiled queries
are loaded before the clock too (once per process, as in a server). Every child runs ``--repeat`` times,
interleaved with the others (A, B, C, D, A, B, ...), and the table gives each step's least CPU time (all
threads) and its largest peak RSS (the child's ``ru_maxrss``, input included):

* ``embree``: the reference, one Embree BVH of all the triangles (``raytrace.engine.embree.EmbreeScene``,
  the tracer's own binding);
* ``phantom``: :meth:`raytrace.body.phantom.Phantom.build` of those organs (every check, the crossing test,
  the containment tree, and the Embree scene its checks and medium lookups use);
* ``pipeline``: the anatomy pipeline (``raytrace.body.anatomy.build_phantom``) from the manifest and the PLY
  files: reading, welding, repairs, the crossing test, overlaps, ``Phantom.build``;
* ``scene``: the tracer's scene (``raytrace.engine.scene.scene_for``) of the built phantom, reported beside,
  not a target of this bench.

The issue's targets (docs/phantoms.md, "Scale") are printed beside the ratios, never asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_RATIO = 3.0
TARGET_RSS_MB = 1536
MODES = ("embree", "phantom", "pipeline", "scene")


def write_inputs(resolution: int, workdir: Path) -> int:
    """The torso's organs as PLY files + a build manifest and as ``organs.npz``; their triangle count."""
    import numpy as np

    from raytrace.body.torso import build_torso

    organs = build_torso(resolution).organs
    manifest: dict = {"name": "bench", "units": "m", "organs": {},
                      "options": {"max_triangles_per_surface": 2_000_000}}
    arrays: dict = {}
    for k, organ in enumerate(organs):
        organ.mesh.export(workdir / f"{organ.name}.ply")
        manifest["organs"][organ.name] = {"file": f"{organ.name}.ply", "tissue": organ.material.tissue,
                                          "max_triangles": 2_000_000}
        arrays[f"v{k}"] = np.asarray(organ.mesh.vertices, float)
        arrays[f"f{k}"] = np.asarray(organ.mesh.faces, np.int64)
    arrays["names"] = np.array([o.name for o in organs])
    arrays["tissues"] = np.array([o.material.tissue for o in organs])
    np.savez(workdir / "organs.npz", **arrays)
    (workdir / "manifest.json").write_text(json.dumps(manifest))
    return int(sum(len(o.mesh.faces) for o in organs))


def _organs(workdir: Path):
    """Fresh organs from ``organs.npz`` (no cached edges or normals)."""
    import numpy as np
    import trimesh

    from raytrace.body.phantom import Organ
    from raytrace.physics.materials import Material

    data = np.load(workdir / "organs.npz")
    return [Organ(str(name), Material(tissue=str(tissue)),
                  trimesh.Trimesh(data[f"v{k}"], data[f"f{k}"], process=False, validate=False))
            for k, (name, tissue) in enumerate(zip(data["names"], data["tissues"]))]


def _measure(fn) -> dict:
    import gc

    gc.collect()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn()
    return {"cpu_s": time.process_time() - cpu, "wall_s": time.perf_counter() - wall,
            "rss_before_mb": before, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "info": out}


def child(mode: str, workdir: Path) -> dict:
    import numpy as np

    from raytrace.body.rays import RayScene
    from raytrace.engine.embree import EmbreeScene

    # the binding and its compiled queries loaded before the clock (once per process, as in a server)
    warm = RayScene(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 2, 1], [0, 1, 3],
                                                                                         [0, 3, 2], [1, 2, 3]]))
    warm.first_hits(np.zeros((1, 3)), np.ones((1, 3)) / 3**0.5)
    warm.first_hits(np.zeros((1, 3)), np.ones((1, 3)) / 3**0.5, np.ones(1))
    warm.edge_hits(np.array([[0, 1]]), np.array([0]), np.array([1]), 1e-3, 1e-6)
    if mode == "pipeline":
        from raytrace.body.anatomy import build_phantom, parse_manifest_text

        data = parse_manifest_text((workdir / "manifest.json").read_bytes(), filename="manifest.json")
        return _measure(lambda: build_phantom(data, workdir).phantom.triangle_count)
    organs = _organs(workdir)
    if mode == "embree":
        offsets = np.cumsum([0] + [len(o.mesh.vertices) for o in organs])
        vertices = np.concatenate([o.mesh.vertices for o in organs])
        faces = np.concatenate([np.asarray(o.mesh.faces) + offsets[i] for i, o in enumerate(organs)])
        del organs
        return _measure(lambda: EmbreeScene(vertices, faces).triangles)
    from raytrace.body.phantom import Phantom

    if mode == "phantom":
        return _measure(lambda: Phantom.build("bench", organs).triangle_count)
    phantom = Phantom.build("bench", organs)
    from raytrace.engine.scene import scene_for

    return _measure(lambda: type(scene_for(phantom)).__name__)


def run(resolution: int, repeat: int, inputs: Path | None = None) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-phantom-") as tmp:
        workdir = inputs or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        stamp = workdir / "resolution.txt"
        if not (stamp.is_file() and stamp.read_text() == str(resolution)):
            triangles = write_inputs(resolution, workdir)
            stamp.write_text(str(resolution))
        else:
            import numpy as np

            data = np.load(workdir / "organs.npz")
            triangles = int(sum(len(data[f"f{k}"]) for k in range(len(data["names"]))))
        out: dict = {"resolution": resolution, "triangles": triangles, "repeat": repeat, "runs": {m: [] for m in MODES}}
        for _ in range(repeat):
            for mode in MODES:
                proc = subprocess.run([sys.executable, "-m", "bench.phantom_build", "--child", mode,
                                       "--workdir", str(workdir)], capture_output=True, text=True, timeout=3600)
                if proc.returncode:
                    raise RuntimeError(f"{mode}: {proc.stderr[-2000:]}")
                out["runs"][mode].append(json.loads(proc.stdout.strip().splitlines()[-1]))
    for mode in MODES:
        runs = out["runs"][mode]
        out[mode] = {"cpu_s": min(r["cpu_s"] for r in runs), "wall_s": min(r["wall_s"] for r in runs),
                     "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
                     "rss_before_mb": max(r["rss_before_mb"] for r in runs)}
    ref = out["embree"]["cpu_s"]
    for mode in MODES[1:]:
        out[mode]["cpu_ratio_to_embree"] = out[mode]["cpu_s"] / ref
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.phantom_build", description=__doc__.split("\n\n")[0])
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--repeat", type=int, default=2, help="runs of every step, interleaved (the least CPU counts)")
    p.add_argument("--inputs", type=Path, default=None, help="directory for the written inputs (kept, reused)")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    p.add_argument("--workdir", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, Path(args.workdir))))
        return 0
    out = run(args.resolution, args.repeat, args.inputs)
    out["load_average"] = os.getloadavg()
    print(f"{out['triangles']} triangles (torso resolution {out['resolution']}, 15 organs); least CPU of "
          f"{out['repeat']} interleaved runs; load average {out['load_average'][0]:.1f}")
    print("| step | CPU s | wall s | CPU / Embree BVH | peak RSS MB (input read) | target |")
    print("|---|---:|---:|---:|---:|---|")
    for mode in MODES:
        r = out[mode]
        ratio = r.get("cpu_ratio_to_embree")
        target = {"phantom": f"<= {TARGET_RATIO:g}x, < {TARGET_RSS_MB} MB",
                  "pipeline": f"<= {TARGET_RATIO:g}x, < {TARGET_RSS_MB} MB"}.get(mode, "reference" if mode == "embree"
                                                                              else "reported")
        print(f"| {mode} | {r['cpu_s']:.2f} | {r['wall_s']:.2f} | {'1' if ratio is None else f'{ratio:.2f}'} | "
              f"{r['peak_rss_mb']:.0f} ({r['rss_before_mb']:.0f}) | {target} |")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
