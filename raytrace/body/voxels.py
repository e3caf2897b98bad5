"""A phantom on a regular voxel grid: the medium (organ index, -1 for air) of every cell.

Cell (i, j, k) spans ``origin_m + [i, i+1) x [j, j+1) x [k, k+1) * spacing_m`` and takes the
medium at its centre, looked up with :meth:`raytrace.body.phantom.Phantom.medium_index` (the
phantom's own point-in-organ rule). That lookup refuses points within
:data:`raytrace.body.phantom.SURFACE_TOLERANCE_M` of a surface; a batch holding one is retried
with every point nudged by ``k * NUDGE_CELLS`` cells (k = 1, 2, ...) along a fixed oblique
direction, so a cell's sample point is its centre up to a few thousandths of a cell.

A grid stair-cases every surface: a cell's medium is wrong by at most the part of it on
the other side, i.e. organ boundaries move by up to sqrt(3) / 2 cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raytrace.body.phantom import AIR_INDEX, Phantom
from raytrace.errors import AmbiguousPositionError, InputError

#: Most cells one grid may hold.
MAX_CELLS = 32_000_000
#: Points per medium lookup.
CHUNK = 2048
#: Nudge of a retried batch, in cells, and the most retries.
NUDGE_CELLS = 1e-3
MAX_RETRIES = 16
_NUDGE_DIRECTION = np.array([0.5362, 0.6284, 0.5635]) / np.linalg.norm([0.5362, 0.6284, 0.5635])


@dataclass(frozen=True, eq=False)
class VoxelGrid:
    """Organ index per cell (``organ[i, j, k]``, int16, -1 air) on a regular grid.

    origin_m: lower corner of cell (0, 0, 0); spacing_m: cell edge; organ_names: the
    phantom's organs, so that ``organ_names[organ[i, j, k]]`` names a cell's medium.
    """

    origin_m: np.ndarray
    spacing_m: float
    organ: np.ndarray
    phantom: str
    organ_names: tuple[str, ...]

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.organ.shape)

    def centres_m(self, axis: int) -> np.ndarray:
        """Cell-centre coordinates along ``axis`` [m]."""
        return self.origin_m[axis] + (np.arange(self.organ.shape[axis]) + 0.5) * self.spacing_m

    def values(self, per_medium: np.ndarray, air: float = np.nan) -> np.ndarray:
        """A float grid from one value per organ (``per_medium[i]`` for organ i) and ``air``."""
        table = np.concatenate([[air], np.asarray(per_medium, float).ravel()])
        if len(table) != len(self.organ_names) + 1:
            raise InputError(f"needs one value per organ ({len(self.organ_names)}), got {len(table) - 1}",
                             field="per_medium")
        return table[self.organ.astype(np.int64) + 1]


def voxelize(phantom: Phantom, spacing_m: float, *, bounds_m: np.ndarray | None = None,
             pad_cells: int = 1) -> VoxelGrid:
    """The phantom's media on a grid of cubic cells of edge ``spacing_m`` covering ``bounds_m``
    ((2, 3) [m], default the phantom's bounds) plus ``pad_cells`` cells of margin (air
    outside the phantom). Raises :class:`~raytrace.errors.InputError` naming ``spacing_m``,
    ``bounds_m`` or ``pad_cells``; grids over :data:`MAX_CELLS` cells are refused."""
    try:
        h = float(spacing_m)
    except (TypeError, ValueError) as exc:
        raise InputError("must be a number of metres", field="spacing_m") from exc
    if not (np.isfinite(h) and h > 0.0):
        raise InputError(f"must be finite and > 0, got {spacing_m!r}", field="spacing_m")
    if isinstance(pad_cells, bool) or not isinstance(pad_cells, (int, np.integer)) or not 0 <= pad_cells <= 64:
        raise InputError(f"must be an integer in [0, 64], got {pad_cells!r}", field="pad_cells")
    if bounds_m is None:
        lo, hi = phantom.bounds_m
    else:
        try:
            b = np.asarray(bounds_m, dtype=float).reshape(2, 3)
        except (TypeError, ValueError) as exc:
            raise InputError("must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] in metres", field="bounds_m") from exc
        if not np.isfinite(b).all() or np.any(b[1] <= b[0]):
            raise InputError("must be finite with max > min on every axis", field="bounds_m")
        lo, hi = b
    shape = np.ceil((hi - lo) / h).astype(np.int64) + 2 * int(pad_cells)
    shape = np.maximum(shape, 1)
    cells = int(np.prod(shape))
    if cells > MAX_CELLS:
        raise InputError(f"{cells} cells exceed the cap of {MAX_CELLS}; use larger cells or smaller bounds",
                         field="spacing_m")
    # centre the grid on the bounds
    origin = 0.5 * (lo + hi) - 0.5 * shape * h
    axes = [origin[i] + (np.arange(shape[i]) + 0.5) * h for i in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    organ = np.empty(len(points), dtype=np.int16)
    for start in range(0, len(points), CHUNK):
        organ[start:start + CHUNK] = _media(phantom, points[start:start + CHUNK], h)
    return VoxelGrid(origin_m=origin, spacing_m=h, organ=organ.reshape(tuple(shape)), phantom=phantom.name,
                     organ_names=tuple(o.name for o in phantom.organs))


def _media(phantom: Phantom, points: np.ndarray, h: float) -> np.ndarray:
    for k in range(MAX_RETRIES + 1):
        try:
            return phantom.medium_index(points + k * NUDGE_CELLS * h * _NUDGE_DIRECTION)
        except AmbiguousPositionError:
            continue
    if len(points) > 1:  # still ambiguous after every nudge: halve the batch
        mid = len(points) // 2
        return np.concatenate([_media(phantom, points[:mid], h), _media(phantom, points[mid:], h)])
    raise InputError(f"cell centre {points[0].tolist()} lies on an organ surface at every nudge",
                     field="spacing_m")


__all__ = ["AIR_INDEX", "VoxelGrid", "voxelize"]
