"""Overlaps between organs, and organs against the body: resolved by clipping below a tolerance,
refused above it (docs/phantoms.md, "Overlaps").

Two organs whose surfaces cross (an edge of one through a triangle of the other, found by one Embree ray per
edge, :func:`crossing_pairs`) are intersected exactly (manifold3d's boolean intersection). When the
intersection holds volume but is not the whole of either (one nested in the other is no overlap):

* the *depth* of the overlap is the largest distance from a vertex of one that lies inside the other
  to the other's surface (both ways; exact distances to the triangles);
* deeper than ``overlap_tolerance_m``: the build is refused, naming both organs, the depth, the
  volume they share and where they meet (the centroid of the intersection, in the project frame);
* otherwise one organ is clipped, the other kept: when most of one lies inside the other it is meant
  to nest, and the inner one is clipped to the outer one pulled in by ``clearance_m``; else they are
  neighbours, and the organ listed *later* in the manifest gives way, minus the earlier one grown by
  ``clearance_m``. The report names the clipped organ, the other, the depth and the volume removed.

Growing or pulling in a surface by ``clearance_m`` moves its vertices along their normals, which is an
offset as long as ``clearance_m`` is small against the surface's features (a fraction of a millimetre
against organs of centimetres); the final phantom's checks (:meth:`Phantom.build`) hold either way.
"""

from __future__ import annotations

import numpy as np
import trimesh

from raytrace.body.anatomy.grid import SurfaceDistance
from raytrace.body.phantom import Surfaces, check_surfaces, surface_crossings
from raytrace.body.topology import ClosedEdges
from raytrace.errors import Field, PhantomValidationError

__all__ = ["clip_inside", "intersect", "resolve_overlaps", "subtract"]


def _manifold(mesh: trimesh.Trimesh, origin: np.ndarray):
    """manifold3d's solid of a closed surface, in float64 about ``origin`` (float32 would merge the vertices
    nanometres apart that marching cubes leaves, into triangles of no area)."""
    import manifold3d

    return manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(mesh.vertices - origin, np.float64),
                                                 np.ascontiguousarray(mesh.faces, np.uint64)))


def _mesh(m, origin: np.ndarray) -> trimesh.Trimesh:
    """The surface of a manifold3d solid as it indexes it: never welded by position (trimesh's ``process``
    joins vertices closer than 1e-8 without regard to the triangles around them, which can leave an edge
    shared by four triangles)."""
    out = m.to_mesh64()
    verts = np.array(out.vert_properties, np.float64)[:, :3] + origin
    mesh = trimesh.Trimesh(verts, np.array(out.tri_verts, np.int64), process=False, validate=False)
    mesh.remove_unreferenced_vertices()
    return mesh


def _offset(mesh: trimesh.Trimesh, distance_m: float) -> trimesh.Trimesh:
    moved = mesh.copy()
    moved.vertices = mesh.vertices + distance_m * mesh.vertex_normals
    return moved


def intersect(a: trimesh.Trimesh, b: trimesh.Trimesh) -> trimesh.Trimesh:
    origin = a.bounds.mean(axis=0)
    return _mesh(_manifold(a, origin) ^ _manifold(b, origin), origin)


def subtract(a: trimesh.Trimesh, b: trimesh.Trimesh) -> trimesh.Trimesh:
    origin = a.bounds.mean(axis=0)
    return _mesh(_manifold(a, origin) - _manifold(b, origin), origin)


def _box(mesh: trimesh.Trimesh) -> np.ndarray:
    """(2, 3) bounds of a mesh's vertices (numpy's; trimesh's property hashes the arrays to validate its cache)."""
    vertices = np.asarray(mesh.vertices)
    return np.stack([vertices.min(axis=0), vertices.max(axis=0)])


