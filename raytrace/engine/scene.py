"""Raw Embree scene of a phantom for the tracer: batched first-hit queries.

Embree (through :mod:`raytrace.engine.embree`) intersects in float32; this module uses it only to find
*which* triangle a ray hits first, then re-intersects the ray with that
triangle's plane in float64 from the true (un-offset) origin, so hit points
and path lengths carry float64 accuracy whatever the float32 rounding.

Spawned rays: the float32 query origin is pushed off the surface just left by
:attr:`TracerScene.offset_m` (a few float32 ulps of the scene's coordinate
magnitude) along the facet normal, on the side the ray travels into, so the
query never re-hits the surface it starts on; the float64 geometry still
starts exactly on the surface (``docs/tracer.md``, "Numerical care").

Two Embree scenes of the same triangles: the robust (watertight) one answers
every query whose answer is final (Newton's re-tracing, the zoomed
refraction-only walk, the straight-line signatures); the shooting and the
global refraction-only walk, which only propose seeds that Newton then
re-traces in the robust scene, cast into one built without
``RTC_SCENE_FLAG_ROBUST``: 18-22 % more rays per second on the torso, at the
price of a ray now and then slipping through a shared edge. Measured on 6
capsules x 24 receivers: the same 5732 paths either way.

Normals: the facet normal decides the side (entering / leaving an organ);
directions (reflection, refraction) use smooth normals interpolated from the
hit's barycentrics over per-corner normals (:func:`corner_normals`). An edge
whose two faces meet at a dihedral angle (between their normals) above the
organ's crease angle (:data:`CREASE_ANGLE_DEG` unless the organ sets its own
``crease_angle_deg``) is a crease: the corner normal of a face at a vertex
averages (with Max's weights, exact for vertices on a sphere) only the faces
reachable round that vertex without crossing a crease. So every face of a box,
whatever its proportions, keeps exactly its facet normal (its only edges
between differently oriented faces are 90 deg creases), and a smooth faceted
organ, whose neighbouring facets differ by a few degrees, gets one continuous
normal per vertex (docs/tracer.md, "Numerical care").
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from raytrace.body.phantom import Phantom
from raytrace.engine.embree import EmbreeScene
from raytrace.engine.records import SceneTables, ShotScene, build

#: Default crease angle [deg]: an edge whose two faces' normals differ by more than this is a crease
#: (module doc). Above the built-in torso's largest dihedral angle between neighbouring facets
#: (33.6 deg on the skin's rim at resolution 48), below a box's 90 deg.
CREASE_ANGLE_DEG = 45.0
#: Spawn offset in float32 ulps of the largest (centred) coordinate.
OFFSET_ULPS = 16.0


@dataclass
class TracerScene:
    """Everything the tracer needs about a phantom's triangles, float64 plus an Embree scene."""

    embree: EmbreeScene  # watertight traversal: every exact query (refinement, walks, signatures)
    center: np.ndarray  # (3,) float64 translation applied before float32 conversion
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    face_organ: np.ndarray  # (F,) int
    face_normals: np.ndarray  # (F, 3) float64 unit, outward
    plane_d: np.ndarray  # (F,) n . v0
    corner_normals: np.ndarray  # (F, 3, 3) per-corner smooth normals (creased)
    scale_m: float  # bounding-box diagonal
    offset_m: float  # spawn offset
    face_map: np.ndarray | None = None  # Embree primitive -> phantom face (None: identity)
    _shooting: EmbreeScene | None = field(default=None, repr=False, compare=False)
    _shooting_lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    @property
    def embree_shooting(self) -> EmbreeScene:
        """The same triangles with Embree's fast (non-robust) traversal, for seed searches only
        (module doc); built on first use (the full scene of the final re-trace never needs it),
        once, whichever thread asks first."""
        with self._shooting_lock:
            if self._shooting is None:
                kept = self.faces if self.face_map is None else self.faces[self.face_map]
                self._shooting = EmbreeScene(self.vertices - self.center, kept, robust=False)
            return self._shooting

    @classmethod
    def build(cls, phantom: Phantom, visible: np.ndarray | None = None) -> "TracerScene":
        """Scene of all triangles, or only of ``visible`` ones (surfaces between identical
        materials are invisible to propagation; face indices stay the phantom's)."""
        vertices = np.asarray(phantom.vertices, dtype=float)
        faces = np.asarray(phantom.faces, dtype=np.int64)
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        center = 0.5 * (lo + hi)
        centred = vertices - center
        face_map = None if visible is None else np.flatnonzero(visible)
        embree = EmbreeScene(centred, faces if face_map is None else faces[face_map])
        fn = np.asarray(phantom.face_normals, dtype=float)
        fn = fn / np.linalg.norm(fn, axis=1, keepdims=True)
        crease_deg = np.array([CREASE_ANGLE_DEG if o.crease_angle_deg is None else float(o.crease_angle_deg)
                               for o in phantom.organs])
        corners = corner_normals(vertices, faces, fn, crease_deg[np.asarray(phantom.face_organ, np.int64)])
        magnitude = float(np.abs(centred).max())
        ulp = np.spacing(np.float32(max(magnitude, 1e-6)))
        return cls(
            embree=embree,
            center=center,
            vertices=vertices,
            faces=faces,
            face_organ=np.asarray(phantom.face_organ, dtype=np.int64),
            face_normals=fn,
            plane_d=np.einsum("fj,fj->f", fn, vertices[faces[:, 0]]),
            corner_normals=corners,
            scale_m=float(np.linalg.norm(hi - lo)),
            offset_m=float(OFFSET_ULPS * ulp),
            face_map=face_map,
        )

    # ----------------------------------------------------------- queries
    def first_hit(self, origins_m: np.ndarray, directions: np.ndarray, push: np.ndarray | None = None):
        """First triangle hit by each ray and the float64 distance to it.

        ``push`` (N, 3): offset added to the float32 query origin only (the
        spawn offset off the surface just left). Returns ``(face, t_m)``:
        ``face = -1`` and ``t = inf`` on a miss; ``t`` is measured from the
        true origin along the unit direction to the hit triangle's plane
        (Embree's float32 distance where the ray is parallel to it).
        """
        q = origins_m - self.center
        if push is not None:
            q = q + push
        prim, tfar, _u, _v = self.embree.intersect(q, directions)
        hit = prim >= 0
        face = np.full(len(prim), -1, np.int64)
        face[hit] = prim[hit] if self.face_map is None else self.face_map[prim[hit]]
        t = np.full(len(prim), np.inf)
        if hit.any():
            f = face[hit]
            nrm = self.face_normals[f]
            denom = np.einsum("ij,ij->i", nrm, directions[hit])
            num = self.plane_d[f] - np.einsum("ij,ij->i", nrm, origins_m[hit])
            with np.errstate(divide="ignore", invalid="ignore"):
                t64 = num / denom
            good = np.isfinite(t64) & (np.abs(denom) > 1e-12)
            t[hit] = np.where(good, np.maximum(t64, 0.0), tfar[hit].astype(float))
        return face, t

    @cached_property
    def _primitive_faces(self) -> np.ndarray:
        """Phantom face of each Embree primitive, int64."""
        return np.ascontiguousarray(np.arange(len(self.faces)) if self.face_map is None else self.face_map, np.int64)

    @cached_property
    def kernel_tables(self) -> SceneTables:
        """The float64 face tables the exact kernels of :mod:`raytrace.engine.kernels` take
        (robust Embree scene)."""
        return build(SceneTables, handle=self.embree.handle, center=np.ascontiguousarray(self.center, np.float64),
                     face_map=self._primitive_faces, face_normals=np.ascontiguousarray(self.face_normals, np.float64),
                     plane_d=np.ascontiguousarray(self.plane_d, np.float64),
                     frame=np.ascontiguousarray(self._barycentric_frame), corner=self.corner_table64,
                     face_organ=np.ascontiguousarray(self.face_organ, np.int64), offset_m=self.offset_m)

    @cached_property
    def shot_tables(self) -> ShotScene:
        """The float32 face tables the shooting's kernel takes (the fast Embree scene,
        :attr:`embree_shooting`)."""
        return build(ShotScene, handle=self.embree_shooting.handle, face_map=self._primitive_faces,
                     face_normals=self.face_normals32, corner=self.corner_table32, curvature=self.face_curvature32,
                     face_organ=np.ascontiguousarray(self.face_organ, np.int64), offset_m=self.offset_m)

    @cached_property
    def face_normals32(self) -> np.ndarray:
        return self.face_normals.astype(np.float32)

    @cached_property
    def face_curvature32(self) -> np.ndarray:
        """Per face, an estimate of the surface's largest normal curvature [1/m]: the largest
        angle between two corner normals over the edge joining them (0 on flat organs; 1/R on
        a faceted sphere of radius R). The shooting widens ray tubes by it (curved organs
        focus and defocus: a mirror of curvature k turns a ray at height h by 2 k h)."""
        tri = self.vertices[self.faces]
        c = self.corner_normals
        out = np.zeros(len(self.faces))
        for i, j in ((0, 1), (1, 2), (2, 0)):
            cos = np.clip(np.einsum("ij,ij->i", c[:, i], c[:, j]), -1.0, 1.0)
            length = np.linalg.norm(tri[:, i] - tri[:, j], axis=1)
            out = np.maximum(out, np.arccos(cos) / np.maximum(length, 1e-12))
        return out.astype(np.float32)

    @cached_property
    def corner_table64(self) -> np.ndarray:
        """Per face (F, 9): the first corner normal and the differences to the other two."""
        c = self.corner_normals
        return np.ascontiguousarray(np.concatenate([c[:, 0], c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]], axis=1))

    @cached_property
    def corner_table32(self) -> np.ndarray:
        return self.corner_table64.astype(np.float32)

    @cached_property
    def _barycentric_frame(self) -> np.ndarray:
        """Per face, one row (F, 22) so :meth:`smooth_normals` gathers once: first vertex a (0:3),
        edge vectors v0 = b - a (3:6), v1 = c - a (6:9), their dot products d00, d01, d11
        (9:12), the Gram determinant (12) and the three corner normals (13:22), float64."""
        tri = self.vertices[self.faces]  # (F, 3, 3)
        a = tri[:, 0]
        v0, v1 = tri[:, 1] - a, tri[:, 2] - a
        d00 = np.einsum("ij,ij->i", v0, v0)
        d01 = np.einsum("ij,ij->i", v0, v1)
        d11 = np.einsum("ij,ij->i", v1, v1)
        return np.concatenate([a, v0, v1, np.stack([d00, d01, d11, d00 * d11 - d01 * d01], axis=1),
                               self.corner_normals.reshape(-1, 9)], axis=1)

    def smooth_normals(self, face: np.ndarray, points_m: np.ndarray) -> np.ndarray:
        """Unit outward normals interpolated from barycentrics (float64) of points on their faces."""
        fr = self._barycentric_frame[face]  # one gather of every per-face quantity
        a, v0, v1 = fr[:, 0:3], fr[:, 3:6], fr[:, 6:9]
        d00, d01, d11, den = fr[:, 9], fr[:, 10], fr[:, 11], fr[:, 12]
        v2 = points_m - a
        d20 = np.einsum("ij,ij->i", v2, v0)
        d21 = np.einsum("ij,ij->i", v2, v1)
        v = (d11 * d20 - d01 * d21) / den
        w = (d00 * d21 - d01 * d20) / den
        u = 1.0 - v - w
        bary = np.clip(np.stack([u, v, w], axis=1), 0.0, 1.0)
        cn = fr[:, 13:22].reshape(-1, 3, 3)
        nrm = np.einsum("nc,ncj->nj", bary, cn)
        norm = np.linalg.norm(nrm, axis=1, keepdims=True)
        fallback = self.face_normals[face]
        nrm = np.where(norm > 1e-12, nrm / np.where(norm > 1e-12, norm, 1.0), fallback)
        # Never let the smooth normal flip relative to the facet.
        flip = np.einsum("ij,ij->i", nrm, fallback) <= 0.0
        return np.where(flip[:, None], fallback, nrm)


