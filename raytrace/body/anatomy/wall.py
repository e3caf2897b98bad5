"""The generated body wall: layers of given thickness beneath the body surface, giving way to organs
(docs/phantoms.md, "The body wall").

The body surface is the skin's outer surface. Each layer boundary beneath it is the zero level of a
field built from two signed distances on a grid of ``wall_grid_m`` (negative inside):
``s_b`` to the body surface and ``s_o`` to the union of the organs::

    f_k = max( min(s_b + D_k, s_o - m_k),  s_b + k g ),     k = 1 .. K

``D_k`` is the depth of boundary k (the sum of the thicknesses above it), ``g`` = ``min_layer_m``
and ``m_k = organ_margin_m + (K - k) g``. Read it as: boundary k lies at depth ``D_k`` under the skin
(``s_b + D_k``), except where an organ comes closer, where it stays ``m_k`` outside the organ
(``min``: the wall gives way), but never closer than ``k g`` to the skin (``max``). Every term of
``f_{k+1}`` exceeds the same term of ``f_k`` by at least ``g`` (a layer is at least ``g`` thick), so
``f_{k+1} >= f_k + g`` everywhere and, the fields being 1-Lipschitz, consecutive boundaries are at
least ``g`` apart: nested and non-intersecting by construction (the build still checks the meshes).
The solid inside boundary k has the tissue of layer k + 1 (the fill tissue for the innermost).

Organs that come within ``K g + organ_margin_m`` of the skin cannot be wrapped by every layer; they
are clipped to the solid ``f_K < -g`` (a boolean intersection, manifold3d), and the report says by
how much. The distances are exact to the triangles (:class:`raytrace.body.anatomy.grid.SurfaceDistance`)
on the cells within 1.5 cells of each surface and, deeper, the fast-marching solution of the eikonal
equation from there (scikit-fmm, second order). The nesting above needs no exactness at all (every
``f_k`` is made of the same two fields), only the skin's and the organs' clearances do, and those are
exact;
the meshes come from marching cubes (linear along the grid's edges: off the true level set by at most
``h^2 |curvature| / 8`` on a smooth field) and are decimated with a measured error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from raytrace.body.anatomy.decimate import decimate
from raytrace.body.anatomy.grid import Grid, SurfaceDistance, inside_mask, surface_from_field
from raytrace.body.anatomy.manifest import LayerSpec, Options
from raytrace.errors import Field, PhantomValidationError
from raytrace.physics.materials import Material

__all__ = ["Wall", "WallLayer", "generate_wall"]


@dataclass
class WallLayer:
    name: str
    material: Material
    depth_m: float
    mesh: trimesh.Trimesh
    decimation_error_m: float
    thinnest_depth_m: float
    gives_way_fraction: float


@dataclass
class Wall:
    layers: list[WallLayer]
    clip: trimesh.Trimesh | None  # organs must lie inside this solid
    grid: Grid
    notes: list[str] = field(default_factory=list)


def generate_wall(body: trimesh.Trimesh, organs: list[trimesh.Trimesh], layers: tuple[LayerSpec, ...],
                  fill: Material, fill_name: str, options: Options, *, max_cells: int, where: Field,
                  progress=None) -> Wall:
    """The wall's layer solids, innermost last, and the solid organs must lie in (module docstring)."""
    h, g, m = options.wall_grid_m, options.min_layer_m, options.organ_margin_m
    K = len(layers)
    depths = np.cumsum([layer.thickness_m for layer in layers])
    far = float(depths[-1] + m + K * g + 4 * h)
    grid = Grid.around(body.bounds[0], body.bounds[1], h, 3, max_cells, where, "the body wall")
    notes: list[str] = []
    body_inside = inside_mask(body, grid)
    if body_inside.bad_columns:
        notes.append(f"{body_inside.bad_columns} grid column(s) of ambiguous parity through the body left outside")
    inside = body_inside.mask
    if not inside.any():
        raise PhantomValidationError("the body surface encloses no grid cell: is it closed, and its units right?",
                                     field=where)
    if progress:
        progress("body wall: distances to the body surface")
    body_distance = SurfaceDistance(body.vertices, body.faces, h)
    s_b = _signed_distance(inside, body_distance, grid, far)
    if organs:
        if progress:
            progress("body wall: distances to the organs")
        organ_inside = np.zeros(grid.shape, dtype=bool)
        for organ in organs:
            organ_inside |= inside_mask(organ, grid).mask
        union = trimesh.util.concatenate(organs)
        s_o = _signed_distance(organ_inside, SurfaceDistance(union.vertices, union.faces, h), grid, far)
    else:
        s_o = np.full(grid.shape, far, dtype=np.float32)
    out: list[WallLayer] = []
    budget = options.max_triangles_per_surface
    clip = None
    for k in range(1, K + 1):
        if progress:
            progress(f"body wall: layer boundary {k} of {K}")
        m_k = m + (K - k) * g
        f = np.maximum(np.minimum(s_b + depths[k - 1], s_o - m_k), s_b + k * g)
        mesh = _clean(surface_from_field(f, grid, 0.0), h)
        mesh, error = decimate(mesh, budget, options.decimation_error_m)
        name, material = (layers[k].name, layers[k].material) if k < K else (fill_name, fill)
        depth = body_distance(mesh.vertices)
        thinnest = float(depth.min()) if len(depth) else 0.0
        gives_way = float(np.mean(depth < depths[k - 1] - h)) if len(depth) else 0.0
        out.append(WallLayer(name, material, float(depths[k - 1]), mesh, error, thinnest, gives_way))
        if k == K and organs:
            clip = _clean(surface_from_field(f + g, grid, 0.0), h)
            clip, _ = decimate(clip, budget, options.decimation_error_m)
    return Wall(out, clip, grid, notes)


def _signed_distance(inside: np.ndarray, distance: SurfaceDistance, grid: Grid, far: float) -> np.ndarray:
    """Signed distance (negative inside) on the grid, to ``far``: exact on the cells within 1.5 cells of
    the surface (the front), and elsewhere the second-order fast-marching solution of the eikonal
    equation from that front (scikit-fmm), which is smooth and within a small fraction of a cell of the
    exact distance for fronts that are smooth on the scale of a cell."""
    import skfmm
    from scipy.ndimage import distance_transform_edt

    h = grid.spacing_m
    approx = np.where(inside, -np.maximum(distance_transform_edt(inside) - 0.5, 0.0),
                      np.maximum(distance_transform_edt(~inside) - 0.5, 0.0)) * h
    front = np.flatnonzero((np.abs(approx) <= 1.5 * h).ravel())
    exact = distance(grid.points(front))
    exact = np.where(inside.reshape(-1)[front], -exact, exact)
    phi = approx.reshape(-1)
    phi[front] = exact
    phi = phi.reshape(grid.shape)
    marched = skfmm.distance(phi, dx=h, order=2, narrow=far)
    out = np.where(np.ma.getmaskarray(marched), np.sign(phi) * far, np.ma.getdata(marched)).astype(np.float32)
    flat = out.reshape(-1)
    flat[front] = exact
    return out


def _clean(mesh: trimesh.Trimesh, h: float) -> trimesh.Trimesh:
    """Outward, and without specks of a few cells (islands of the field's noise)."""
    parts = mesh.split(only_watertight=False)
    if len(parts) > 1:
        keep = [p for p in parts if abs(p.volume) >= 8 * h**3]
        mesh = trimesh.util.concatenate(keep) if keep else mesh
    if mesh.volume < 0:
        mesh.invert()
    return mesh
