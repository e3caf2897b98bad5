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

One phantom, one set of tables (:class:`FaceTables`): the face tables the kernels read
(float64 for the exact kernels, float32 for the shooting) are computed once per phantom by one
compiled pass (:func:`_face_tables`, no per-face temporaries), and both Embree scenes hold
every organ as its own geometry with its own mask bit over one shared float32 copy of the
vertices and faces (:mod:`raytrace.engine.embree`). The scene of a trace that leaves out the
surfaces between identical materials (:func:`scene_for` with ``visible``) is then the same
two Embree scenes queried with a ray mask of the visible organs, not two more scenes and a
copy of every table: on the 0.98 M-triangle torso this took the first trace's scene build
from 7.4 CPU-s and 1.3 GB to what ``python -m bench.scene_build`` reports
(docs/performance-log.md, session 11). Only a subset of faces that no mask expresses (more
than 32 organs sharing bits across the subset, or a subset that splits an organ) gets Embree
scenes of its own, still over the shared tables.

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

import math
import threading
import weakref
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from raytrace.body.phantom import AIR_INDEX, Phantom
from raytrace.engine.embree import ALL, EmbreeScene, Geometry, buffers
from raytrace.engine.jit import kernel
from raytrace.engine.records import SceneTables, ShotScene, build

#: Default crease angle [deg]: an edge whose two faces' normals differ by more than this is a crease
#: (module doc). Above the built-in torso's largest dihedral angle between neighbouring facets
#: (33.6 deg on the skin's rim at resolution 48), below a box's 90 deg.
CREASE_ANGLE_DEG = 45.0
#: Spawn offset in float32 ulps of the largest (centred) coordinate.
OFFSET_ULPS = 16.0


@kernel
def _face_tables(vertices, faces, fn, corners, plane_d, frame, normals32, corner32, curvature32):
    """The per-face tables of :class:`FaceTables` in one pass over the faces (the arithmetic of
    the numpy expressions they replace, in the same order: tests/raytrace/test_scene_build.py
    checks them bit for bit): ``plane_d = n . a``; the barycentric frame row (first vertex
    ``a``, edges ``v0 = b - a``, ``v1 = c - a``, ``d00, d01, d11``, the Gram determinant, the
    three corner normals); the float32 facet normal; the float32 corner table (first corner
    normal and the differences to the other two, differenced in float64); and the largest
    normal curvature over the face's edges, the angle between two corner normals over the
    edge's length (:attr:`FaceTables.curvature32`)."""
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, az = vertices[i0, 0], vertices[i0, 1], vertices[i0, 2]
        bx, by, bz = vertices[i1, 0], vertices[i1, 1], vertices[i1, 2]
        cx, cy, cz = vertices[i2, 0], vertices[i2, 1], vertices[i2, 2]
        ux, uy, uz = bx - ax, by - ay, bz - az
        wx, wy, wz = cx - ax, cy - ay, cz - az
        # the three-term dot products summed as numpy's einsum sums them: (x0 y0 + x2 y2) + x1 y1
        d00 = (ux * ux + uz * uz) + uy * uy
        d01 = (ux * wx + uz * wz) + uy * wy
        d11 = (wx * wx + wz * wz) + wy * wy
        nx, ny, nz = fn[f, 0], fn[f, 1], fn[f, 2]
        plane_d[f] = (nx * ax + nz * az) + ny * ay
        row = frame[f]
        row[0], row[1], row[2] = ax, ay, az
        row[3], row[4], row[5] = ux, uy, uz
        row[6], row[7], row[8] = wx, wy, wz
        row[9], row[10], row[11], row[12] = d00, d01, d11, d00 * d11 - d01 * d01
        for c in range(3):
            for q in range(3):
                row[13 + 3 * c + q] = corners[f, c, q]
        normals32[f, 0], normals32[f, 1], normals32[f, 2] = np.float32(nx), np.float32(ny), np.float32(nz)
        for q in range(3):
            corner32[f, q] = np.float32(corners[f, 0, q])
            corner32[f, 3 + q] = np.float32(corners[f, 1, q] - corners[f, 0, q])
            corner32[f, 6 + q] = np.float32(corners[f, 2, q] - corners[f, 0, q])
        best = 0.0
        for e in range(3):
            i, j = e, (e + 1) % 3
            cos = corners[f, i, 0] * corners[f, j, 0] + corners[f, i, 1] * corners[f, j, 1] \
                + corners[f, i, 2] * corners[f, j, 2]
            cos = min(max(cos, -1.0), 1.0)
            pi_, pj = faces[f, i], faces[f, j]
            ex = vertices[pi_, 0] - vertices[pj, 0]
            ey = vertices[pi_, 1] - vertices[pj, 1]
            ez = vertices[pi_, 2] - vertices[pj, 2]
            length = math.sqrt(ex * ex + ey * ey + ez * ez)
            best = max(best, math.acos(cos) / max(length, 1e-12))
        curvature32[f] = np.float32(best)


