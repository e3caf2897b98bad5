"""Travel-time fields of a phantom's sensors: voxel grid -> refractive index per cell ->
eikonal fields (docs/localization.md, "Travel-time fields").

    sensor_fields(phantom, sensors_m, frequency_hz, cell_size_m, delay_kind="group", *, check, cache_dir, workers)

The phantom's side (voxel grid, index per organ, content hash) is :mod:`raytrace.body.indexgrid`;
the fields' side (eikonal solves in parallel, memory and disk caches) is
:mod:`estimators.localization.fieldstore`. A field is computed once per (phantom content,
frequency, delay kind, cell size, sensor) and, with ``cache_dir``, survives a restart.

Every function building fields takes the ``delay_kind`` of the delays they will be compared
with (``estimators.localization.delays``): ``group`` (the default, what a TOA receiver timing an
envelope measures) builds them on the group index, ``phase`` on Re n.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from estimators.localization import DEFAULT_DELAY_KIND, TravelTimeFields, check_delay_kind
from estimators.localization.fieldstore import fields_for_sensors
from raytrace.body.indexgrid import grid_key, voxel_grid
from raytrace.body.indexgrid import index_grid as _index_grid
from raytrace.body.indexgrid import organ_indices as _organ_indices
from raytrace.body.phantom import Phantom
from raytrace.body.voxels import VoxelGrid

__all__ = ["DEFAULT_CELL_SIZE_M", "eikonal_path", "grid_key", "index_grid", "organ_indices", "path_media",
           "sensor_fields", "voxel_grid"]

#: Default cell edge of the travel-time grids [m] (docs/localization.md: accuracy and cost).
DEFAULT_CELL_SIZE_M = 0.004


def organ_indices(phantom: Phantom, frequency_hz: float, delay_kind: str = DEFAULT_DELAY_KIND) -> np.ndarray:
    """Refractive index of every organ at the carrier for delays of ``delay_kind``, ``(n_organs,)``:
    ``phase`` Re n (a path's ``delay_s``), ``group`` n_g = c d(Re k)/dw (its ``group_delay_s``;
    docs/science.md (S22)); :func:`raytrace.body.indexgrid.organ_indices`."""
    return _organ_indices(phantom, frequency_hz, check_delay_kind(delay_kind))


def index_grid(phantom: Phantom, frequency_hz: float, cell_size_m: float = DEFAULT_CELL_SIZE_M,
               delay_kind: str = DEFAULT_DELAY_KIND) -> tuple[VoxelGrid, np.ndarray]:
    """(voxel grid, refractive index per cell for delays of ``delay_kind``), air NaN
    (:func:`raytrace.body.indexgrid.index_grid`)."""
    return _index_grid(phantom, frequency_hz, cell_size_m, check_delay_kind(delay_kind))


def sensor_fields(phantom: Phantom, sensors_m: Sequence, frequency_hz: float,
                  cell_size_m: float = DEFAULT_CELL_SIZE_M, delay_kind: str = DEFAULT_DELAY_KIND,
                  check: Callable[[], None] | None = None, *, cache_dir: str | Path | None = None,
                  workers: int | None = None) -> TravelTimeFields:
    """Travel-time fields of every sensor for delays of ``delay_kind``, stacked for the
    model-based fix; cached in memory and, with ``cache_dir``, on disk; misses solved on
    ``workers`` processes (default: this process's CPUs). ``check`` (e.g. a request budget's) is
    called before and between the solves and may raise to stop. A sensor outside the grid or the
    body raises EstimatorInputError naming ``sensors[i].position_m``."""
    key = grid_key(phantom, frequency_hz, cell_size_m, check_delay_kind(delay_kind))

    def build() -> tuple:
        grid, n = index_grid(phantom, frequency_hz, cell_size_m, delay_kind)
        return n, grid.origin_m, grid.spacing_m

    return fields_for_sensors(key, sensors_m, build, cache_dir=cache_dir, workers=workers, check=check)


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
