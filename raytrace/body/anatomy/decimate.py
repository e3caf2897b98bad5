"""Decimation to a triangle budget with a measured, bounded error (fast-simplification's quadric edge
collapse, aggressiveness :data:`AGGRESSIVENESS`; manifold3d's simplification where that pinches;
docs/phantoms.md, "Decimation").

:func:`decimate` asks fast-simplification for the budget; the result's distance from the input surface
is then measured at every vertex and triangle centroid of the result (the exact distance to the input's
triangles, :class:`raytrace.body.anatomy.grid.SurfaceDistance`). A result is kept only when it is still
closed and two-manifold (every edge shared by exactly two triangles, consistently wound), with as many
pieces as the input, no triangle of zero area and no edge through a triangle (walls pressed together, each
moved by up to the error, may pass through each other), within ``max_error_m``; otherwise the reduction is
relaxed (budget x 1.5, up to four times), and the least-reduced closed result is kept when only the error
bound failed. A handle narrower than the error may close (a marching-cubes surface has many a voxel wide).

The result is taken as fast-simplification indexes it, never re-welded by position (trimesh's
``process`` joins vertices a few nanometres apart, which marching cubes leaves near grid nodes, without
the link condition: an edge shared by four triangles). fast-simplification itself does not check the
link condition either: where walls are pressed together (the voxel-remeshed small intestine) every
reduction leaves a few edges shared by four triangles, the pinch. Then manifold3d's ``simplify`` (edge
collapses that keep the surface a manifold, each moving it by less than a tolerance) is used instead:
tolerances from 0.6 x ``max_error_m`` down (x 0.75, up to six times) until the measured error is within
the bound. Where its result crosses itself (walls a fraction of a millimetre apart), the input's triangles
within 3 mm of each crossing are made features of their own, which it does not collapse, and it runs again
(up to four rounds). From that result fast-simplification is tried again for the budget (relaxed as above,
the error still measured from the input, no crossing allowed). What is kept may then be over the budget:
the report says how many triangles and the error.
"""

from __future__ import annotations

import numpy as np
import trimesh

from raytrace.body.anatomy.grid import SurfaceDistance

__all__ = ["decimate", "surface_error"]

_RELAX = 1.5
#: fast-simplification's aggressiveness (its default is 7): 3 keeps the largest error about 3x smaller at the
#: same budget (measured on the CT abdomen's wall layers: 0.41 mm against 1.2 mm at 65k triangles), for ~20 %
#: more time.
AGGRESSIVENESS = 3
_TRIES = 5
_MANIFOLD_TRIES = 6
_OFFSET_FACTORS = (1.0, 2.0, 4.0)
#: manifold3d's first tolerance (x max_error_m) and its step down: its measured error runs up to ~2x the
#: tolerance on marching-cubes surfaces (0.66 mm at 0.3 mm on the remeshed small intestine).
_MANIFOLD_START, _MANIFOLD_STEP = 0.6, 0.75
#: Where manifold3d's result crosses itself, the input's triangles within this distance of each crossing are
#: kept (their edges made features, which it does not collapse), up to this many rounds.
_PROTECT_RADIUS_M, _PROTECT_ROUNDS = 0.003, 4


def surface_error(original: SurfaceDistance, mesh: trimesh.Trimesh) -> float:
    """Largest distance from the vertices and triangle centroids of ``mesh`` to ``original``."""
    points = np.vstack([mesh.vertices, mesh.triangles_center])
    return float(np.max(original(points))) if len(points) else 0.0


def _indexed(points: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    """A decimator's output as it indexes it (module docstring: no weld by position)."""
    # copies: manifold3d's arrays are read-only views, which fast-simplification's binding refuses
    out = trimesh.Trimesh(np.array(points, np.float64, order="C"), np.array(faces, np.int64, order="C"),
                          process=False, validate=False)
    out.remove_unreferenced_vertices()
    return out


def _kept(out: trimesh.Trimesh, pieces: int) -> bool:
    """Closed two-manifold, consistently wound, ``pieces`` pieces, no zero-area triangle (module docstring)."""
    if not (len(out.faces) >= 4 and out.is_watertight and out.is_winding_consistent):
        return False
    tri = out.vertices[out.faces]
    if not np.all(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1]), axis=1) > 0.0):
        return False
    return int(out.body_count) == pieces


def _quadric(mesh: trimesh.Trimesh, target: int) -> trimesh.Trimesh:
    import fast_simplification

    reduction = 1.0 - min(1.0, target / len(mesh.faces))
    points, faces = fast_simplification.simplify(np.ascontiguousarray(mesh.vertices, np.float64),
                                                 np.ascontiguousarray(mesh.faces, np.int64), reduction,
                                                 agg=AGGRESSIVENESS)
    return _indexed(points, faces)


