"""A phantom's refractive index on a voxel grid: what eikonal travel-time fields march through
(docs/localization.md, "Travel-time fields").

    phantom_digest(phantom)                              content hash of geometry and materials
    voxel_grid(phantom, cell_size_m)                     organ per cell (cached per phantom, cell size)
    organ_indices(phantom, frequency_hz, kind)           one index per organ: "phase" (Re n) or "group" (n_g)
    index_grid(phantom, frequency_hz, cell_size_m, kind) -> (VoxelGrid, index per cell, air NaN)
    grid_key(phantom, frequency_hz, cell_size_m, kind)   what that grid depends on, without building it

``kind="phase"``: Re n = Re sqrt(eps_r*) of each organ's material (Gabriel 1996 Cole-Cole or an
explicit eps_r / sigma), the index of the tracer's ray geometry and of a path's ``delay_s``.
``kind="group"``: n_g = Re(n + w dn/dw) = c d(Re k)/dw (docs/science.md (S22)), the index a
pulse's envelope travels with, of a path's ``group_delay_s``.

Air is NaN: outside the propagation domain. An in-body link never travels through the air around
a convex body (a straight segment between two points of it stays inside), and air's index 1 would
let an eikonal front run around the body faster than any tissue path.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.body.voxels import VoxelGrid, voxelize
from raytrace.errors import InputError
from raytrace.physics.em import refractive_index

__all__ = ["INDEX_KINDS", "clear_cache", "grid_key", "index_grid", "organ_indices", "phantom_digest", "voxel_grid"]

INDEX_KINDS = ("group", "phase")
_VOXEL_CACHE_SIZE = 6
_voxels: OrderedDict = OrderedDict()
_digests: OrderedDict = OrderedDict()
_lock = threading.Lock()


def phantom_digest(phantom: Phantom) -> str:
    """blake2b digest of everything a travel-time field of the phantom depends on: the organs'
    names, materials and containment, the combined mesh (vertices, faces, organ of each face).
    Two phantoms with the same digest give the same voxel grids and indices; a changed mesh or
    material changes it. Cached per instance (phantoms are immutable once built)."""
    with _lock:
        hit = _digests.get(id(phantom))
        if hit is not None and hit[0] is phantom:
            return hit[1]
    h = hashlib.blake2b(digest_size=20)
    for organ in phantom.organs:
        m = organ.material
        h.update(repr((organ.name, m.tissue, m.relative_permittivity, m.conductivity_s_per_m)).encode())
    for array, dtype in ((phantom.parent, np.int64), (phantom.vertices, np.float64), (phantom.faces, np.int64),
                         (phantom.face_organ, np.int64)):
        a = np.ascontiguousarray(array, dtype=dtype)
        h.update(np.asarray(a.shape, np.int64).tobytes())
        h.update(a.tobytes())
    digest = h.hexdigest()
    with _lock:
        _digests[id(phantom)] = (phantom, digest)  # holding the phantom keeps its id from being reused
        while len(_digests) > _VOXEL_CACHE_SIZE:
            _digests.popitem(last=False)
    return digest


def voxel_grid(phantom: Phantom, cell_size_m: float) -> VoxelGrid:
    """The phantom's voxel grid (its bounds plus one cell), cached per (phantom, cell size)."""
    key = (id(phantom), float(cell_size_m))
    with _lock:
        hit = _voxels.get(key)
        if hit is not None and hit[0] is phantom:
            _voxels.move_to_end(key)
            return hit[1]
    grid = voxelize(phantom, float(cell_size_m))
    with _lock:
        _voxels[key] = (phantom, grid)  # holding the phantom keeps its id from being reused
        while len(_voxels) > _VOXEL_CACHE_SIZE:
            _voxels.popitem(last=False)
    return grid


def organ_indices(phantom: Phantom, frequency_hz: float, kind: str) -> np.ndarray:
    """Refractive index of every organ at ``frequency_hz``, ``(n_organs,)``, of ``kind``
    (module docstring)."""
    if kind not in INDEX_KINDS:
        raise InputError(f"must be one of {' | '.join(INDEX_KINDS)}, got {kind!r}", field="delay_kind")
    f = float(frequency_hz)
    if kind == "group":
        return np.array([float(o.material.group_index(f)) for o in phantom.organs])
    return np.array([float(np.real(refractive_index(o.material.complex_relative_permittivity(f))))
                     for o in phantom.organs])


def index_grid(phantom: Phantom, frequency_hz: float, cell_size_m: float, kind: str) -> tuple[VoxelGrid, np.ndarray]:
    """(voxel grid, index of ``kind`` per cell) with air as NaN (module docstring)."""
    grid = voxel_grid(phantom, cell_size_m)
    return grid, grid.values(organ_indices(phantom, frequency_hz, kind), air=np.nan)


def grid_key(phantom: Phantom, frequency_hz: float, cell_size_m: float, kind: str) -> str:
    """A key naming :func:`index_grid`'s answer without building it: the phantom's content hash,
    the frequency, the index kind and the cell size (a cache key of fields on that grid)."""
    if kind not in INDEX_KINDS:
        raise InputError(f"must be one of {' | '.join(INDEX_KINDS)}, got {kind!r}", field="delay_kind")
    return f"{phantom_digest(phantom)}|{float(frequency_hz)!r}|{kind}|{float(cell_size_m)!r}"


def clear_cache() -> None:
    """Forget the voxel grids and content hashes kept in memory."""
    with _lock:
        _voxels.clear()
        _digests.clear()
