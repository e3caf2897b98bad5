"""Regular grids over meshes: inside masks, signed distances, and surfaces back out of them.

These are the pipeline's two robust tools for surfaces that are not fit to use as they are
(docs/phantoms.md, "Checks and repairs" and "The body wall"):

* :func:`inside_mask`: which grid cells lie inside a closed mesh, by ray parity along z. One ray
  per (x, y) column of cell centres (Embree, all hits), the number of hits below a cell's
  centre decides (odd: inside). A column with an odd number of hits (a ray through an edge
  counted once or thrice) is cast again a fraction of a cell aside; if that one is odd too the
  column is left out and counted (``InsideMask.bad_columns``).
* :class:`SurfaceDistance`: the exact distance from points to a mesh's triangles. Candidate
  triangles are those of the 8 nearest of a k-d tree's
  points (every triangle's centroid, and a lattice on triangles longer than ``3 sample_m``); the
  distance to each candidate is computed exactly (closest point on a triangle, Ericson,
  *Real-Time Collision Detection* 5.1.5), so the answer is exact wherever the nearest triangle
  is among the candidates, and never more than the distance to the nearest sample otherwise.
  Few, spread samples keep each query cheap: a k-d tree query visits the samples within the
  distance sought, so its cost grows with the square of that distance times the samples' density.
* :func:`surface_from_field`: marching cubes (scikit-image, Lewiner) of a field at a level, in
  metres (the grid's origin and spacing applied), welded and cleaned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from raytrace.errors import Field, PhantomValidationError

__all__ = ["Grid", "SurfaceDistance", "inside_mask", "surface_from_field", "surface_samples", "triangle_distance"]

#: Added to every marching-cubes level (metres or, for masks, a fraction): off every value a field takes
#: exactly (e.g. depths that are whole multiples of half a cell), far below every tolerance.
LEVEL_NUDGE = 1.234e-7
#: Offset of a re-cast column, in cells (an irrational-looking fraction, off every symmetry).
_RECAST = np.array([0.2718, 0.1414])


@dataclass(frozen=True)
class Grid:
    """Cell centres ``origin_m + (i, j, k) * spacing_m`` for ``0 <= (i, j, k) < shape``."""

    origin_m: np.ndarray
    spacing_m: float
    shape: tuple[int, int, int]

    @classmethod
    def around(cls, lo: np.ndarray, hi: np.ndarray, spacing_m: float, pad_cells: int, max_cells: int,
               where: Field, what: str) -> "Grid":
        """A grid covering ``[lo, hi]`` plus ``pad_cells``; refused above ``max_cells`` (before any work)."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        shape = tuple(int(n) for n in np.ceil((hi - lo) / spacing_m).astype(np.int64) + 1 + 2 * pad_cells)
        cells = int(np.prod(shape, dtype=np.int64))
        if cells > max_cells:
            raise PhantomValidationError(
                f"{what} needs a {'x'.join(map(str, shape))} grid of {spacing_m * 1e3:g} mm cells ({cells:.3g} "
                f"cells), over the cap of {max_cells:.3g}: use larger cells or a smaller body", field=where)
        origin = lo - pad_cells * spacing_m
        return cls(origin, float(spacing_m), shape)  # type: ignore[arg-type]

    @property
    def cells(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def axis(self, k: int) -> np.ndarray:
        return self.origin_m[k] + np.arange(self.shape[k]) * self.spacing_m

    def points(self, index: np.ndarray) -> np.ndarray:
        """Centres of cells given by flat indices."""
        ijk = np.stack(np.unravel_index(index, self.shape), axis=1)
        return self.origin_m + ijk * self.spacing_m


@dataclass
class InsideMask:
    mask: np.ndarray
    bad_columns: int


def inside_mask(mesh: trimesh.Trimesh, grid: Grid) -> InsideMask:
    """Cells of ``grid`` inside the closed ``mesh`` (module docstring)."""
    nx, ny, nz = grid.shape
    h = grid.spacing_m
    mask = np.zeros(grid.shape, dtype=bool)
    lo, hi = np.asarray(mesh.bounds, float)
    xs, ys = grid.axis(0), grid.axis(1)
    ix = np.flatnonzero((xs >= lo[0] - h) & (xs <= hi[0] + h))
    iy = np.flatnonzero((ys >= lo[1] - h) & (ys <= hi[1] + h))
    if not len(ix) or not len(iy):
        return InsideMask(mask, 0)
    gi, gj = (a.ravel() for a in np.meshgrid(ix, iy, indexing="ij"))
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    intersector = RayMeshIntersector(mesh)
    z0 = lo[2] - 2.0 * h
    parity, bad = _columns(intersector, xs[gi], ys[gj], z0, grid)
    if bad.any():  # re-cast the odd columns a little aside
        again, still = _columns(intersector, xs[gi[bad]] + _RECAST[0] * h, ys[gj[bad]] + _RECAST[1] * h, z0, grid)
        parity[bad] = again
        bad_count = int(still.sum())
    else:
        bad_count = 0
    mask[gi, gj, :] = parity
    return InsideMask(mask, bad_count)


def _columns(intersector, x: np.ndarray, y: np.ndarray, z0: float, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    n = len(x)
    nz = grid.shape[2]
    origins = np.stack([x, y, np.full(n, z0)], axis=1)
    directions = np.tile([0.0, 0.0, 1.0], (n, 1))
    locations, ray, _ = intersector.intersects_location(origins, directions, multiple_hits=True)
    delta = np.zeros((n, nz + 1), dtype=np.int16)
    counts = np.bincount(ray, minlength=n)
    if len(ray):
        k = np.clip(np.ceil((locations[:, 2] - grid.origin_m[2]) / grid.spacing_m).astype(np.int64), 0, nz)
        np.add.at(delta, (ray, k), 1)
    parity = (np.cumsum(delta, axis=1)[:, :nz] % 2).astype(bool)
    bad = counts % 2 == 1
    parity[bad] = False
    return parity, bad


def surface_samples(vertices: np.ndarray, faces: np.ndarray, sample_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on every triangle, with the triangle of each: its centroid, and for a triangle whose longest
    edge is ``n > 1`` times ``sample_m`` the inner points of a barycentric lattice of ``n`` steps per edge."""
    tri = vertices[faces]
    edge = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    steps = np.clip(np.ceil(edge / sample_m).astype(np.int64), 1, 32)
    points, owner = [tri.mean(axis=1)], [np.arange(len(faces))]
    for n in np.unique(steps):
        if n < 3:
            continue
        sel = np.flatnonzero(steps == n)
        a, b = np.meshgrid(np.arange(1, n), np.arange(1, n), indexing="ij")
        keep = a + b < n
        u, v = a[keep] / n, b[keep] / n
        w = 1.0 - u - v
        t = tri[sel]
        p = (w[None, :, None] * t[:, None, 0] + u[None, :, None] * t[:, None, 1] + v[None, :, None] * t[:, None, 2])
        points.append(p.reshape(-1, 3))
        owner.append(np.repeat(sel, len(u)))
    return np.concatenate(points), np.concatenate(owner)


def triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to triangles ``(a, b, c)`` (row by row): the closest point on a
    triangle by its Voronoi regions (Ericson 2005, section 5.1.5), vectorised."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        closest = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # edges
        t_ab = np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0)
        t_ac = np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0)
        t_bc = np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0)
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    closest = np.where(on_bc[:, None], b + (c - b) * t_bc[:, None], closest)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    closest = np.where(on_ac[:, None], a + ac * t_ac[:, None], closest)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    closest = np.where(on_ab[:, None], a + ab * t_ab[:, None], closest)
    # vertices
    closest = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, closest)
    closest = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, closest)
    closest = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, closest)
    return np.linalg.norm(p - closest, axis=1)


class SurfaceDistance:
    """Unsigned distance to a triangle mesh (module docstring, :class:`SurfaceDistance`)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, sample_m: float, candidates: int = 8) -> None:
        self.vertices = np.asarray(vertices, float)
        self.faces = np.asarray(faces, np.int64)
        points, self.owner = surface_samples(self.vertices, self.faces, sample_m)
        self.tree = cKDTree(points)
        self.k = candidates

    def __call__(self, points: np.ndarray, upper_m: float = np.inf, chunk: int = 200_000) -> np.ndarray:
        out = np.empty(len(points))
        for s in range(0, len(points), chunk):
            p = points[s:s + chunk]
            d, idx = self.tree.query(p, k=self.k, distance_upper_bound=upper_m, workers=-1)
            best = d[:, 0].copy()  # distance to the nearest sample: an upper bound
            for j in range(self.k):
                ok = np.isfinite(d[:, j])
                if not ok.any():
                    continue
                f = self.faces[self.owner[idx[ok, j]]]
                exact = triangle_distance(p[ok], self.vertices[f[:, 0]], self.vertices[f[:, 1]],
                                          self.vertices[f[:, 2]])
                best[ok] = np.minimum(best[ok], exact)
            out[s:s + chunk] = best
        return out


def surface_from_field(field: np.ndarray, grid: Grid, level: float = 0.0) -> trimesh.Trimesh:
    """Marching cubes of ``field`` at ``level`` (outward = increasing field), in metres; welded,
    degenerate triangles removed."""
    from skimage.measure import marching_cubes

    # a level a hair off the value itself: a field value exactly at the level puts a vertex on a grid node,
    # shared by several cubes' triangles, and the surface there would not be a manifold
    verts, faces, _, _ = marching_cubes(field, level=level + LEVEL_NUDGE, spacing=(grid.spacing_m,) * 3,
                                        gradient_direction="ascent", allow_degenerate=False)
    verts = verts + grid.origin_m
    return trimesh.Trimesh(verts, faces, process=True, validate=False)