def _outward(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _crossings(mesh: trimesh.Trimesh) -> np.ndarray:
    """Where an edge of the surface crosses one of its triangles (walls pressed together, each moved by up to
    the error, can pass through each other), (k, 3): :func:`raytrace.body.selfintersect.edge_crossings`
    through one Embree scene of the surface, cast with its own segment offset and with 2x and 4x it. A
    crossing shallower than the offset can hide from one offset and show at another, and the phantom's scene,
    with the body around the organ, has a larger one (2x on the shared abdomen): what any of them finds is a
    crossing."""
    from raytrace.body.phantom import check_surfaces
    from raytrace.body.rays import RayScene
    from raytrace.body.selfintersect import edge_crossings

    surfaces = check_surfaces([mesh], ["surface"])
    scene = RayScene(surfaces.vertices, surfaces.faces, surfaces.face_normals)
    own = scene.offset_m
    for factor in _OFFSET_FACTORS:
        scene.offset_m = own * factor
        where = edge_crossings(surfaces.vertices, surfaces.faces, surfaces.edges, surfaces.face_normals, scene)[2]
        if len(where):
            return where
    return np.zeros((0, 3))


def _manifold(mesh: trimesh.Trimesh, original: SurfaceDistance, budget: int, max_error_m: float,
              pieces: int) -> tuple[trimesh.Trimesh, float] | None:
    """manifold3d's simplification within the error bound, kept from crossing itself, then the budget tried
    from it (module docstring)."""
    import manifold3d
    from scipy.spatial import cKDTree

    solid = manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(mesh.vertices, np.float64),
                                                  np.ascontiguousarray(mesh.faces, np.uint64)))
    if solid.status() != manifold3d.Error.NoError:
        return None
    table = solid.to_mesh64()
    points = np.array(table.vert_properties, np.float64)[:, :3]
    triangles = np.array(table.tri_verts, np.uint64)
    centres = cKDTree(points[triangles.astype(np.int64)].mean(axis=1))
    tolerance = _MANIFOLD_START * max_error_m
    for _ in range(_MANIFOLD_TRIES):
        kept: tuple[trimesh.Trimesh, float] | None = None
        face_id = np.zeros(len(triangles), np.uint64)  # one face: manifold3d collapses by geometry alone
        for _ in range(_PROTECT_ROUNDS):
            result = manifold3d.Manifold(manifold3d.Mesh64(points, triangles, face_id=face_id)).simplify(tolerance)
            table = result.to_mesh64()
            out = _indexed(np.asarray(table.vert_properties)[:, :3], np.asarray(table.tri_verts))
            if not (len(out.faces) < len(mesh.faces) and _kept(out, pieces)):
                break
            out = _outward(out)
            error = surface_error(original, out)
            if error > max_error_m:
                break
            where = _crossings(out)
            if not len(where):
                kept = (out, error)
                break
            # keep the input's triangles around each crossing: a face each, whose edges manifold3d keeps
            near = np.unique(np.concatenate([np.asarray(i, np.int64) for i in
                                             centres.query_ball_point(where, _PROTECT_RADIUS_M)]))
            face_id[near] = 1 + near.astype(np.uint64)
        tolerance *= _MANIFOLD_STEP
        if kept is None:
            continue
        out, error = kept
        target = budget
        while target < len(out.faces):  # the budget from the manifold result, relaxed as above
            finer = _quadric(out, target)
            target = int(target * _RELAX)
            if _kept(finer, pieces):
                finer = _outward(finer)
                finer_error = surface_error(original, finer)  # from the input, not from ``out``
                if finer_error <= max_error_m and not len(_crossings(finer)):
                    return finer, finer_error
        return kept
    return None


def decimate(mesh: trimesh.Trimesh, budget: int, max_error_m: float) -> tuple[trimesh.Trimesh, float]:
    """(the mesh with at most about ``budget`` triangles, its measured error [m]) (module docstring); the mesh
    itself and 0 when nothing within the bound keeps it closed."""
    if len(mesh.faces) <= budget:
        return mesh, 0.0
    pieces = int(mesh.body_count)
    spacing = float(np.median(mesh.edges_unique_length)) / 2.0
    original = SurfaceDistance(mesh.vertices, mesh.faces, max(spacing, 1e-6))
    best: tuple[trimesh.Trimesh, float] | None = None
    target = budget
    for _ in range(_TRIES):
        if target >= len(mesh.faces):
            break
        out = _quadric(mesh, target)
        target = int(target * _RELAX)
        if _kept(out, pieces):
            out = _outward(out)
            error = surface_error(original, out)
            if error <= max_error_m:
                if not len(_crossings(out)):
                    return out, error
            elif best is None or error < best[1]:
                best = (out, error)
    if best is not None and not len(_crossings(best[0])):
        return best
    return _manifold(mesh, original, budget, max_error_m, pieces) or (mesh, 0.0)
