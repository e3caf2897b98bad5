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

from raytrace.body.selfintersect import self_intersections
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
    """One closed organ surface and what fills it."""

    name: str
    material: Material
    mesh: trimesh.Trimesh


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
    ) -> "Phantom":
        """Validate organs, build the containment tree and the combined mesh.

        ``sites`` maps a site name to ``(kind, position_m)``. Raises
        :class:`PhantomValidationError` naming the organ and the defect; nothing
        is returned half-built.
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
            _validate_organ_mesh(organ)
        parent = _containment_tree(organs)

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
            parent=parent,
            sites={},
            vertices=vertices,
            faces=faces,
            face_organ=face_organ,
            face_normals=face_normals,
            vertex_normals=vertex_normals,
            description=description,
        )
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
    crossing = self_intersections(mesh.vertices, mesh.faces, limit=1000)
    if len(crossing):
        i, j = (int(k) for k in crossing[0])
        where_m = np.round(np.asarray(mesh.triangles_center[i], float), 4).tolist()
        raise PhantomValidationError(
            f"mesh intersects itself: {len(crossing)}{'+' if len(crossing) == 1000 else ''} pairs of "
            f"triangles that share no vertex cross each other (e.g. triangles {i} and {j}, near "
            f"{where_m} m); an organ must be one closed surface that does not pass through itself",
            field=where,
        )


def _containment_tree(organs: tuple[Organ, ...]) -> np.ndarray:
    """Parent organ of every organ (-1 for air), and a check that no two
    surfaces intersect: every vertex of organ i must lie on the same side of
    organ j (all inside or all outside), and containment must nest."""
    n = len(organs)
    volumes = np.array([o.mesh.volume for o in organs])
    boxes = np.array([o.mesh.bounds for o in organs])
    inside = np.zeros((n, n), dtype=bool)  # inside[i, j]: organ i lies inside organ j
    for j, outer in enumerate(organs):
        for i, inner in enumerate(organs):
            if i == j:
                continue
            lo, hi = boxes[j]
            vi = np.asarray(inner.mesh.vertices)
            in_box = np.all((vi >= lo) & (vi <= hi), axis=1)
            if not in_box.any():
                continue
            flags = np.zeros(len(vi), dtype=bool)
            flags[in_box] = outer.mesh.contains(vi[in_box])
            if flags.all():
                inside[i, j] = True
            elif flags.any():
                raise PhantomValidationError(
                    f"surface of organ {inner.name!r} intersects organ {outer.name!r} "
                    f"({int(flags.sum())} of {len(vi)} vertices inside it)",
                    field=f"organs.{inner.name}",
                )
    parent = np.full(n, AIR_INDEX, dtype=np.int64)
    for i in range(n):
        containers = np.flatnonzero(inside[i])
        if len(containers):
            if np.any(inside[i] & inside[:, i]):
                raise PhantomValidationError(
                    f"organ {organs[i].name!r} and another organ contain each other",
                    field=f"organs.{organs[i].name}",
                )
            parent[i] = containers[np.argmin(volumes[containers])]
    return parent