class _Gaps:
    """min_gap between organs (manifold3d), each organ's manifold and bounds made once (in float32 about one
    origin, the organs' common centre: a body's extent keeps a float32 ulp below 0.1 um)."""

    def __init__(self, meshes: dict[str, trimesh.Trimesh]) -> None:
        self.bounds = {id(m): _box(m) for m in meshes.values()}
        every = np.array(list(self.bounds.values())) if self.bounds else np.zeros((1, 2, 3))
        self.origin = 0.5 * (every[:, 0].min(axis=0) + every[:, 1].max(axis=0))
        self.manifolds: dict[int, object] = {}

    def _bounds(self, mesh: trimesh.Trimesh) -> np.ndarray:
        if id(mesh) not in self.bounds:
            self.bounds[id(mesh)] = _box(mesh)
        return self.bounds[id(mesh)]

    def _manifold(self, mesh: trimesh.Trimesh):
        if id(mesh) not in self.manifolds:
            self.manifolds[id(mesh)] = _manifold(mesh, self.origin)
        return self.manifolds[id(mesh)]

    def touching(self, a: trimesh.Trimesh, b: trimesh.Trimesh, clearance_m: float) -> bool:
        """Whether the surfaces of two neighbouring organs come closer than ``clearance_m`` (manifold3d's
        ``min_gap``). A pair whose bounding boxes nest is left to the phantom's own checks: one organ is then
        most likely inside the other, and giving way would hollow the outer one."""
        (lo_a, hi_a), (lo_b, hi_b) = self._bounds(a), self._bounds(b)
        if np.any(hi_a + clearance_m < lo_b) or np.any(hi_b + clearance_m < lo_a):
            return False
        if (np.all(lo_a <= lo_b) and np.all(hi_b <= hi_a)) or (np.all(lo_b <= lo_a) and np.all(hi_a <= hi_b)):
            return False
        return float(self._manifold(a).min_gap(self._manifold(b), clearance_m)) < clearance_m


def _drop_specks(mesh: trimesh.Trimesh, min_volume: float) -> trimesh.Trimesh:
    parts = mesh.split(only_watertight=False)
    keep = [p for p in parts if abs(_volume(p)) >= min_volume]
    return trimesh.util.concatenate(keep) if len(keep) != len(parts) and keep else mesh