#: Organs with their own mask bit: beyond that, organs share bits by how they are seen
#: (:func:`_organ_masks`).
MASK_BITS = 32


def _organ_masks(phantom: Phantom) -> np.ndarray:
    """The Embree mask bit of each organ: its own bit for up to :data:`MASK_BITS` organs; else one
    of four bits by (the same material as its parent, its parent is air), which keeps the two
    subsets a trace asks for (the surfaces between identical materials left out, with the
    phantom's own materials or the homogeneous override) expressible by a mask."""
    n = len(phantom.organs)
    if n <= MASK_BITS:
        return (np.uint32(1) << np.arange(n, dtype=np.uint32)).astype(np.uint32)
    parent = np.asarray(phantom.parent, np.int64)
    same = np.array([phantom.organs[i].material == phantom.material(int(parent[i])) for i in range(n)])
    return (np.uint32(1) << (2 * same + (parent == AIR_INDEX)).astype(np.uint32)).astype(np.uint32)


@dataclass(eq=False)
class FaceTables:
    """One phantom's face tables and Embree scenes, shared by every :class:`TracerScene` of it
    (module doc). Face ``f`` is the phantom's face ``f`` everywhere."""

    center: np.ndarray  # (3,) float64 translation applied before float32 conversion
    vertices: np.ndarray  # (V, 3) float64 (the phantom's)
    faces: np.ndarray  # (F, 3) int64 (the phantom's)
    face_organ: np.ndarray  # (F,) int64
    face_normals: np.ndarray  # (F, 3) float64 unit, outward
    plane_d: np.ndarray  # (F,) n . v0
    frame: np.ndarray  # (F, 22) float64 barycentric frame and corner normals (_face_tables)
    normals32: np.ndarray  # (F, 3) float32 facet normals
    corner32: np.ndarray  # (F, 9) float32 first corner normal, differences to the other two
    curvature32: np.ndarray  # (F,) float32 largest normal curvature [1/m]
    bounds32: np.ndarray  # (2, 3) float64 box of the float32 centred vertices Embree holds
    organ_start: np.ndarray  # (organs + 1,) first face of each organ (organs are runs of faces)
    organ_mask: np.ndarray  # (organs,) uint32 Embree mask bit of each organ (_organ_masks)
    scale_m: float  # bounding-box diagonal
    offset_m: float  # spawn offset
    buffers: tuple  # Embree's shared float32 vertex / uint32 index buffers (embree.buffers)
    _robust: EmbreeScene | None = field(default=None, repr=False)
    _fast: EmbreeScene | None = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, phantom: Phantom) -> "FaceTables":
        """The tables of every face of ``phantom`` (its Embree scenes are built on first use)."""
        vertices = np.asarray(phantom.vertices, dtype=float)
        faces = np.asarray(phantom.faces, dtype=np.int64)
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        center = 0.5 * (lo + hi)
        fn = np.asarray(phantom.face_normals, dtype=float)
        fn = fn / np.linalg.norm(fn, axis=1, keepdims=True)
        crease_deg = np.array([CREASE_ANGLE_DEG if o.crease_angle_deg is None else float(o.crease_angle_deg)
                               for o in phantom.organs])
        corners = corner_normals(vertices, faces, fn, crease_deg[np.asarray(phantom.face_organ, np.int64)])
        n_faces = len(faces)
        plane_d = np.empty(n_faces)
        frame = np.empty((n_faces, 22))
        normals32 = np.empty((n_faces, 3), np.float32)
        corner32 = np.empty((n_faces, 9), np.float32)
        curvature32 = np.empty(n_faces, np.float32)
        _face_tables(vertices, faces, np.ascontiguousarray(fn), np.ascontiguousarray(corners, np.float64), plane_d,
                     frame, normals32, corner32, curvature32)
        del corners
        vbuf, fbuf = buffers(vertices - center, faces)
        magnitude = float(np.abs(vbuf).max()) if len(vbuf) else 0.0
        ulp = np.spacing(np.float32(max(magnitude, 1e-6)))
        v32 = vbuf[:-1].reshape(-1, 3)
        face_organ = np.asarray(phantom.face_organ, dtype=np.int64)
        if len(face_organ) and (np.any(face_organ[1:] < face_organ[:-1]) or face_organ[0] < 0):
            raise ValueError("a phantom's faces must be grouped organ by organ (Phantom.build concatenates them)")
        counts = np.bincount(face_organ, minlength=len(phantom.organs))
        organ_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return cls(
            center=center, vertices=vertices, faces=faces, face_organ=face_organ, face_normals=fn, plane_d=plane_d,
            frame=frame, normals32=normals32, corner32=corner32, curvature32=curvature32,
            bounds32=np.array([v32.min(axis=0), v32.max(axis=0)], np.float64) if len(v32) else np.zeros((2, 3)),
            organ_start=organ_start, organ_mask=_organ_masks(phantom), scale_m=float(np.linalg.norm(hi - lo)),
            offset_m=float(OFFSET_ULPS * ulp), buffers=(vbuf, fbuf),
        )

    def _geometry(self, organs: np.ndarray | None = None) -> Geometry:
        """Every organ (or the ``organs`` given) as one geometry with its mask bit."""
        idx = np.arange(len(self.organ_mask)) if organs is None else np.asarray(organs, np.int64)
        return Geometry(self.organ_start[idx], self.organ_start[idx + 1], self.organ_mask[idx])

    def robust(self) -> EmbreeScene:
        """The watertight Embree scene of every face, built once, whichever thread asks first."""
        with self._lock:
            if self._robust is None:
                self._robust = EmbreeScene(*self.buffers, geometry=self._geometry())
            return self._robust

    def fast(self) -> EmbreeScene:
        """The same faces with Embree's fast (non-robust) traversal, for seed searches only."""
        with self._lock:
            if self._fast is None:
                self._fast = EmbreeScene(*self.buffers, robust=False, geometry=self._geometry())
            return self._fast

    def cached(self, key, make):
        """A value derived from these tables, made once per ``key`` (small tables a trace
        derives from the faces and its media, e.g. :func:`raytrace.solver.sbr.return_lengths`)."""
        with self._lock:
            if key in self._cache:
                return self._cache[key]
        value = make()
        with self._lock:
            if len(self._cache) >= 16:
                self._cache.pop(next(iter(self._cache)))
            return self._cache.setdefault(key, value)

    @cached_property
    def identity(self) -> np.ndarray:
        """``arange(F)``: the face map of a scene that reports phantom faces (vision's kernels)."""
        return np.arange(len(self.faces), dtype=np.int64)


