"""One Embree scene of a set of triangles for the body's own ray queries: a phantom's medium lookups and
containment tree, the crossing checks (:mod:`raytrace.body.selfintersect`), the anatomy pipeline's.

Built with the tracer's own Embree binding (:class:`raytrace.engine.embree.EmbreeScene`: robust, i.e.
watertight, traversal; float32 triangles, centred on their bounding box's centre as the tracer's scene
centres them), which builds a BVH about twice as fast as embreex's scene through trimesh (whose binding
copies the vertices one Python index at a time); docs/architecture.md says why ``raytrace.body`` may use
the binding. Queries are cast in float32 from the origins less the centre; the distance to a hit is then
recomputed in float64 on the hit triangle's plane from the true origin (so a point's distance to the
surface it lies near is not rounded to float32), except for rays within 1e-6 of parallel to that plane,
where Embree's float32 distance stands. Rays may end at a distance (``tfar``:
:func:`raytrace.engine.segments.segment_hits`), which is what makes a segment query cheap.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RayScene"]

#: Below this |n . d| a hit's distance is Embree's float32 one (the plane's is ill-conditioned).
_PARALLEL = 1e-6
#: Offset of a re-cast ray past the last hit, in float32 ulps of the largest centred coordinate (the
#: tracer's spawn offset, raytrace.engine.scene.OFFSET_ULPS).
OFFSET_ULPS = 16.0


class RayScene:
    """First hits of rays (and segments) among triangles ``faces`` of ``vertices`` (module docstring).
    ``normals``: the unit facet normals, when the caller has them."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> None:
        from raytrace.engine.embree import EmbreeScene

        self.vertices = np.asarray(vertices, float)
        self.faces = np.asarray(faces, np.int64)
        if len(self.vertices):
            lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        else:
            lo = hi = np.zeros(3)
        self.center = 0.5 * (lo + hi)
        self.scale_m = float(np.linalg.norm(hi - lo)) or 1.0
        centred = self.vertices - self.center
        self.embree = EmbreeScene(centred, self.faces)
        magnitude = float(np.abs(centred).max()) if len(centred) else 1.0
        #: A distance a few float32 ulps of the scene's coordinates: what a query must move to be another.
        self.offset_m = float(OFFSET_ULPS * np.spacing(np.float32(max(magnitude, 1e-6))))
        if normals is None:
            tri = self.vertices[self.faces]
            normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            length = np.linalg.norm(normals, axis=1, keepdims=True)
            normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
        self.normals = np.asarray(normals, float)

    @property
    def triangles(self) -> int:
        return int(len(self.faces))

    def first_hits(self, origins: np.ndarray, directions: np.ndarray,
                   tfar: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(face, distance)`` of the first triangle along each ray (``-1``, ``inf`` on a miss); with
        ``tfar``, only hits at most that far along the (unit) direction count."""
        origins = np.asarray(origins, float).reshape(-1, 3)
        directions = np.asarray(directions, float).reshape(-1, 3)
        query = origins - self.center
        if tfar is None:
            hits = self.embree.intersect(query, directions)
            face, t32 = np.asarray(hits.prim, np.int64), np.asarray(hits.tfar)
        else:
            from raytrace.engine.segments import segment_hits

            face, t32 = segment_hits(self.embree, query, directions, np.asarray(tfar, float))
        distance = np.full(len(face), np.inf)
        hit = np.flatnonzero(face >= 0)
        if len(hit):
            f = face[hit]
            n = self.normals[f]
            d = directions[hit]
            nd = np.einsum("ij,ij->i", n, d)
            exact = np.einsum("ij,ij->i", n, self.vertices[self.faces[f, 0]] - origins[hit])
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(np.abs(nd) > _PARALLEL, exact / nd, t32[hit])
            distance[hit] = np.maximum(t, 0.0)
        return face, distance

    def edge_hits(self, pairs: np.ndarray, face: np.ndarray, twin: np.ndarray, trim: float,
                  offset_m: float) -> tuple[np.ndarray, np.ndarray]:
        """First hits of one segment beside each edge (``pairs`` of vertex indices of this scene, each with its
        two triangles ``face`` and ``twin``), as :func:`raytrace.engine.segments.edge_segment_hits` casts them:
        ``(face, t)``, ``t`` the float32 distance from the segment's start (-1, inf on a miss)."""
        from raytrace.engine.segments import edge_segment_hits

        return edge_segment_hits(self.embree, self.center, self.vertices, pairs, face, twin, self.normals, trim,
                                 offset_m)

    def intersects_id(self, ray_origins: np.ndarray, ray_directions: np.ndarray, multiple_hits: bool = False,
                      return_locations: bool = False, max_hits: int = 1000):
        """trimesh's ``RayMeshIntersector.intersects_id`` on this scene: ``(triangle, ray, location)`` of the
        first hit of each ray, or of every hit along it (``multiple_hits``: re-cast past each hit)."""
        origins = np.asarray(ray_origins, float).reshape(-1, 3)
        directions = np.asarray(ray_directions, float).reshape(-1, 3)
        directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        tris, rays, locs = [], [], []
        alive = np.arange(len(origins))
        start = origins.copy()
        for _ in range(max_hits if multiple_hits else 1):
            if not len(alive):
                break
            face, distance = self.first_hits(start[alive], directions[alive])
            hit = face >= 0
            alive, face, distance = alive[hit], face[hit], distance[hit]
            loc = start[alive] + distance[:, None] * directions[alive]
            tris.append(face)
            rays.append(alive)
            locs.append(loc)
            start[alive] = loc + self.offset_m * directions[alive]
        tri = np.concatenate(tris) if tris else np.zeros(0, np.int64)
        ray = np.concatenate(rays) if rays else np.zeros(0, np.int64)
        loc = np.concatenate(locs) if locs else np.zeros((0, 3))
        if return_locations:
            return tri, ray, loc
        return tri, ray
