"""First hits along segments: Embree rays that end at a given distance, for the phantom's checks.

The tracer's rays (:func:`raytrace.engine.embree.intersect`) run to infinity. The checks of a phantom's
surfaces (:mod:`raytrace.body.selfintersect`: does anything cross this edge?) ask about a *segment*: with
the ray's ``tfar`` set to the segment's length Embree prunes every BVH node beyond it, so a segment a
millimetre long visits a handful of nodes where an unbounded ray walks across the body (measured on the
default torso at 0.98 M triangles, 1.46 M edges: 0.3 against 1.4 CPU-s).

This module holds only that query. It writes the same ``RTCRayHit`` words as
:func:`raytrace.engine.embree.intersect` (the layout is documented there), with ``tfar`` from the caller,
and answers Embree's ``geomID`` beside its ``primID`` so that a scene of several geometries maps a hit to
its face (``base[geomID] + primID``). It is the Embree binding's, below :mod:`raytrace.body` in the
layering (docs/architecture.md): it imports nothing of the project but the binding.
"""

from __future__ import annotations

import numpy as np

from raytrace.engine.embree import EmbreeScene, ray_hit, rtc_intersect1
from raytrace.engine.jit import kernel

__all__ = ["edge_segment_hits", "segment_hits"]

_INVALID = 0xFFFFFFFF


@kernel
def _segments(handle, o, d, tfar, prim, geom, t):
    """First hit of every ray ``o[i] + s d[i]``, ``0 <= s <= tfar[i]`` (float32), into ``prim, geom, t``
    (``prim = geom = -1``, ``t = inf`` on a miss)."""
    hit = ray_hit()
    buf, words = hit.buf, hit.words
    for i in range(len(o)):
        buf[0], buf[1], buf[2], buf[3] = o[i, 0], o[i, 1], o[i, 2], 0.0
        buf[4], buf[5], buf[6], buf[7] = d[i, 0], d[i, 1], d[i, 2], 0.0
        buf[8] = tfar[i]
        words[9], words[10], words[11] = _INVALID, 0, 0  # mask (every geometry), id, flags
        words[17], words[18] = _INVALID, _INVALID  # primID, geomID
        rtc_intersect1(handle, hit.ptr, 0)
        if words[18] == _INVALID:
            prim[i], geom[i], t[i] = -1, -1, np.inf
        else:
            prim[i], geom[i], t[i] = words[17], words[18], buf[8]


@kernel
def _edge_segments(handle, center, vertices, pairs, face, twin, normals, trim, offset, prim, geom, t):
    """One segment per edge ``pairs[k] = (a, b)``: from ``a`` moved ``trim`` of the edge's length towards
    ``b``, and ``offset`` beside the edge along the normalised sum of ``normals[face[k]]`` and
    ``normals[twin[k]]`` (the first alone where they cancel), to ``trim`` before ``b``; first hits into
    ``prim, geom, t`` as :func:`_segments` (``t`` from the segment's start)."""
    hit = ray_hit()
    buf, words = hit.buf, hit.words
    for k in range(len(pairs)):
        a, b = pairs[k, 0], pairs[k, 1]
        dx, dy, dz = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if not length > 0.0:
            prim[k], geom[k], t[k] = -1, -1, np.inf
            continue
        dx, dy, dz = dx / length, dy / length, dz / length
        f, g = face[k], twin[k]
        sx, sy, sz = normals[f, 0] + normals[g, 0], normals[f, 1] + normals[g, 1], normals[f, 2] + normals[g, 2]
        norm = np.sqrt(sx * sx + sy * sy + sz * sz)
        if norm > 1e-3:
            sx, sy, sz = sx / norm, sy / norm, sz / norm
        else:
            sx, sy, sz = normals[f, 0], normals[f, 1], normals[f, 2]
        s = trim * length
        buf[0] = vertices[a, 0] - center[0] + s * dx + offset * sx
        buf[1] = vertices[a, 1] - center[1] + s * dy + offset * sy
        buf[2] = vertices[a, 2] - center[2] + s * dz + offset * sz
        buf[3] = 0.0
        buf[4], buf[5], buf[6], buf[7] = dx, dy, dz, 0.0
        buf[8] = (1.0 - 2.0 * trim) * length
        words[9], words[10], words[11] = _INVALID, 0, 0
        words[17], words[18] = _INVALID, _INVALID
        rtc_intersect1(handle, hit.ptr, 0)
        if words[18] == _INVALID:
            prim[k], geom[k], t[k] = -1, -1, np.inf
        else:
            prim[k], geom[k], t[k] = words[17], words[18], buf[8]


def edge_segment_hits(scene: EmbreeScene, center: np.ndarray, vertices: np.ndarray, pairs: np.ndarray,
                      face: np.ndarray, twin: np.ndarray, normals: np.ndarray, trim: float,
                      offset: float) -> tuple[np.ndarray, np.ndarray]:
    """First hits of one segment per edge (:func:`_edge_segments`; ``vertices`` float64 in the frame the
    scene was built from less ``center``): ``(face, t)`` as :func:`segment_hits`. One compiled pass over the
    edges, no per-edge arrays: the crossing test of :func:`raytrace.body.selfintersect.edge_crossings`."""
    n = len(pairs)
    prim, geom, t = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.float32)
    if n:
        _edge_segments(scene.handle, np.ascontiguousarray(center, np.float64),
                       np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(pairs, np.int64),
                       np.ascontiguousarray(face, np.int64), np.ascontiguousarray(twin, np.int64),
                       np.ascontiguousarray(normals, np.float64), float(trim), float(offset), prim, geom, t)
    return _faces(scene, prim, geom), t


def segment_hits(scene: EmbreeScene, origins: np.ndarray, directions: np.ndarray,
                 tfar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits of float32 rays that end at ``tfar`` (module docstring): ``(face, t)``, the face index
    in the scene's face table (-1 on a miss) and the float32 distance along the direction (inf on a miss)."""
    o = np.ascontiguousarray(origins, np.float32)
    d = np.ascontiguousarray(directions, np.float32)
    far = np.ascontiguousarray(tfar, np.float32)
    if o.ndim != 2 or o.shape[1] != 3 or o.shape != d.shape or far.shape != (len(o),):
        raise ValueError(f"origins and directions must be (N, 3) arrays of one shape and tfar (N,), got {o.shape}, "
                         f"{d.shape} and {far.shape}")
    n = len(o)
    prim, geom, t = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.float32)
    if n:
        _segments(scene.handle, o, d, far, prim, geom, t)
    return _faces(scene, prim, geom), t


def _faces(scene: EmbreeScene, prim: np.ndarray, geom: np.ndarray) -> np.ndarray:
    """Face indices of hits: ``primID``, plus the first face of its geometry in a scene of several."""
    base = getattr(scene, "base", None)
    if base is not None:
        hit = geom >= 0
        prim[hit] += np.asarray(base, np.int64)[geom[hit]]
    return prim
