"""Travel-time fields of a phantom's sensors: voxel grid -> refractive index per cell ->
eikonal fields (docs/localization.md, "Travel-time fields").

Caches: voxel grids per (phantom, cell size) here (bounded, holding the phantom so its id
stays valid), fields per (index grid content, sensor) in
:func:`estimators.localization.cached_travel_time_field`; together a field is computed once
per (phantom, sensor, frequency, cell size, index kind).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence

import numpy as np

from estimators.errors import EstimatorInputError
from estimators.localization import TravelTimeFields, cached_travel_time_field
from estimators.localization.traveltime import grid_fingerprint
from raytrace.body.phantom import Phantom
from raytrace.body.voxels import VoxelGrid, voxelize
from raytrace.physics.em import refractive_index

#: Default cell edge of the travel-time grids [m] (docs/localization.md: accuracy and cost).
DEFAULT_CELL_SIZE_M = 0.004
INDEX_KINDS = ("phase", "group")
_VOXEL_CACHE_SIZE = 6

_voxels: OrderedDict = OrderedDict()
_voxels_lock = threading.Lock()


def organ_indices(phantom: Phantom, frequency_hz: float, kind: str = "phase") -> np.ndarray:
    """Refractive index of every organ at the carrier, ``(n_organs,)``.

    ``kind="phase"``: Re n = Re sqrt(eps_r*) from each organ's material (Gabriel 1996 Cole-Cole
    or explicit eps_r / sigma), the index the tracer uses for its ray geometry and delays.
    ``kind="group"``: n_g = Re(n + w dn/dw) (docs/science.md (S22)), the index a pulse's
    envelope travels with, i.e. of the paths' ``group_delay_s``: the index for delays measured
    on a band-limited waveform that sees the dispersion. Use the kind whose delay the
    ranging measures: the travel-time fields must share the delays' definition.
    """
    if kind not in INDEX_KINDS:
        raise EstimatorInputError(f"unknown index kind {kind!r} ({' | '.join(INDEX_KINDS)})", "index_kind")
    f = float(frequency_hz)
    if kind == "group":
        return np.array([float(o.material.group_index(f)) for o in phantom.organs])
    return np.array([float(np.real(refractive_index(o.material.complex_relative_permittivity(f))))
                     for o in phantom.organs])


def voxel_grid(phantom: Phantom, cell_size_m: float = DEFAULT_CELL_SIZE_M) -> VoxelGrid:
    """The phantom's voxel grid (phantom bounds plus one cell), cached per (phantom, cell size)."""
    key = (id(phantom), float(cell_size_m))
    with _voxels_lock:
        hit = _voxels.get(key)
        if hit is not None and hit[0] is phantom:
            _voxels.move_to_end(key)
            return hit[1]
    grid = voxelize(phantom, float(cell_size_m))
    with _voxels_lock:
        _voxels[key] = (phantom, grid)
        while len(_voxels) > _VOXEL_CACHE_SIZE:
            _voxels.popitem(last=False)
    return grid


def index_grid(phantom: Phantom, frequency_hz: float, cell_size_m: float = DEFAULT_CELL_SIZE_M,
               kind: str = "phase") -> tuple[VoxelGrid, np.ndarray]:
    """(voxel grid, refractive index per cell) with air as NaN: outside the propagation
    domain. An in-body link never travels through the air around a convex body (a straight
    segment between two points of it stays inside), and air's index of 1 would let the
    eikonal front run around the body faster than any tissue path."""
    grid = voxel_grid(phantom, cell_size_m)
    return grid, grid.values(organ_indices(phantom, frequency_hz, kind), air=np.nan)


def sensor_fields(phantom: Phantom, sensors_m: Sequence, frequency_hz: float,
                  cell_size_m: float = DEFAULT_CELL_SIZE_M, kind: str = "phase",
                  check: Callable[[], None] | None = None) -> TravelTimeFields:
    """Travel-time fields of every sensor (cached), stacked for the model-based fix. ``check``
    (e.g. a request budget's) is called before each field is built and may raise to stop."""
    grid, n = index_grid(phantom, frequency_hz, cell_size_m, kind)
    key = grid_fingerprint(n, grid.origin_m, grid.spacing_m)
    fields = []
    for i, s in enumerate(np.asarray(sensors_m, float).reshape(-1, 3)):
        if check is not None:
            check()
        try:
            fields.append(cached_travel_time_field(n, grid.origin_m, grid.spacing_m, s, fingerprint=key))
        except EstimatorInputError as exc:
            raise EstimatorInputError(exc.reason, f"sensors[{i}].position_m") from exc
    return TravelTimeFields(fields)


def eikonal_path(fields: TravelTimeFields, sensor: int, start_m: np.ndarray, step_cells: float = 0.25,
                 max_steps: int = 20_000) -> np.ndarray:
    """The first-arrival ray from ``start_m`` back to sensor ``sensor``: steepest descent of
    T along -grad T (interpolated) in steps of ``step_cells`` cells, until within two cells
    of the sensor. Returns the (K, 3) points [m]."""
    h = fields.spacing_m
    target = fields.sensors_m[sensor]
    x = np.asarray(start_m, float).copy()
    pts = [x.copy()]
    for _ in range(max_steps):
        if np.linalg.norm(x - target) < 2.0 * h:
            break
        _, g = fields.evaluate(x, np.array([sensor]))
        g = g[0]
        norm = np.linalg.norm(g)
        if norm == 0.0:
            break
        x = x - step_cells * h * g / norm
        pts.append(x.copy())
    pts.append(target.copy())
    return np.array(pts)


def path_media(grid: VoxelGrid, points_m: np.ndarray) -> dict[str, float]:
    """Fraction of a polyline's length in each medium of the voxel grid (segment midpoints)."""
    seg = np.diff(points_m, axis=0)
    length = np.linalg.norm(seg, axis=1)
    mid = 0.5 * (points_m[1:] + points_m[:-1])
    idx = np.floor((mid - grid.origin_m) / grid.spacing_m).astype(np.int64)
    idx = np.clip(idx, 0, np.asarray(grid.shape) - 1)
    organ = grid.organ[idx[:, 0], idx[:, 1], idx[:, 2]]
    total = float(length.sum()) or 1.0
    out: dict[str, float] = {}
    for o in np.unique(organ):
        name = "air" if o < 0 else grid.organ_names[int(o)]
        out[name] = float(length[organ == o].sum() / total)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))
