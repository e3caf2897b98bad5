"""Phantom model: named, nested, closed organ meshes with their media.

A phantom is a set of organs. Each organ is one closed, watertight, outward
oriented triangle mesh with a :class:`Material`. Organs nest (skin contains
fat contains the muscle wall contains the abdominal cavity, which contains the
organs) but their surfaces never intersect. The medium at a point is the
innermost organ containing it; outside every organ is air
(``docs/tracer.md``, "Scene model").

The containment tree is built once, at construction: organ *i*'s parent is
the smallest organ containing a vertex of *i*. A ray crossing a triangle of
organ X then knows both sides without any further point-in-mesh test:
against X's outward normal it enters X from ``parent[X]``; along it, it
leaves X into ``parent[X]``.

Medium indices: ``-1`` is air (outside everything), ``i >= 0`` is organ *i*
(inside *i* and outside all of *i*'s children).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal, Mapping, NamedTuple, Sequence

import numpy as np
import trimesh

from raytrace.body.rays import RayScene
from raytrace.body.selfintersect import cross_rows, edge_crossings
from raytrace.body.topology import ClosedEdges, closed_edges
from raytrace.errors import AmbiguousPositionError, Field, InvalidGeometryError, PhantomValidationError
from raytrace.physics.materials import AIR, Material  # noqa: F401 (AIR re-exported for phantom users)

AIR_INDEX = -1
AIR_NAME = "air"

#: Points closer than this to an organ surface have an ambiguous medium [m].
SURFACE_TOLERANCE_M = 1e-6
#: An antenna must be at least this far from every organ surface [m]. A receiver a few microns
#: under a surface is where the tracer stops resolving that surface's own reflection: it
#: coincides with the direct wave there (their phases differ by 2 k d, ~1e-3 rad at 10 um and
#: 402 MHz in skin), and dropping it costs ~1.9 dB under skin. Measured on 1 m scenes: lost at
#: 1-4 um, found from 5 um (tests/raytrace/test_near_surface.py). Ten microns move no antenna
#: that matters; the error says to move it.
ANTENNA_CLEARANCE_M = 10e-6

#: An antenna must lie inside the phantom's bounding box grown by this fraction of its
#: diagonal: farther away is surely a unit mistake (millimetres typed as metres put it hundreds
#: of diagonals away), while antennas in the air around a small test body stay valid. The one
#: rule for every antenna: a channel request's (:meth:`raytrace.spec.ChannelSpec.resolve`), a
#: sweep's positions and an upload's sites (:meth:`Phantom.check_antenna_bounds`).
ANTENNA_BOUNDS_MARGIN_FRACTION = 1.0

# Fixed, "irrational" probe directions for the medium lookup: never parallel
# to a coordinate plane, so axis-aligned meshes are not hit edge-on.
_PROBE_DIRECTIONS = np.array(
    [
        [0.5773502691896258, 0.5773502691896258, 0.5773502691896258],
        [-0.2672612419124244, 0.5345224838248488, -0.8017837257372732],
        [0.8164965809277261, -0.4082482904638631, -0.4082482904638631],
    ]
)
_PROBE_DIRECTIONS = _PROBE_DIRECTIONS + np.array([1e-3, -2e-3, 3e-3])
_PROBE_DIRECTIONS /= np.linalg.norm(_PROBE_DIRECTIONS, axis=1, keepdims=True)
#: The smallest, over unit normals n, of the largest |n . p| over the probes (check_antenna_clearance).
PROBE_COVER = 1.0 / max(float(np.linalg.norm(np.linalg.solve(_PROBE_DIRECTIONS, [a, b, c])))
                        for a in (-1.0, 1.0) for b in (-1.0, 1.0) for c in (-1.0, 1.0))




@dataclass(frozen=True)
class Organ:
    """One closed organ surface and what fills it.

    ``crease_angle_deg``: the organ's own smoothing setting, the dihedral angle between two
    neighbouring facets above which their shared edge is a crease of the surface (the tracer keeps
    the normal discontinuous there, :mod:`raytrace.engine.scene`); None: the tracer's default
    (45 deg). 0 makes every facet flat, 180 smooths everything.
    """

    name: str
    material: Material
    mesh: trimesh.Trimesh
    crease_angle_deg: float | None = None


@dataclass(frozen=True)
class Site:
    """A named position: a capsule site in the GI tract or a sensor site on the skin."""

    name: str
    kind: Literal["capsule", "sensor"]
    position_m: np.ndarray
    medium: str = ""


@dataclass
class Phantom:
    """Organs, their containment tree, one combined mesh, and named sites.

    Build with :meth:`Phantom.build`, which validates and derives everything;
    treat instances as immutable afterwards.
    """

    name: str
    organs: tuple[Organ, ...]
    parent: np.ndarray  # (n_organs,) int: containing organ, -1 for air
    sites: dict[str, Site]
    vertices: np.ndarray  # (V, 3) float64 [m]
    faces: np.ndarray  # (F, 3) int64 indices into vertices
    face_organ: np.ndarray  # (F,) int32 organ of each triangle
    face_normals: np.ndarray  # (F, 3) outward unit facet normals
    description: str = ""
    metadata: dict = field(default_factory=dict)
    #: Named paths through the organs (``raytrace.body.centreline``), e.g. the GI tract.
    centrelines: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ build
    @classmethod
    def build(
        cls,
        name: str,
        organs: Sequence[Organ],
        sites: Mapping[str, tuple[str, Sequence[float]]] | None = None,
        *,
        description: str = "",
        max_triangles: int | None = None,
        check_crossings: bool = True,
        checked: Surfaces | None = None,
    ) -> "Phantom":
        """Validate organs, build the containment tree and the combined mesh.

        ``sites`` maps a site name to ``(kind, position_m)``. Raises
        :class:`PhantomValidationError` naming the organ and the defect; nothing
        is returned half-built. ``check_crossings=False`` skips the edge test of
        :func:`_check_crossings` (for phantoms validated before, e.g. an upload a
        sweep worker reloads); the containment tree is built either way. ``checked``: what
        :func:`surface_crossings` answered for these organs' meshes (the same objects, in order) when
        the caller tested them: if no two crossed, its triangle table, checks and Embree scene are
        taken as they are instead of being made again.
        """
        organs = tuple(organs)
        if not organs:
            raise PhantomValidationError("a phantom needs at least one organ", field="organs")
        names = [o.name for o in organs]
        if len(set(names)) != len(names):
            raise PhantomValidationError("organ names must be unique", field="organs")
        total = sum(len(o.mesh.faces) for o in organs)
        if max_triangles is not None and total > max_triangles:
            raise PhantomValidationError(
                f"{total} triangles exceed the cap of {max_triangles}", field="mesh"
            )
        for organ in organs:
            if organ.crease_angle_deg is not None and not 0.0 <= float(organ.crease_angle_deg) <= 180.0:
                raise PhantomValidationError(
                    f"crease_angle_deg must be in [0, 180] deg, got {organ.crease_angle_deg}",
                    field=f"organs.{organ.name}.crease_angle_deg")
        meshes = tuple(o.mesh for o in organs)
        reuse = checked is not None and checked.scene is not None and not checked.crossings and \
            len(checked.meshes) == len(meshes) and all(a is b for a, b in zip(checked.meshes, meshes))
        surfaces = checked if reuse and checked is not None else check_surfaces(meshes, names)
        phantom = cls(
            name=name,
            organs=organs,
            parent=np.full(len(organs), AIR_INDEX, dtype=np.int64),
            sites={},
            vertices=surfaces.vertices,
            faces=surfaces.faces,
            face_organ=surfaces.face_organ,
            face_normals=surfaces.face_normals,
            description=description,
        )
        if reuse:
            phantom.__dict__["intersector"] = surfaces.scene
        elif check_crossings:
            _check_crossings(phantom, surfaces.edges)
        phantom.__dict__.update(volumes_m3=surfaces.volumes, areas_m2=surfaces.areas)  # the cached properties
        phantom.parent = _containment_tree(phantom, surfaces.volumes)
        for site_name, (kind, position) in (sites or {}).items():
            if kind not in ("capsule", "sensor"):
                raise PhantomValidationError(
                    f"site kind must be 'capsule' or 'sensor', got {kind!r}",
                    field=f"sites.{site_name}",
                )
            pos = np.asarray(position, float).reshape(3)
            try:
                index = phantom.antenna_medium(pos, field=f"sites.{site_name}")
            except InvalidGeometryError as exc:
                raise PhantomValidationError(exc.reason, field=exc.field) from exc
            phantom.sites[site_name] = Site(site_name, kind, pos, phantom.medium_name(index))
        return phantom

    # ------------------------------------------------------------- accessors
    @property
    def triangle_count(self) -> int:
        return int(len(self.faces))

    @cached_property
    def bounds_m(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds of all organs [m] (computed once: every antenna of every
        request checks against it, ~20 ms a time at 1 M triangles)."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @cached_property
    def volumes_m3(self) -> np.ndarray:
        """(n_organs,) the volume each organ's surface encloses (its own, children included)."""
        return _volumes_and_areas(self.vertices, self.faces, self.face_organ, len(self.organs))[0]

    @cached_property
    def areas_m2(self) -> np.ndarray:
        """(n_organs,) each organ's surface area."""
        return _volumes_and_areas(self.vertices, self.faces, self.face_organ, len(self.organs))[1]

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """All organs as one mesh (no merging, no processing): triangle i is ``faces[i]``."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    @cached_property
    def intersector(self) -> RayScene:
        """The Embree scene of every triangle (:class:`raytrace.body.rays.RayScene`), built once per phantom:
        its checks, medium lookups and containment tree cast through it."""
        return RayScene(self.vertices, self.faces, self.face_normals)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(V, 3) smooth normals, per organ (never blended across organs): trimesh's, computed when asked."""
        return np.concatenate([np.asarray(o.mesh.vertex_normals, float) for o in self.organs])

    def organ_index(self, name: str) -> int:
        for i, organ in enumerate(self.organs):
            if organ.name == name:
                return i
        raise PhantomValidationError(f"no organ named {name!r}", field="organ")

    def medium_name(self, index: int) -> str:
        """Organ name for an organ index, ``"air"`` for -1."""
        return AIR_NAME if index == AIR_INDEX else self.organs[index].name

    def medium_names(self, indices: np.ndarray) -> list[str]:
        return [self.medium_name(int(i)) for i in np.asarray(indices).ravel()]

    def material(self, index: int) -> Material:
        """The material filling a medium index (air for -1)."""
        return AIR if index == AIR_INDEX else self.organs[index].material

    def child_side(self, face_index: np.ndarray) -> np.ndarray:
        """Medium index on the inner side of each triangle (its organ)."""
        return self.face_organ[face_index]

    def parent_side(self, face_index: np.ndarray) -> np.ndarray:
        """Medium index on the outer side of each triangle (its organ's parent)."""
        return self.parent[self.face_organ[face_index]]

    # --------------------------------------------------------- medium lookup
    def antenna_medium(self, position_m, *, field: Field = "position_m") -> int:
        """Medium index at an antenna position, after the two rules every antenna (a channel
        request's or a site of an upload) obeys: inside the bounding box grown by
        :data:`ANTENNA_BOUNDS_MARGIN_FRACTION` of its diagonal (else
        :class:`InvalidGeometryError`, :meth:`check_antenna_bounds`), and off every organ surface
        (else :class:`AmbiguousPositionError`)."""
        position = np.asarray(position_m, dtype=float).reshape(3)
        self.check_antenna_bounds(position[None, :], [field])
        medium = int(self.medium_index(position[None, :], field=field)[0])
        self.check_antenna_clearance(position[None, :], [field])
        return medium

    def check_antenna_clearance(self, points_m, fields: "list[Field]") -> None:
        """Raise :class:`AmbiguousPositionError` naming ``fields[k]`` for the first point ``k`` within
        :data:`ANTENNA_CLEARANCE_M` of an organ surface.

        The distance is bounded by first hits along the three probe directions, both ways: a
        surface at distance d with normal n is met along probe p_i within d / |n . p_i|, and for
        every n some probe has |n . p_i| >= :data:`PROBE_COVER` (= 1 / max over sign vectors s of
        |P^-1 s|, P the probes' matrix: the largest |n . p_i| is smallest where P n lies on a
        vertex of a cube). Refusing probe distances below ANTENNA_CLEARANCE_M / PROBE_COVER
        (20.7 um) therefore refuses every point within the clearance and none farther than that."""
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        reach = ANTENNA_CLEARANCE_M / PROBE_COVER
        near = np.zeros(len(points), bool)
        for direction in _PROBE_DIRECTIONS:
            for sign in (1.0, -1.0):
                near |= self._probe(points, sign * direction)[1] < reach
        if near.any():
            k = int(np.argmax(near))
            raise AmbiguousPositionError(
                f"point {points[k].tolist()} lies within {ANTENNA_CLEARANCE_M:g} m of an organ surface: "
                "there the surface's own reflection merges with the direct wave and is not resolved; "
                "move the antenna at least that far off the surface",
                field=fields[k],
            )

    def check_antenna_bounds(self, points_m, fields: "list[Field]") -> None:
        """Raise :class:`InvalidGeometryError` naming ``fields[k]`` for the first point ``k`` that is
        not finite or lies outside the bounding box grown by :data:`ANTENNA_BOUNDS_MARGIN_FRACTION`
        of its diagonal (vectorised: one call for all antennas of a request)."""
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        lo, hi = (np.asarray(b, float) for b in self.bounds_m)
        margin = ANTENNA_BOUNDS_MARGIN_FRACTION * float(np.linalg.norm(hi - lo))
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(points).all(axis=1) | np.any((points < lo - margin) | (points > hi + margin), axis=1)
        if bad.any():
            k = int(np.argmax(bad))
            raise InvalidGeometryError(
                f"position {points[k].tolist()} m is outside the phantom's bounds {lo.tolist()}..{hi.tolist()} m "
                f"(grown by {margin:.3g} m)",
                field=fields[k],
            )

    def medium_index(self, points_m: np.ndarray, *, field: Field = "position_m") -> np.ndarray:
        """Medium index (organ, or -1 for air) of each point, vectorised.

        One first-hit ray per point and probe direction: hitting organ X's
        triangle against its outward normal means the point is outside X (in
        ``parent[X]``), along it means inside X. Two probe directions are cast;
        where they disagree (a ray grazing an edge) a third one decides.

        Raises :class:`InvalidGeometryError` for non-finite points and
        :class:`AmbiguousPositionError` for a point within
        :data:`SURFACE_TOLERANCE_M` of a surface.
        """
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        bad = ~np.isfinite(points).all(axis=1)
        if bad.any():
            raise InvalidGeometryError(
                f"coordinates must be finite numbers, got {points[np.argmax(bad)].tolist()}",
                field=field,
            )
        votes = []
        for k, direction in enumerate(_PROBE_DIRECTIONS):
            if k == 2:
                undecided = votes[0] != votes[1]
                if not undecided.any():
                    break
            medium, distance = self._probe(points, direction)
            near = distance < SURFACE_TOLERANCE_M
            # Also probe backwards: a point just past a surface is as ambiguous.
            _, back = self._probe(points, -direction)
            near |= back < SURFACE_TOLERANCE_M
            if near.any():
                p = points[np.argmax(near)]
                raise AmbiguousPositionError(
                    f"point {p.tolist()} lies on an organ surface (within "
                    f"{SURFACE_TOLERANCE_M} m): its medium is ambiguous; move it off the surface",
                    field=field,
                )
            votes.append(medium)
        if len(votes) == 3:
            return np.where(votes[0] == votes[1], votes[0], votes[2])
        return votes[0]

    def _probe(self, points: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(points)
        tri, distance = self.intersector.first_hits(points, np.broadcast_to(direction, (n, 3)))
        medium = np.full(n, AIR_INDEX, dtype=np.int64)
        hit = tri >= 0
        if hit.any():
            t = tri[hit]
            leaving = np.einsum("ij,j->i", self.face_normals[t], direction) > 0.0
            medium[hit] = np.where(leaving, self.face_organ[t], self.parent[self.face_organ[t]])
        return medium, distance


# ------------------------------------------------------------------ helpers
class Surfaces(NamedTuple):
    """Closed surfaces as one triangle table (:func:`check_surfaces`)."""

    meshes: tuple  # the trimesh meshes, in order (their identity says what was checked)
    vertices: np.ndarray
    faces: np.ndarray
    face_organ: np.ndarray  # (F,) int32: the surface of each triangle
    face_normals: np.ndarray  # (F, 3) unit, as trimesh's ``face_normals``
    volumes: np.ndarray  # (n,) m^3
    areas: np.ndarray  # (n,) m^2
    edges: ClosedEdges
    scene: RayScene | None = None  # built by :func:`surface_crossings`
    crossings: frozenset = frozenset()  # pairs (i, j), i <= j, of surfaces that cross ((i, i): i crosses itself)


def check_surfaces(meshes: Sequence[trimesh.Trimesh], names: Sequence[str],
                   known: Sequence[ClosedEdges | None] | None = None) -> Surfaces:
    """Refuse a surface that is not closed, consistently and outward wound, of non-degenerate triangles,
    naming it (``organs.<name>``); the surfaces as one triangle table, their unit facet normals (trimesh's
    ``face_normals``, computed the same way over all triangles at once, and also for triangles under its
    TOL_ZERO), volumes and edges
    (:func:`raytrace.body.topology.closed_edges`, for the crossing test). ``known``: each surface's closed
    edges when the caller has them (the anatomy build's repairs), else None: those are taken, offset into
    the table, instead of sorting every half-edge again; the surfaces' own vertices then never share one."""
    meshes = tuple(meshes)
    for mesh, name in zip(meshes, names):
        where = f"organs.{name}"
        if len(mesh.faces) < 4:
            raise PhantomValidationError("mesh has fewer than 4 triangles", field=where)
        if not np.isfinite(np.asarray(mesh.vertices)).all():
            raise PhantomValidationError("mesh has non-finite vertex coordinates", field=where)
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    counts = [len(m.faces) for m in meshes]
    vertices = np.concatenate([np.asarray(m.vertices, float) for m in meshes])
    faces = np.concatenate([np.asarray(m.faces, np.int64) + offsets[i] for i, m in enumerate(meshes)])
    face_organ = np.repeat(np.arange(len(meshes), dtype=np.int32), counts)
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    cross = cross_rows(v1 - v0, v2 - v1)  # trimesh.triangles.cross
    norm = np.sqrt(np.dot(cross * cross, [1.0, 1.0, 1.0]))  # trimesh.util.unitize, bit for bit
    # only a triangle of exactly zero area has no normal (as the phantom's check has always been): trimesh
    # gives no normal below TOL_ZERO (1e-12 m^2 of |cross|), but marching cubes leaves corner triangles of
    # ~0.5 um^2 where a surface passes a hair off a grid node, whose float64 normals are well defined
    bad = np.flatnonzero(~(norm > 0.0))
    if len(bad):
        raise PhantomValidationError("mesh has degenerate (zero-area) triangles",
                                     field=f"organs.{names[face_organ[bad[0]]]}")
    face_normals = cross * (1.0 / norm).reshape((-1, 1))
    edges = closed_edges(faces) if known is None else _joined_edges(meshes, known, offsets)
    if edges is None:  # find the surface and say what is wrong with it
        for mesh, name in zip(meshes, names):
            if closed_edges(np.asarray(mesh.faces, np.int64)) is None:
                where = f"organs.{name}"
                if not mesh.is_watertight:
                    raise PhantomValidationError("mesh is not watertight (closed)", field=where)
                raise PhantomValidationError("mesh triangles are not consistently oriented", field=where)
        raise PhantomValidationError("the organs' surfaces share vertices", field="organs")
    # the divergence theorem: sum of v0 . ((v1 - v0) x (v2 - v1)) / 6 = v0 . (v1 x v2) / 6 per organ
    volumes = np.bincount(face_organ, np.einsum("ij,ij->i", v0, cross), len(meshes)) / 6.0
    inward = np.flatnonzero(volumes <= 0.0)
    if len(inward):
        raise PhantomValidationError("mesh is oriented inwards (negative volume); normals must point outwards",
                                     field=f"organs.{names[inward[0]]}")
    areas = np.bincount(face_organ, norm, len(meshes)) / 2.0
    return Surfaces(meshes, vertices, faces, face_organ, face_normals, volumes, areas, edges)


def _joined_edges(meshes: Sequence[trimesh.Trimesh], known: Sequence[ClosedEdges | None],
                  offsets: np.ndarray) -> ClosedEdges | None:
    """The surfaces' closed edges as one table (``known`` where given, else sorted here), vertex and triangle
    indices offset as in :func:`check_surfaces`'s table; None if a surface is not closed."""
    parts, face_base = [], 0
    for mesh, edges in zip(meshes, known):
        if edges is None:
            edges = closed_edges(np.asarray(mesh.faces, np.int64))
            if edges is None:
                return None
        parts.append((edges.edges + offsets[len(parts)], edges.face + face_base, edges.twin + face_base))
        face_base += len(mesh.faces)
    return ClosedEdges(*(np.concatenate([part[k] for part in parts]) for k in range(3)))


def _volumes_and_areas(vertices: np.ndarray, faces: np.ndarray, face_organ: np.ndarray,
                       n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per surface: the enclosed volume (divergence theorem, sum of v0 . (v1 - v0) x (v2 - v1) / 6) and the
    area (half the cross products' lengths)."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    cross = cross_rows(v1 - v0, v2 - v1)
    return (np.bincount(face_organ, np.einsum("ij,ij->i", v0, cross), n) / 6.0,
            np.bincount(face_organ, np.sqrt(np.einsum("ij,ij->i", cross, cross)), n) / 2.0)


def surface_crossings(surfaces: Surfaces) -> Surfaces:
    """``surfaces`` with their Embree scene and the pairs of them that cross (every edge of every surface
    cast once as a segment, :func:`raytrace.body.selfintersect.edge_crossings`): what
    :meth:`Phantom.build` tests, for a caller that resolves crossings before building (the anatomy
    pipeline) and hands the result on, so that neither the scene nor the test is made twice."""
    scene = RayScene(surfaces.vertices, surfaces.faces, surfaces.face_normals)
    edge, tri, _ = edge_crossings(surfaces.vertices, surfaces.faces, surfaces.edges, surfaces.face_normals, scene)
    a = surfaces.face_organ[surfaces.edges.face[edge]].tolist()
    b = surfaces.face_organ[tri].tolist()
    return surfaces._replace(scene=scene, crossings=frozenset((min(i, j), max(i, j)) for i, j in zip(a, b)))


def _check_crossings(phantom: "Phantom", edges: ClosedEdges) -> None:
    """Refuse any two triangles that cross, of one organ (it passes through itself) or of two (they cross):
    every edge of every organ cast once as a segment through the one Embree scene of all triangles
    (:attr:`Phantom.intersector`, the scene every medium lookup uses),
    :func:`raytrace.body.selfintersect.edge_crossings`. The cost is the scene's BVH build plus about 1.5
    short segments per triangle (docs/phantoms.md, "Scale")."""
    edge, tri, loc = edge_crossings(phantom.vertices, phantom.faces, edges, phantom.face_normals,
                                    phantom.intersector)
    if not len(edge):
        return
    k = 0
    count = len(edge)
    edge_organ, hit_organ = int(phantom.face_organ[edges.face[edge[k]]]), int(phantom.face_organ[tri[k]])
    where = np.round(loc[k], 4).tolist()
    if edge_organ == hit_organ:
        name = phantom.organs[edge_organ].name
        local = int(tri[k]) - int(sum(len(o.mesh.faces) for o in phantom.organs[:edge_organ]))
        raise PhantomValidationError(
            f"mesh intersects itself: {count} of its edges cross its own triangles (e.g. triangle {local}, near "
            f"{where} m); an organ must be one closed surface that does not pass through itself",
            field=f"organs.{name}")
    inner, outer = phantom.organs[edge_organ].name, phantom.organs[hit_organ].name
    raise PhantomValidationError(
        f"surface of organ {inner!r} intersects organ {outer!r} ({count} edges cross, e.g. near {where} m); organs "
        "must nest or be disjoint, never touch", field=f"organs.{inner}")


def _containment_tree(phantom: "Phantom", volumes: np.ndarray) -> np.ndarray:
    """Parent organ of every organ (-1 for air). Surfaces that do not cross (:func:`_check_crossings`)
    leave each organ wholly inside or wholly outside each other one, so one point of its surface decides:
    the centroid of its first triangle, whose ray (a fixed oblique direction) through the one scene of all
    triangles crosses each organ containing it an odd number of times (every hit counted, the ray re-cast
    just past each). The parent is the smallest-volume container."""
    n = len(phantom.organs)
    first_face = np.cumsum([0] + [len(o.mesh.faces) for o in phantom.organs])[:-1]
    points = phantom.vertices[phantom.faces[first_face]].mean(axis=1)
    direction = _PROBE_DIRECTIONS[0]
    counts = np.zeros((n, n), dtype=np.int64)  # counts[i, j]: crossings of organ j by organ i's ray
    origins = points.copy()
    alive = np.arange(n)
    scale = float(np.linalg.norm(phantom.bounds_m[1] - phantom.bounds_m[0])) or 1.0
    for _ in range(4 * len(phantom.faces) + 8):
        if not len(alive):
            break
        tri, distance = phantom.intersector.first_hits(origins[alive], np.broadcast_to(direction, (len(alive), 3)))
        hit = tri >= 0
        hit_rays = alive[hit]
        organs_hit = phantom.face_organ[tri[hit]]
        np.add.at(counts, (hit_rays, organs_hit), 1)
        # past the hit by more than float32 resolves
        origins[hit_rays] += (distance[hit] + 1e-6 * scale)[:, None] * direction
        alive = hit_rays
    inside = counts % 2 == 1
    np.fill_diagonal(inside, False)
    parent = np.full(n, AIR_INDEX, dtype=np.int64)
    for i in range(n):
        containers = np.flatnonzero(inside[i])
        if len(containers):
            if np.any(inside[i] & inside[:, i]):
                raise PhantomValidationError(
                    f"organ {phantom.organs[i].name!r} and another organ contain each other",
                    field=f"organs.{phantom.organs[i].name}",
                )
            parent[i] = containers[np.argmin(volumes[containers])]
    return parent
