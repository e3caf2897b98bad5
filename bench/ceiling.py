"""Raw Embree first-hit throughput on a phantom: the ceiling the tracer is compared to.

Rays of the kind the tracer casts: a Fibonacci sphere of primary rays from the
capsule, then one generation of secondary rays spawned at the primary hits
(mirror-reflected, pushed off the surface). Only the Embree calls are timed:
each batch is one compiled loop of ``rtcIntersect1`` through
:mod:`raytrace.engine.embree` (the tracer's own binding; nothing faster is available
from Python), into a scene built like the tracer's shooting scene (Embree's
default traversal, the faster one): ``rays_per_s``, the reference of the
ratio. For context, the same rays through the tracer's robust scene
(``robust_rays_per_s``) and through embreex's ``EmbreeScene.run``
(``embreex_rays_per_s``). The rays are cast from as many threads as the tracer
shoots with (``raytrace.solver.config.TracerConfig().threads``; Embree runs without the GIL), so
the ratio tracer / ceiling compares like with like. Each rate is also given per CPU-second
(``*_per_cpu_s``: the casts over the CPU time of both threads, best of the repeats), the
measure a machine shared with other work disturbs least.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from raytrace.engine.embree import EmbreeScene
from raytrace.solver.config import TracerConfig


def fibonacci_directions(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def embree_ceiling(phantom, origin_m: np.ndarray, rays: int, repeat: int = 3, threads: int | None = None) -> dict:
    if threads is None:
        threads = TracerConfig().threads
    vertices = np.asarray(phantom.vertices, float)
    center = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=(vertices - center).astype(np.float32),
                 indices=np.asarray(phantom.faces, np.int32))
    d1 = fibonacci_directions(rays)
    o1 = np.broadcast_to(origin_m - center, d1.shape)
    o1_32 = np.ascontiguousarray(o1, np.float32)
    d1_32 = np.ascontiguousarray(d1, np.float32)
    first = scene.run(o1_32, d1_32, output=1)
    hit = first["primID"] >= 0
    t = first["tfar"][hit].astype(float)
    n = np.asarray(phantom.face_normals)[first["primID"][hit]]
    p = o1[hit] + t[:, None] * d1[hit]
    d2 = d1[hit] - 2.0 * np.einsum("ij,ij->i", d1[hit], n)[:, None] * n
    side = np.sign(np.einsum("ij,ij->i", d2, n))[:, None]
    o2_32 = np.ascontiguousarray(p + side * n * 1e-6, np.float32)
    d2_32 = np.ascontiguousarray(d2, np.float32)
    chunks = [(o[i::threads], d[i::threads]) for o, d in ((o1_32, d1_32), (o2_32, d2_32)) for i in range(threads)]
    chunks = [(np.ascontiguousarray(o), np.ascontiguousarray(d)) for o, d in chunks]
    cast = len(d1_32) + len(d2_32)
    centred = (vertices - center).astype(np.float32)
    fast = EmbreeScene(centred, phantom.faces, robust=False)
    robust = EmbreeScene(centred, phantom.faces)
    rates = {}
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for name, cast_batch in (("rays_per_s", fast.intersect), ("robust_rays_per_s", robust.intersect),
                                 ("embreex_rays_per_s", lambda o, d: scene.run(o, d, output=1))):
            best, best_cpu = np.inf, np.inf
            for _ in range(repeat):
                t0, c0 = time.perf_counter(), time.process_time()
                list(pool.map(lambda od, f=cast_batch: f(od[0], od[1]), chunks))
                best, best_cpu = min(best, time.perf_counter() - t0), min(best_cpu, time.process_time() - c0)
            rates[name] = float(cast / best)
            rates[name.replace("_per_s", "_per_cpu_s")] = float(cast / best_cpu)
    return {"rays_cast": int(cast), **rates, "threads": int(threads), "triangles": int(len(phantom.faces))}