def corner_normals(vertices: np.ndarray, faces: np.ndarray, face_normals: np.ndarray,
                   crease_deg: float | np.ndarray = CREASE_ANGLE_DEG) -> np.ndarray:
    """(F, 3, 3) unit normal of each face at each of its corners (module doc).

    Two faces sharing an edge are joined across it when the angle between their (unit, outward)
    ``face_normals`` is at most the crease angle (``crease_deg``: one value, or one per face, the
    smaller of the two faces' applies); the corners of one vertex joined that way, directly or
    through other faces round the vertex, form a smoothing group, and every corner of a group
    gets the group's normal: the sum over its faces of Max's weights ``(e1 x e2) / (|e1|^2 |e2|^2)``
    (e1, e2 the face's two edges from the vertex; N. Max, "Weights for computing vertex normals from
    facet normals", J. Graphics Tools 4(2), 1999: exact for vertices on a sphere, where the plain
    area-weighted average is off by ~0.15 deg on a 5120-face icosphere and skews the curvature a ray
    tube sees by ~4 %), normalised. Without any crease round a vertex that is the vertex
    normal; a face alone in its group (every neighbour across a crease) keeps its facet normal
    exactly. An edge shared by other than two faces (not in a phantom: meshes are closed) joins
    nothing."""
    faces = np.asarray(faces, np.int64)
    nf = len(faces)
    if nf == 0:
        return np.zeros((0, 3, 3))
    fn = np.asarray(face_normals, float)
    crease = np.broadcast_to(np.asarray(crease_deg, float), (nf,))
    v = vertices[faces]  # (F, 3, 3)
    weights = np.empty((nf, 3, 3))
    for i in range(3):
        e1 = v[:, (i + 1) % 3] - v[:, i]
        e2 = v[:, (i + 2) % 3] - v[:, i]
        weights[:, i] = np.cross(e1, e2) / (np.einsum("ij,ij->i", e1, e1) * np.einsum("ij,ij->i", e2, e2))[:, None]
    # half-edges: face f, corner i -> corner i + 1; an edge is the sorted vertex pair
    hf = np.repeat(np.arange(nf), 3)
    hc = np.tile(np.arange(3), nf)
    a, b = faces[hf, hc], faces[hf, (hc + 1) % 3]
    key = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    k = key[order]
    same = np.all(k[1:] == k[:-1], axis=1)
    starts = np.flatnonzero(np.concatenate([[True], ~same]))
    counts = np.diff(np.concatenate([starts, [len(k)]]))
    runs = np.repeat(counts, counts)  # how many half-edges carry each one's edge (two: manifold)
    pair = same & (runs[:-1] == 2)
    h1, h2 = order[:-1][pair], order[1:][pair]
    f1, f2 = hf[h1], hf[h2]
    limit = np.cos(np.radians(np.minimum(crease[f1], crease[f2])))
    smooth = np.einsum("ij,ij->i", fn[f1], fn[f2]) >= limit
    h1, h2, f1, f2 = h1[smooth], h2[smooth], f1[smooth], f2[smooth]
    # the corners of f1 and f2 at the edge's two vertices (vertex a of h1, then its b)
    c1a, c1b = hc[h1], (hc[h1] + 1) % 3
    va, vb = faces[f1, c1a], faces[f1, c1b]
    c2a = np.argmax(faces[f2] == va[:, None], axis=1)
    c2b = np.argmax(faces[f2] == vb[:, None], axis=1)
    node1 = np.concatenate([3 * f1 + c1a, 3 * f1 + c1b])
    node2 = np.concatenate([3 * f2 + c2a, 3 * f2 + c2b])
    graph = coo_matrix((np.ones(len(node1), np.int8), (node1, node2)), shape=(3 * nf, 3 * nf))
    _, label = connected_components(graph, directed=False)
    acc = np.zeros((label.max() + 1, 3))
    flat = weights.reshape(-1, 3)
    for j in range(3):
        acc[:, j] = np.bincount(label, weights=flat[:, j], minlength=len(acc))
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    out = (acc / np.where(norm > 0.0, norm, 1.0))[label].reshape(nf, 3, 3)
    alone = np.bincount(label, minlength=len(acc))[label].reshape(nf, 3) == 1
    degenerate = (norm[label, 0] <= 0.0).reshape(nf, 3)
    return np.where((alone | degenerate)[..., None], fn[:, None, :], out)


_CACHE: dict[tuple, tuple[weakref.ref, TracerScene]] = {}
_LOCK = threading.Lock()


def scene_for(phantom: Phantom, visible: np.ndarray | None = None) -> TracerScene:
    """The :class:`TracerScene` of a phantom (optionally of its ``visible`` triangles only),
    built once and cached while the phantom lives."""
    mask_key = None if visible is None or bool(np.all(visible)) else np.packbits(visible).tobytes()
    if mask_key is None:
        visible = None
    key = (id(phantom), mask_key)
    with _LOCK:
        entry = _CACHE.get(key)
        if entry is not None and entry[0]() is phantom:
            return entry[1]
    scene = TracerScene.build(phantom, visible)
    with _LOCK:
        _CACHE[key] = (weakref.ref(phantom, lambda _r, k=key: _CACHE.pop(k, None)), scene)
    return scene
