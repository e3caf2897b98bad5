"""Sensor candidates on a phantom's outermost organ surface (docs/design.md, "Candidates").

Contact sensors sit in the outermost organ (the skin of the torso), ``depth_m`` below its outer
surface, like the phantom's own contact sensor sites. Nothing here knows a particular phantom: the
outer surface is every organ whose parent is air (:attr:`raytrace.Phantom.parent`), and the
candidates are either its mesh vertices or an even grid of points on it:

* ``spacing_m`` null: every vertex of the outer surface, moved ``depth_m`` inwards along its smooth
  vertex normal;
* ``spacing_m`` given: points on the outer surface no closer than ``spacing_m`` to each other
  (a dense area-weighted sample of the surface, trimesh's with seed 0, thinned in order: a point is
  kept unless a kept one lies within the spacing; the same phantom and spacing always give the
  same grid), each moved ``depth_m`` inwards along the normal
  interpolated at it from the vertex normals.

Candidates are kept only where the moved point lies in the outer organ itself (a thin layer would
put it in the organ inside) and at least the antennas' clearance from every surface
(:meth:`raytrace.Phantom.check_antenna_clearance`), and inside ``region`` (a box) when one is
given. With ``include_sites`` the phantom's sensor sites are added at the end, named, so that a
layout can be compared with the phantom's own sensors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from design.checks import boolean, mapping, number, vector
from design.errors import DesignInputError
from raytrace.body.phantom import AIR_INDEX, Phantom
from raytrace.errors import InputError

#: Default depth of a contact candidate below the outer surface [m] (the torso's sensor sites' depth).
DEFAULT_DEPTH_M = 1e-3
#: Fewest and most candidates of one request (before the sites are added).
MAX_CANDIDATES = 20_000
#: Dense samples per candidate of the Poisson-disc grid (more: a more even grid).
_OVERSAMPLE = 12


@dataclass(frozen=True)
class CandidateSpec:
    """How candidates are made (module docstring); :meth:`from_dict` reads the JSON form."""

    spacing_m: float | None = 0.015
    depth_m: float = DEFAULT_DEPTH_M
    region_min_m: tuple[float, float, float] | None = None
    region_max_m: tuple[float, float, float] | None = None
    include_sites: bool = True

    @classmethod
    def from_dict(cls, data, field: str = "candidates") -> "CandidateSpec":
        data = mapping(data or {}, field, {"spacing_m", "depth_m", "region", "include_sites"})
        spacing = data.get("spacing_m", 0.015)
        spacing = None if spacing is None else number(spacing, f"{field}.spacing_m", lo=0.002, hi=0.5)
        depth = number(data.get("depth_m", DEFAULT_DEPTH_M), f"{field}.depth_m", lo=1e-5, hi=0.05)
        lo = hi = None
        region = data.get("region")
        if region is not None:
            region = mapping(region, f"{field}.region", {"min_m", "max_m"})
            lo = tuple(vector(region.get("min_m", [-1e3] * 3), f"{field}.region.min_m").tolist())
            hi = tuple(vector(region.get("max_m", [1e3] * 3), f"{field}.region.max_m").tolist())
            if any(a >= b for a, b in zip(lo, hi)):
                raise DesignInputError("every max_m coordinate must exceed its min_m", f"{field}.region.max_m")
        include = boolean(data.get("include_sites", True), f"{field}.include_sites")
        return cls(spacing, depth, lo, hi, include)

    def to_dict(self) -> dict:
        region = None if self.region_min_m is None else {"min_m": list(self.region_min_m),
                                                          "max_m": list(self.region_max_m)}
        return {"spacing_m": self.spacing_m, "depth_m": self.depth_m, "region": region,
                "include_sites": self.include_sites}


@dataclass(frozen=True)
class Candidates:
    """Sensor candidates: positions [m], outward unit normals, the organ each is in, and the site
    name of those that are the phantom's own sensor sites (``""`` for the others)."""

    positions_m: np.ndarray  # (C, 3)
    normals: np.ndarray  # (C, 3)
    organ: tuple[str, ...]
    site: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.positions_m)

    def to_dict(self) -> dict:
        return {"positions_m": self.positions_m.tolist(), "normals": self.normals.tolist(),
                "organ": list(self.organ), "site": list(self.site)}

    @classmethod
    def from_dict(cls, d: dict) -> "Candidates":
        return cls(np.asarray(d["positions_m"], float).reshape(-1, 3), np.asarray(d["normals"], float).reshape(-1, 3),
                   tuple(d["organ"]), tuple(d["site"]))


def outer_organs(phantom: Phantom) -> list[int]:
    """Indices of the organs whose parent is air: the phantom's outermost surface."""
    return [i for i in range(len(phantom.organs)) if int(phantom.parent[i]) == AIR_INDEX]