class EmbreeView:
    """An Embree scene queried with one ray mask: the faces a :class:`TracerScene` holds."""

    def __init__(self, scene: EmbreeScene, mask: int):
        self.scene, self.mask = scene, int(mask)
        self.handle, self.base = scene.handle, scene.base

    def intersect(self, origins: np.ndarray, directions: np.ndarray):
        """:meth:`raytrace.engine.embree.EmbreeScene.intersect` with this view's mask: hits are
        phantom faces."""
        return self.scene.intersect(origins, directions, self.mask)


@dataclass(eq=False)
class TracerScene:
    """Everything the tracer needs about a phantom's triangles, float64 plus Embree scenes: the
    phantom's :class:`FaceTables` and which faces this scene holds (all, or the ``visible``
    ones: by a ray mask, or by scenes of their own when no mask expresses them)."""

    tables: FaceTables
    visible: np.ndarray | None = None  # (F,) bool, None: every face
    mask: int = ALL  # the ray mask of this scene's faces in the phantom's scenes
    _own: tuple | None = field(default=None, repr=False)  # (robust, fast) of a subset no mask expresses
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @classmethod
    def build(cls, phantom: Phantom, visible: np.ndarray | None = None,
              tables: FaceTables | None = None) -> "TracerScene":
        """Scene of all triangles, or only of ``visible`` ones (surfaces between identical
        materials are invisible to propagation; face indices stay the phantom's), over the
        phantom's ``tables`` (built here if not given)."""
        tables = FaceTables.build(phantom) if tables is None else tables
        if visible is None:
            return cls(tables)
        visible = np.asarray(visible, bool)
        seen = np.add.reduceat(visible.astype(np.int64), tables.organ_start[:-1]) if len(visible) else np.zeros(0)
        counts = np.diff(tables.organ_start)
        whole = (seen == 0) | (seen == counts)
        shown = np.flatnonzero(seen > 0)
        mask = int(np.bitwise_or.reduce(tables.organ_mask[shown])) if len(shown) else 0
        hidden = np.flatnonzero(seen == 0)
        if whole.all() and not (len(hidden) and np.any(tables.organ_mask[hidden] & np.uint32(mask))) and mask:
            return cls(tables, visible, mask)
        return cls(tables, visible, ALL, _own=_subset_scenes(tables, visible))

    # ----------------------------------------------------------- the tables, as before
    @property
    def center(self) -> np.ndarray:
        return self.tables.center

    @property
    def vertices(self) -> np.ndarray:
        return self.tables.vertices

    @property
    def faces(self) -> np.ndarray:
        return self.tables.faces

    @property
    def face_organ(self) -> np.ndarray:
        return self.tables.face_organ

    @property
    def face_normals(self) -> np.ndarray:
        return self.tables.face_normals

    @property
    def plane_d(self) -> np.ndarray:
        return self.tables.plane_d

    @property
    def corner_normals(self) -> np.ndarray:
        """(F, 3, 3) per-corner smooth normals (creased): a view of the frame's last columns."""
        return self.tables.frame[:, 13:22].reshape(-1, 3, 3)

    @property
    def scale_m(self) -> float:
        return self.tables.scale_m

    @property
    def offset_m(self) -> float:
        return self.tables.offset_m

    @property
    def face_normals32(self) -> np.ndarray:
        return self.tables.normals32

    @property
    def face_curvature32(self) -> np.ndarray:
        """Per face, an estimate of the surface's largest normal curvature [1/m]: the largest
        angle between two corner normals over the edge joining them (0 on flat organs; 1/R on
        a faceted sphere of radius R). The shooting widens ray tubes by it (curved organs
        focus and defocus: a mirror of curvature k turns a ray at height h by 2 k h)."""
        return self.tables.curvature32

    @property
    def corner_table32(self) -> np.ndarray:
        return self.tables.corner32

    @property
    def _barycentric_frame(self) -> np.ndarray:
        """Per face, one row (F, 22) so :meth:`smooth_normals` gathers once: first vertex a (0:3),
        edge vectors v0 = b - a (3:6), v1 = c - a (6:9), their dot products d00, d01, d11
        (9:12), the Gram determinant (12) and the three corner normals (13:22), float64."""
        return self.tables.frame

    # ----------------------------------------------------------- Embree
    @property
    def embree(self) -> EmbreeView:
        """The watertight traversal of this scene's faces: every exact query (refinement, walks,
        signatures)."""
        if self._own is not None:
            return EmbreeView(self._own[0], ALL)
        return EmbreeView(self.tables.robust(), self.mask)

    @property
    def embree_shooting(self) -> EmbreeView:
        """The same faces with Embree's fast (non-robust) traversal, for seed searches only
        (module doc); built on first use (the full scene of the final re-trace never needs it)."""
        if self._own is not None and self.visible is not None:  # a subset with scenes of its own
            with self._lock:
                if self._own[1] is None:
                    self._own = (self._own[0], EmbreeScene(*self.tables.buffers, robust=False,
                                                           geometry=_visible_runs(self.tables, self.visible)))
                return EmbreeView(self._own[1], ALL)
        return EmbreeView(self.tables.fast(), self.mask)

    def has_transparent(self, transparent: np.ndarray) -> bool:
        """Whether this scene holds a face of the ``transparent`` mask (F,)."""
        t = np.asarray(transparent, bool)
        return bool(t.any() if self.visible is None else (t & self.visible).any())

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
        face = np.asarray(prim, np.int64)
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
    def kernel_tables(self) -> SceneTables:
        """The float64 face tables the exact kernels of :mod:`raytrace.engine.kernels` take
        (robust Embree scene)."""
        view = self.embree
        t = self.tables
        return build(SceneTables, handle=view.handle, mask=view.mask, base=view.base,
                     center=np.ascontiguousarray(t.center, np.float64), face_map=t.identity,
                     face_normals=t.face_normals, plane_d=t.plane_d, frame=t.frame, face_organ=t.face_organ,
                     offset_m=t.offset_m)

    @cached_property
    def shot_tables(self) -> ShotScene:
        """The float32 face tables the shooting's kernel takes (the fast Embree scene,
        :attr:`embree_shooting`)."""
        view = self.embree_shooting
        t = self.tables
        return build(ShotScene, handle=view.handle, mask=view.mask, base=view.base, face_normals=t.normals32,
                     corner=t.corner32, curvature=t.curvature32, face_organ=t.face_organ, offset_m=t.offset_m)

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


