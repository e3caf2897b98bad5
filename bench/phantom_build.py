"""Building a phantom of ~1 M triangles against the raw Embree BVH build of the same triangles.

    python -m bench.phantom_build                 # the torso at resolution 256: 0.98 M triangles, 15 organs
    python -m bench.phantom_build --resolution 96 # a quick run

Each measurement runs in its own child process (its peak RSS is that process's own ``ru_maxrss``), on the
default torso's organs at the given resolution, in CPU time (all threads) and wall time:

* ``embree``: the reference, one Embree BVH of all the triangles (``raytrace.engine.embree.EmbreeScene``,
  the tracer's own binding);
* ``phantom``: :meth:`raytrace.body.phantom.Phantom.build` of those organs (every check, the containment
  tree, the normals, and the Embree scene its checks and medium lookups use);
* ``pipeline``: the anatomy pipeline (``raytrace.body.anatomy.build_phantom``) from a manifest and one PLY file
  per organ, written beforehand: reading, welding, repairs, overlaps, ``Phantom.build``;
* ``scene``: the tracer's scene (``raytrace.engine.scene.scene_for``) of the built phantom, reported beside,
  not a target of this bench.

The issue's targets (docs/phantoms.md, "Scale") are printed beside the ratios, never asserted.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_RATIO = 3.0
TARGET_RSS_MB = 1536


def _organs(resolution: int):
    """The torso's organs as fresh meshes (no cached edges or normals from the torso's own build)."""
    import trimesh

    from raytrace.body.phantom import Organ
    from raytrace.body.torso import build_torso

    return [Organ(o.name, o.material, trimesh.Trimesh(o.mesh.vertices.copy(), o.mesh.faces.copy(), process=False))
            for o in build_torso(resolution).organs]


def _measure(fn) -> dict:
    import gc

    gc.collect()
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn()
    return {"cpu_s": time.process_time() - cpu, "wall_s": time.perf_counter() - wall,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, "info": out}


def child(mode: str, resolution: int, workdir: str) -> dict:
    import numpy as np

    if mode == "pipeline":
        from raytrace.body.anatomy import build_phantom, parse_manifest_text

        path = Path(workdir) / "manifest.json"
        data = parse_manifest_text(path.read_bytes(), filename=path.name)
        return _measure(lambda: build_phantom(data, Path(workdir)).phantom.triangle_count)
    organs = _organs(resolution)
    if mode == "embree":
        from raytrace.engine.embree import EmbreeScene

        offsets = np.cumsum([0] + [len(o.mesh.vertices) for o in organs])
        vertices = np.concatenate([o.mesh.vertices for o in organs])
        faces = np.concatenate([np.asarray(o.mesh.faces) + offsets[i] for i, o in enumerate(organs)])
        return _measure(lambda: EmbreeScene(vertices, faces).triangles)
    from raytrace.body.phantom import Phantom

    if mode == "phantom":
        return _measure(lambda: Phantom.build("bench", organs).triangle_count)
    phantom = Phantom.build("bench", organs)
    from raytrace.engine.scene import scene_for

    return _measure(lambda: type(scene_for(phantom)).__name__)


def _write_files(resolution: int, workdir: Path) -> int:
    organs = _organs(resolution)
    manifest = {"name": "bench", "units": "m", "organs": {}}
    for organ in organs:
        organ.mesh.export(workdir / f"{organ.name}.ply")
        manifest["organs"][organ.name] = {"file": f"{organ.name}.ply", "tissue": organ.material.tissue,
                                          "max_triangles": 2_000_000}
    manifest["options"] = {"max_triangles_per_surface": 2_000_000}
    (workdir / "manifest.json").write_text(json.dumps(manifest))
    return sum(len(o.mesh.faces) for o in organs)


def run(resolution: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-phantom-") as tmp:
        triangles = _write_files(resolution, Path(tmp))
        out = {"resolution": resolution, "triangles": triangles}
        for mode in ("embree", "phantom", "pipeline", "scene"):
            proc = subprocess.run([sys.executable, "-m", "bench.phantom_build", "--child", mode, "--resolution",
                                   str(resolution), "--workdir", tmp], capture_output=True, text=True, timeout=3600)
            if proc.returncode:
                raise RuntimeError(f"{mode}: {proc.stderr[-2000:]}")
            out[mode] = json.loads(proc.stdout.strip().splitlines()[-1])
    ref = out["embree"]["cpu_s"]
    for mode in ("phantom", "pipeline", "scene"):
        out[mode]["cpu_ratio_to_embree"] = out[mode]["cpu_s"] / ref
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.phantom_build", description=__doc__.split("\n\n")[0])
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    p.add_argument("--workdir", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.resolution, args.workdir)))
        return 0
    import os

    out = run(args.resolution)
    out["load_average"] = os.getloadavg()
    print(f"{out['triangles']} triangles (torso resolution {out['resolution']}); load average "
          f"{out['load_average'][0]:.1f}")
    print("| step | CPU s | wall s | CPU / Embree BVH | peak RSS MB | target |")
    print("|---|---:|---:|---:|---:|---|")
    for mode in ("embree", "phantom", "pipeline", "scene"):
        r = out[mode]
        ratio = r.get("cpu_ratio_to_embree")
        target = {"phantom": f"<= {TARGET_RATIO:g}x, < {TARGET_RSS_MB} MB",
                  "pipeline": f"<= {TARGET_RATIO:g}x, < {TARGET_RSS_MB} MB"}.get(mode, "reference" if mode == "embree"
                                                                              else "reported")
        print(f"| {mode} | {r['cpu_s']:.2f} | {r['wall_s']:.2f} | {'1' if ratio is None else f'{ratio:.2f}'} | "
              f"{r['peak_rss_mb']:.0f} | {target} |")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