def _surface_points(mesh: trimesh.Trimesh, spacing_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Points on ``mesh`` and their smooth outward normals (module docstring)."""
    vertices = np.asarray(mesh.vertices, float)
    vnormals = np.asarray(mesh.vertex_normals, float)
    if spacing_m is None:
        return vertices, vnormals
    count = int(np.ceil(_OVERSAMPLE * mesh.area / spacing_m**2))
    if count > 50 * MAX_CANDIDATES:
        raise DesignInputError(f"a spacing of {spacing_m:g} m on {mesh.area:.3g} m^2 of surface makes about "
                               f"{mesh.area / spacing_m**2:.0f} candidates, over {MAX_CANDIDATES}: a larger spacing",
                               "candidates.spacing_m")
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=0)
    keep = _thin(np.asarray(points, float), spacing_m)
    points, faces = points[keep], faces[keep]
    tri = np.asarray(mesh.triangles, float)[faces]
    bary = trimesh.triangles.points_to_barycentric(tri, points)
    normals = np.einsum("ij,ijk->ik", bary, vnormals[np.asarray(mesh.faces)[faces]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return np.asarray(points, float), normals


def _thin(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """Indices of a subset of ``points`` no two closer than ``spacing_m``: each point in order is kept
    unless a kept one lies within the spacing (a spatial hash of cubes of the spacing's size)."""
    cells: dict[tuple[int, int, int], list[int]] = {}
    keep: list[int] = []
    key = np.floor(points / spacing_m).astype(np.int64)
    s2 = spacing_m * spacing_m
    for i, (p, k) in enumerate(zip(points, key)):
        kx, ky, kz = (int(v) for v in k)
        near = False
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for j in cells.get((kx + dx, ky + dy, kz + dz), ()):
                        d = points[j] - p
                        if d @ d < s2:
                            near = True
                            break
                    if near:
                        break
                if near:
                    break
        if not near:
            cells.setdefault((kx, ky, kz), []).append(i)
            keep.append(i)
    return np.asarray(keep, np.int64)


def _keep_valid(phantom: Phantom, points: np.ndarray, organ: int) -> np.ndarray:
    """Mask of the points whose medium is ``organ`` and that clear every surface."""
    keep = np.zeros(len(points), bool)
    try:
        medium = np.asarray(phantom.medium_index(points), np.int64)
        keep = medium == organ
    except InputError:  # some point on a surface: one by one
        for k, p in enumerate(points):
            try:
                keep[k] = int(phantom.medium_index(p[None, :])[0]) == organ
            except InputError:
                keep[k] = False
    rows = np.flatnonzero(keep)
    try:
        phantom.check_antenna_clearance(points[rows], ["p"] * len(rows))
    except InputError:
        for k in rows:
            try:
                phantom.check_antenna_clearance(points[k][None, :], ["p"])
            except InputError:
                keep[k] = False
    return keep


def skin_candidates(phantom: Phantom, spec: CandidateSpec | None = None) -> Candidates:
    """The candidates of ``spec`` on ``phantom`` (module docstring). Raises
    :class:`~design.errors.DesignInputError` naming ``candidates`` when none remain."""
    spec = spec or CandidateSpec()
    outer = outer_organs(phantom)
    pos, nrm, org = [], [], []
    for i in outer:
        points, normals = _surface_points(phantom.organs[i].mesh, spec.spacing_m)
        moved = points - spec.depth_m * normals
        if spec.region_min_m is not None:
            inside = np.all((moved >= spec.region_min_m) & (moved <= spec.region_max_m), axis=1)
            moved, normals = moved[inside], normals[inside]
        keep = _keep_valid(phantom, moved, i)
        pos.append(moved[keep])
        nrm.append(normals[keep])
        org += [phantom.organs[i].name] * int(keep.sum())
    positions = np.concatenate(pos) if pos else np.zeros((0, 3))
    normals = np.concatenate(nrm) if nrm else np.zeros((0, 3))
    if len(positions) == 0:
        where = "candidates.region" if spec.region_min_m is not None else "candidates.depth_m"
        raise DesignInputError("no sensor candidate remains on the phantom's outermost organ surface "
                               f"({', '.join(phantom.organs[i].name for i in outer) or 'none'}): the region excludes "
                               "every one, or depth_m puts them all outside the outer organ", where)
    if len(positions) > MAX_CANDIDATES:
        raise DesignInputError(f"{len(positions)} candidates exceed the limit of {MAX_CANDIDATES}: a larger spacing_m "
                               "or a smaller region", "candidates.spacing_m")
    site = [""] * len(positions)
    if spec.include_sites:
        sites = [s for s in phantom.sites.values() if s.kind == "sensor"]
        if sites:
            sp = np.array([s.position_m for s in sites], float)
            positions = np.vstack([positions, sp])
            normals = np.vstack([normals, _site_normals(phantom, sp, outer)])
            org += [s.medium for s in sites]
            site += [s.name for s in sites]
    return Candidates(positions, normals, tuple(org), tuple(site))


def _site_normals(phantom: Phantom, points: np.ndarray, outer: list[int]) -> np.ndarray:
    """Outward normal of the nearest outer-surface vertex of each site (for the plots)."""
    if not outer:
        return np.zeros_like(points)
    verts = np.vstack([np.asarray(phantom.organs[i].mesh.vertices) for i in outer])
    norms = np.vstack([np.asarray(phantom.organs[i].mesh.vertex_normals) for i in outer])
    nearest = np.argmin(((points[:, None, :] - verts[None, :, :]) ** 2).sum(axis=2), axis=1)
    return norms[nearest]
