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
from typing import Literal, Mapping, Sequence

import numpy as np
import trimesh

from raytrace.body.selfintersect import edge_crossings
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
    vertex_normals: np.ndarray  # (V, 3) smooth normals, per organ (never blended across organs)
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
        parent: Sequence[int] | None = None,
    ) -> "Phantom":
        """Validate organs, build the containment tree and the combined mesh.

        ``sites`` maps a site name to ``(kind, position_m)``. Raises
        :class:`PhantomValidationError` naming the organ and the defect; nothing
        is returned half-built. ``check_crossings=False`` skips the edge test of
        :func:`_check_crossings` (for phantoms validated before, e.g. an upload a
        sweep worker reloads); the containment tree is built either way, unless
        ``parent`` gives it: the tree of these very organs from a build that passed
        every check (a built phantom reloaded from its own cache, e.g.
        ``raytrace.body.abdomen``); then the organs are not validated again either.
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
        if parent is None:
            for organ in organs:
                _validate_organ_mesh(organ)
        elif check_crossings or len(parent) != len(organs):
            raise PhantomValidationError("a known containment tree (parent) needs one entry per organ and "
                                         "check_crossings=False: it is for phantoms validated before", field="organs")

        offsets = np.cumsum([0] + [len(o.mesh.vertices) for o in organs])
        vertices = np.concatenate([np.asarray(o.mesh.vertices, float) for o in organs])
        faces = np.concatenate(
            [np.asarray(o.mesh.faces, np.int64) + offsets[i] for i, o in enumerate(organs)]
        )
        face_organ = np.concatenate(
            [np.full(len(o.mesh.faces), i, np.int32) for i, o in enumerate(organs)]
        )
        face_normals = np.concatenate([np.asarray(o.mesh.face_normals, float) for o in organs])
        vertex_normals = np.concatenate(
            [np.asarray(o.mesh.vertex_normals, float) for o in organs]
        )
        phantom = cls(
            name=name,
            organs=organs,
            parent=np.full(len(organs), AIR_INDEX, dtype=np.int64),
            sites={},
            vertices=vertices,
            faces=faces,
            face_organ=face_organ,
            face_normals=face_normals,
            vertex_normals=vertex_normals,
            description=description,
        )
        if check_crossings:
            _check_crossings(phantom)
        phantom.parent = _containment_tree(phantom) if parent is None else np.asarray(parent, np.int64)
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
    def mesh(self) -> trimesh.Trimesh:
        """All organs as one mesh (no merging, no processing): triangle i is ``faces[i]``."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    @cached_property
    def intersector(self):
        """Embree (embreex) ray intersector over every triangle, built once per phantom."""
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        return RayMeshIntersector(self.mesh)

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
        dirs = np.broadcast_to(direction, (n, 3))
        tri, ray, loc = self.intersector.intersects_id(
            points, dirs, multiple_hits=False, return_locations=True
        )
        medium = np.full(n, AIR_INDEX, dtype=np.int64)
        distance = np.full(n, np.inf)
        if len(tri):
            leaving = np.einsum("ij,j->i", self.face_normals[tri], direction) > 0.0
            medium[ray] = np.where(leaving, self.face_organ[tri], self.parent[self.face_organ[tri]])
            distance[ray] = np.linalg.norm(loc - points[ray], axis=1)
        return medium, distance


# ------------------------------------------------------------------ helpers
def _validate_organ_mesh(organ: Organ) -> None:
    mesh = organ.mesh
    where = f"organs.{organ.name}"
    if organ.crease_angle_deg is not None and not 0.0 <= float(organ.crease_angle_deg) <= 180.0:
        raise PhantomValidationError(f"crease_angle_deg must be in [0, 180] deg, got {organ.crease_angle_deg}",
                                     field=f"{where}.crease_angle_deg")
    if len(mesh.faces) < 4:
        raise PhantomValidationError("mesh has fewer than 4 triangles", field=where)
    if not np.isfinite(np.asarray(mesh.vertices)).all():
        raise PhantomValidationError("mesh has non-finite vertex coordinates", field=where)
    if np.any(mesh.area_faces <= 0.0):
        raise PhantomValidationError("mesh has degenerate (zero-area) triangles", field=where)
    if not mesh.is_watertight:
        raise PhantomValidationError("mesh is not watertight (closed)", field=where)
    if not mesh.is_winding_consistent:
        raise PhantomValidationError("mesh triangles are not consistently oriented", field=where)
    if mesh.volume <= 0.0:
        raise PhantomValidationError(
            "mesh is oriented inwards (negative volume); normals must point outwards",
            field=where,
        )


def _check_crossings(phantom: "Phantom") -> None:
    """Refuse any two triangles that cross, of one organ (it passes through itself) or of two (they cross):
    every edge of every organ cast once through the one Embree scene of all triangles (:attr:`Phantom.intersector`,
    the scene every medium lookup uses), :func:`raytrace.body.selfintersect.edge_crossings`. The cost is the
    scene's BVH build plus about 1.5 rays per triangle (docs/phantoms.md, "Scale")."""
    offsets = np.cumsum([0] + [len(o.mesh.vertices) for o in phantom.organs])
    per_organ = [np.asarray(o.mesh.edges_unique, np.int64) for o in phantom.organs]
    pairs = np.concatenate([e + offsets[i] for i, e in enumerate(per_organ)])
    owner = np.concatenate([np.full(len(e), i, np.int32) for i, e in enumerate(per_organ)])
    edge, tri, loc = edge_crossings(phantom.vertices, pairs, phantom.intersector)
    if not len(edge):
        return
    k = 0
    count = len(edge)
    edge_organ, hit_organ = int(owner[edge[k]]), int(phantom.face_organ[tri[k]])
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


def _containment_tree(phantom: "Phantom") -> np.ndarray:
    """Parent organ of every organ (-1 for air). Surfaces that do not cross (:func:`_check_crossings`)
    leave each organ wholly inside or wholly outside each other one, so one point of its surface decides:
    the centroid of its first triangle, whose ray (a fixed oblique direction) through the one scene of all
    triangles crosses each organ containing it an odd number of times (every hit counted, the ray re-cast
    just past each). The parent is the smallest-volume container."""
    n = len(phantom.organs)
    volumes = np.array([o.mesh.volume for o in phantom.organs])
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
        tri, ray, loc = phantom.intersector.intersects_id(origins[alive], np.broadcast_to(direction, (len(alive), 3)),
                                                          multiple_hits=False, return_locations=True)
        hit_rays = alive[ray]
        organs_hit = phantom.face_organ[tri]
        np.add.at(counts, (hit_rays, organs_hit), 1)
        origins[hit_rays] = loc + 1e-6 * scale * direction  # past the hit by more than float32 resolves
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