def _visible_runs(tables: FaceTables, visible: np.ndarray) -> Geometry:
    """The ``visible`` faces as runs of consecutive faces within one organ (a geometry each)."""
    v = np.asarray(visible, bool)
    boundary = np.zeros(len(v) + 1, bool)
    boundary[tables.organ_start] = True
    starts = np.flatnonzero(v & (~np.r_[False, v[:-1]] | boundary[:-1]))
    stops = np.flatnonzero(v & (~np.r_[v[1:], False] | boundary[1:])) + 1
    return Geometry(starts.astype(np.int64), stops.astype(np.int64), np.full(len(starts), ALL, np.uint32))


def _subset_scenes(tables: FaceTables, visible: np.ndarray) -> tuple:
    """The robust scene of a subset of faces no mask expresses (the fast one is built on first use)."""
    return EmbreeScene(*tables.buffers, geometry=_visible_runs(tables, visible)), None


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
    nothing.

    Computed by one compiled pass (:func:`_corner_normals`, half-edges bucketed by vertex and
    union-find, no (F, 3, 3) temporaries): the numpy expressions it replaced, bit for bit
    (tests/raytrace/test_scene_build.py), at ~1/10 of their time and memory on 1 M triangles
    (docs/performance-log.md, session 12)."""
    faces = np.ascontiguousarray(faces, np.int64)
    nf = len(faces)
    if nf == 0:
        return np.zeros((0, 3, 3))
    fn = np.ascontiguousarray(face_normals, np.float64)
    crease = np.ascontiguousarray(np.broadcast_to(np.asarray(crease_deg, float), (nf,)))
    # cos of each face's crease angle as numpy computes it (the kernel picks the smaller angle's)
    limit = np.cos(np.radians(crease))
    vertices = np.ascontiguousarray(vertices, np.float64)
    out = np.empty((nf, 3, 3))
    _corner_normals(vertices, faces, fn, crease, limit, out)
    return out


@kernel
def _corner_normals(vertices, faces, fn, crease, limit, out):
    """:func:`corner_normals` into ``out`` (F, 3, 3), with the arithmetic of the numpy expressions
    it replaced in their order: numpy's cross product (``a1 b2 - a2 b1``, ...), einsum's three-term
    sums ``(x0 y0 + x2 y2) + x1 y1``, the group sums in corner order (as ``np.bincount``), the norm
    ``sqrt((x^2 + y^2) + z^2)`` (``np.linalg.norm``). The edges: half-edges (face ``f``, corner
    ``c`` -> ``c + 1``) bucketed by their smaller vertex in half-edge order, so that of the two
    half-edges of an edge the lower index is the first, as numpy's stable sort of the edge keys
    had it; an edge of exactly two half-edges across no crease joins the two faces' corners at
    each of its ends (union-find)."""
    nf = faces.shape[0]
    nv = vertices.shape[0]
    nh = 3 * nf
    start = np.zeros(nv + 1, np.int64)
    for h in range(nh):
        f, c = h // 3, h % 3
        start[min(faces[f, c], faces[f, (c + 1) % 3]) + 1] += 1
    for v in range(nv):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    bucket = np.empty(nh, np.int64)
    for h in range(nh):
        f, c = h // 3, h % 3
        lo = min(faces[f, c], faces[f, (c + 1) % 3])
        bucket[fill[lo]] = h
        fill[lo] += 1
    parent = np.arange(nh)
    for lo in range(nv):
        for p in range(start[lo], start[lo + 1]):
            h1 = bucket[p]
            f1, c1 = h1 // 3, h1 % 3
            hi1 = max(faces[f1, c1], faces[f1, (c1 + 1) % 3])
            partner, same = -1, 1
            for q in range(start[lo], start[lo + 1]):
                h2 = bucket[q]
                if h2 != h1 and max(faces[h2 // 3, h2 % 3], faces[h2 // 3, (h2 % 3 + 1) % 3]) == hi1:
                    same += 1
                    partner = h2
            if same != 2 or partner < h1:  # each manifold edge once, from its lower half-edge
                continue
            f2 = partner // 3
            cos = (fn[f1, 0] * fn[f2, 0] + fn[f1, 2] * fn[f2, 2]) + fn[f1, 1] * fn[f2, 1]
            if not cos >= (limit[f1] if crease[f1] <= crease[f2] else limit[f2]):
                continue
            for end in range(2):
                corner = (c1 + end) % 3
                v = faces[f1, corner]
                other = 0
                while other < 2 and faces[f2, other] != v:  # the first corner of f2 at v (argmax)
                    other += 1
                a, b = 3 * f1 + corner, 3 * f2 + other
                while parent[a] != a:
                    parent[a] = parent[parent[a]]
                    a = parent[a]
                while parent[b] != b:
                    parent[b] = parent[parent[b]]
                    b = parent[b]
                if a != b:
                    parent[max(a, b)] = min(a, b)
    acc = np.zeros((nh, 3))
    size = np.zeros(nh, np.int64)
    root = np.empty(nh, np.int64)
    for h in range(nh):
        r = h
        while parent[r] != r:
            r = parent[r]
        root[h] = r
        f, i = h // 3, h % 3
        j, k = faces[f, i], faces[f, (i + 1) % 3]
        m = faces[f, (i + 2) % 3]
        a0, a1, a2 = vertices[k, 0] - vertices[j, 0], vertices[k, 1] - vertices[j, 1], vertices[k, 2] - vertices[j, 2]
        b0, b1, b2 = vertices[m, 0] - vertices[j, 0], vertices[m, 1] - vertices[j, 1], vertices[m, 2] - vertices[j, 2]
        scale = ((a0 * a0 + a2 * a2) + a1 * a1) * ((b0 * b0 + b2 * b2) + b1 * b1)
        acc[r, 0] += (a1 * b2 - a2 * b1) / scale
        acc[r, 1] += (a2 * b0 - a0 * b2) / scale
        acc[r, 2] += (a0 * b1 - a1 * b0) / scale
        size[r] += 1
    for h in range(nh):
        f, i, r = h // 3, h % 3, root[h]
        norm = math.sqrt((acc[r, 0] * acc[r, 0] + acc[r, 1] * acc[r, 1]) + acc[r, 2] * acc[r, 2])
        if size[r] == 1 or not norm > 0.0:
            for q in range(3):
                out[f, i, q] = fn[f, q]
        else:
            for q in range(3):
                out[f, i, q] = acc[r, q] / norm


_CACHE: dict[tuple, tuple[weakref.ref, TracerScene]] = {}
_LOCK = threading.Lock()


def scene_for(phantom: Phantom, visible: np.ndarray | None = None) -> TracerScene:
    """The :class:`TracerScene` of a phantom (optionally of its ``visible`` triangles only),
    built once and cached while the phantom lives; every scene of one phantom shares its
    :class:`FaceTables`."""
    mask_key = None if visible is None or bool(np.all(visible)) else np.packbits(visible).tobytes()
    if mask_key is None:
        visible = None
    key = (id(phantom), mask_key)
    with _LOCK:
        entry = _CACHE.get(key)
        if entry is not None and entry[0]() is phantom:
            return entry[1]
    tables = None if mask_key is None else scene_for(phantom).tables
    scene = TracerScene.build(phantom, visible, tables)
    with _LOCK:
        _CACHE[key] = (weakref.ref(phantom, lambda _r, k=key: _CACHE.pop(k, None)), scene)
    return scene