def _volume(mesh: trimesh.Trimesh) -> float:
    """The mesh's enclosed volume [m^3]; a flat one (touching caps' intersection) is 0 whatever numpy's error
    setting (trimesh divides by the volume for the centre of mass; gprMax, once imported, makes that raise)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(mesh.volume)


def _depth(a: trimesh.Trimesh, b: trimesh.Trimesh, b_distance: SurfaceDistance) -> float:
    inside = b.contains(a.vertices) if len(a.vertices) else np.zeros(0, bool)
    return float(b_distance(a.vertices[inside]).max()) if inside.any() else 0.0


def _mm(x: float) -> str:
    return f"{x * 1e3:.3g} mm"


def _give_way(meshes: dict[str, trimesh.Trimesh], notes: dict[str, list[str]], first: str, second: str,
              clearance_m: float) -> None:
    """``second`` (listed later) minus ``first`` grown by ``clearance_m``, for two organs that touch without
    sharing volume (module doc); left as it is when nothing of it would be left."""
    a, b = meshes[first], meshes[second]
    moved = _drop_specks(subtract(b, _offset(a, clearance_m)), 1e-9)
    if len(moved.faces):
        removed = float(b.volume - moved.volume)
        meshes[second] = moved
        notes[second].append(f"touched {first!r}: gave way by {_mm(clearance_m)} ({removed * 1e6:.3g} mL removed)")


def resolve_overlaps(organs: dict[str, trimesh.Trimesh], fields: dict[str, Field], tolerance_m: float,
                     clearance_m: float, crossing: set[tuple[int, int]] | None = None,
                     ) -> tuple[dict[str, trimesh.Trimesh], dict[str, list[str]]]:
    """Organs (in manifest order) with their pairwise overlaps resolved, and the notes per organ (module doc);
    ``crossing``: the pairs :func:`crossing_pairs` found, when the caller has them."""
    names = list(organs)
    meshes = dict(organs)
    notes: dict[str, list[str]] = {n: [] for n in names}
    if crossing is None:
        crossing = set(crossing_pairs([meshes[n] for n in names], names).crossings)
    gaps = _Gaps(meshes)
    for i, first in enumerate(names):
        for j in range(i + 1, len(names)):
            second = names[j]
            a, b = meshes[first], meshes[second]
            if (i, j) not in crossing:
                if gaps.touching(a, b, clearance_m):  # closer than the clearance, e.g. shared caps of cut pieces
                    _give_way(meshes, notes, first, second, clearance_m)
                continue
            shared = intersect(a, b)
            volume = _volume(shared) if len(shared.faces) else 0.0
            if volume <= 0.0:
                # flagged as crossing yet sharing no volume: the surfaces touch (e.g. the caps of two cut pieces
                # meeting exactly), which the phantom would refuse as a crossing once stored in float32
                _give_way(meshes, notes, first, second, clearance_m)
                continue
            if volume >= (1.0 - 1e-6) * min(a.volume, b.volume):
                continue  # one nested in the other: no surface crosses (the phantom checks touching)
            da, db = SurfaceDistance(a.vertices, a.faces, clearance_m * 4 + 1e-4), \
                SurfaceDistance(b.vertices, b.faces, clearance_m * 4 + 1e-4)
            depth = max(_depth(a, b, db), _depth(b, a, da))
            where = np.round(shared.centroid * 1e3, 1).tolist()
            if depth > tolerance_m:
                raise PhantomValidationError(
                    f"organs {first!r} and {second!r} overlap by {_mm(depth)} ({volume * 1e6:.3g} mL shared, "
                    f"around {where} mm in the project frame), more than overlap_tolerance_m = {_mm(tolerance_m)}: "
                    "they cross; "
                    "fix the surfaces (or raise options.overlap_tolerance_m to clip the later one)",
                    field=fields[second])
            a_in_b = float(np.mean(b.contains(a.vertices)))
            b_in_a = float(np.mean(a.contains(b.vertices)))
            if b_in_a >= 0.5 or a_in_b >= 0.5:
                inner, outer = (second, first) if b_in_a >= a_in_b else (first, second)
                clipped = intersect(meshes[inner], _offset(meshes[outer], -clearance_m))
                how = f"clipped to the inside of {outer!r} (it is meant to nest in it)"
            else:
                inner, outer = second, first
                clipped = subtract(meshes[inner], _offset(meshes[outer], clearance_m))
                how = f"gave way to {outer!r} (listed before it)"
            clipped = _drop_specks(clipped, 1e-9)
            if not len(clipped.faces):
                raise PhantomValidationError(f"organ {inner!r} lies within {outer!r}: clipping left nothing of it",
                                             field=fields[inner])
            removed = float(meshes[inner].volume - clipped.volume)
            meshes[inner] = clipped
            notes[inner].append(f"overlapped {outer!r} by {_mm(depth)} around {where} mm: {how}, "
                                f"{removed * 1e6:.3g} mL removed, {_mm(clearance_m)} clearance")
    return meshes, notes


def crossing_pairs(meshes: list[trimesh.Trimesh], names: list[str] | None = None,
                   known: list[ClosedEdges | None] | None = None) -> Surfaces:
    """The surfaces checked and tested for crossings (:func:`raytrace.body.phantom.surface_crossings`): its
    ``crossings`` are the pairs ``(i, j)``, ``i <= j``, of surfaces that cross (``(i, i)``: surface i crosses
    itself), every edge cast once as a segment through one Embree scene of all of them, so that only
    crossing pairs pay for a boolean; the anatomy build hands the result on to :meth:`Phantom.build`.
    ``known``: the surfaces' closed edges where the caller has them (:func:`check_surfaces`)."""
    names = names or [f"surface{k}" for k in range(len(meshes))]
    return surface_crossings(check_surfaces(meshes, names, known))


def clip_inside(organ: trimesh.Trimesh, container: trimesh.Trimesh, what: str) -> tuple[trimesh.Trimesh, str | None]:
    """``organ`` inside ``container`` (unchanged when it already is); the note when it was clipped."""
    outside = ~container.contains(organ.vertices)
    if not outside.any():
        return organ, None
    clipped = _drop_specks(intersect(organ, container), 1e-9)
    if not len(clipped.faces):
        return clipped, f"nothing of it lies inside {what}"
    removed = float(organ.volume - clipped.volume)
    where = np.round(organ.vertices[outside].mean(axis=0) * 1e3, 1).tolist()
    return clipped, (f"clipped to {what} where it came too close to the skin (around {where} mm): "
                     f"{removed * 1e6:.3g} mL removed")
