"""Self-intersection tests of triangle surfaces: exact pairs (:func:`self_intersections`) and, for whole
phantoms, one Embree ray per edge (:func:`edge_crossings`).

A surface that is watertight, consistently wound and of positive volume can
still cross itself: pull one vertex of a sphere through the opposite side and
every check of :func:`raytrace.body.phantom._validate_organ_mesh` passes, while the
inside of the organ is no longer defined. Two triangles that share no vertex
must never intersect; this module finds the pairs that do.

Broad phase: a hierarchy of uniform grids. Level ``l`` has cells of size
``h * 2**l`` (``h`` the median triangle extent); a triangle is *native* to the
finest level where its bounding box spans at most two cells per axis. Two
triangles whose boxes overlap share a cell at the native level of the larger
one, so the candidates of level ``l`` are the pairs (native of ``l``, any
triangle at most that large) in one cell. Every array operation is vectorised
and the work grows with the number of candidate pairs (about 10 per triangle
on a regular mesh), not with the square of the triangle count.

Narrow phase (exact geometric predicates in float64, no tolerance for the
general case): two non-coplanar triangles intersect iff an edge of one
crosses the other; segment PQ crosses triangle ABC iff P and Q lie strictly
on opposite sides of its plane and the three signed volumes [P, Q, A, B],
[P, Q, B, C], [P, Q, C, A] have one strict sign. Coplanar pairs (all three
vertices within 1e-9 of the triangle's size from the other's plane) are tested
in the plane: a proper crossing of two edges, or a vertex strictly inside the
other triangle. Touching without crossing (a vertex exactly on the other
triangle) is not reported.
"""

from __future__ import annotations

import numpy as np

#: Candidate pairs tested at once (bounded memory: ~1 kB per pair in the narrow phase).
_PAIR_CHUNK = 1 << 18
#: Relative distance below which a vertex counts as lying in the other triangle's plane.
_COPLANAR_REL = 1e-9
_HASH = np.array([73856093, 19349663, 83492791], dtype=np.int64)
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int64)


def self_intersections(vertices: np.ndarray, faces: np.ndarray, limit: int | None = None) -> np.ndarray:
    """(K, 2) index pairs ``i < j`` of triangles that share no vertex and intersect.

    ``limit``: stop once this many pairs are found (the caller only reports).
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    found: list[np.ndarray] = []
    count = 0
    for pairs in _candidate_pairs(lo, hi):
        for start in range(0, len(pairs), _PAIR_CHUNK):
            chunk = pairs[start:start + _PAIR_CHUNK]
            fa, fb = faces[chunk[:, 0]], faces[chunk[:, 1]]
            # adjacent triangles (a shared vertex) touch by construction
            shared = np.zeros(len(chunk), dtype=bool)
            for k in range(3):
                shared |= (fa[:, k, None] == fb).any(axis=1)
            chunk = chunk[~shared]
            if len(chunk) == 0:
                continue
            hit = triangles_intersect(tri[chunk[:, 0]], tri[chunk[:, 1]])
            found.append(chunk[hit])
            count += int(hit.sum())
            if limit is not None and count >= limit:
                pairs = np.concatenate(found)
                return _unique_rows(pairs[:, 0], pairs[:, 1], len(faces))[:limit]
    if not found:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.concatenate(found)
    return _unique_rows(pairs[:, 0], pairs[:, 1], len(faces))


def _cells_of(lo: np.ndarray, hi: np.ndarray, size: float, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hash keys (n, 8) of the up to 2 x 2 x 2 cells each box touches, and a mask of the real
    ones (a hash collision only adds candidates, it never loses one)."""
    c_lo = np.floor((lo - origin) / size).astype(np.int64)
    span = np.minimum(np.floor((hi - origin) / size).astype(np.int64) - c_lo, 1)  # 0 or 1 per axis
    keys = (c_lo @ _HASH)[:, None] + np.zeros((1, 8), dtype=np.int64)
    real = np.ones((len(lo), 8), dtype=bool)
    for axis in range(3):
        corner = _CORNERS[:, axis][None, :]
        keys += corner * (span[:, axis] * _HASH[axis])[:, None]
        real &= corner <= span[:, axis][:, None]
    return keys, real


def _unique_rows(i: np.ndarray, j: np.ndarray, n: int) -> np.ndarray:
    """Distinct pairs (m, 2) of two index arrays (sort-based: faster than a hash here)."""
    key = np.sort(i * n + j)
    if len(key):
        key = key[np.r_[True, key[1:] != key[:-1]]]
    return np.stack([key // n, key % n], axis=1)


def _candidate_pairs(lo: np.ndarray, hi: np.ndarray):
    """Yield arrays (m, 2) of pairs i < j whose boxes overlap, level by level (a pair may
    come twice, from two levels)."""
    n = len(lo)
    extent = (hi - lo).max(axis=1)
    size0 = 2.0 * float(np.median(extent))
    if not size0 > 0.0:
        size0 = float(extent.max()) or 1.0
    origin = lo.min(axis=0)
    # native level: cells of size0 * 2**level hold the box within two cells per axis
    level = np.maximum(0, np.ceil(np.log2(np.maximum(extent / size0, 1.0)))).astype(np.int64)
    for lv in np.unique(level):
        size = size0 * 2.0 ** int(lv)
        smaller = np.flatnonzero(level <= lv)
        keys, real = _cells_of(lo[smaller], hi[smaller], size, origin)
        native = level[smaller] == lv
        if not native.all():  # only cells that hold a native triangle matter at this level
            real &= np.isin(keys, np.unique(keys[native][real[native]]))
        rows, cols = np.nonzero(real)
        entry_key = keys[rows, cols]
        order = np.argsort(entry_key, kind="stable")
        entry_key, entry_tri = entry_key[order], smaller[rows[order]]
        is_native = level[entry_tri] == lv
        starts = np.flatnonzero(np.r_[True, entry_key[1:] != entry_key[:-1]])
        ends = np.r_[starts[1:], len(entry_key)]
        group = np.repeat(np.arange(len(starts)), ends - starts)
        native_pos = np.flatnonzero(is_native)
        # each native entry pairs with the entries after it in its cell, and with the
        # non-native ones before it (ragged ranges, in bounded chunks)
        for s in range(0, len(native_pos), 1 << 16):
            pos = native_pos[s:s + (1 << 16)]
            g = group[pos]
            begin = starts[g]
            counts = ends[g] - begin
            total = int(counts.sum())
            if total == 0:
                continue
            first = np.repeat(pos, counts)
            second = np.repeat(begin, counts) + (np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts))
            keep = (second > first) | ((second < first) & ~is_native[second])
            i, j = entry_tri[first[keep]], entry_tri[second[keep]]
            keep = (i != j) & np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
            i, j = i[keep], j[keep]
            yield _unique_rows(np.minimum(i, j), np.maximum(i, j), n)


def cross_rows(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise cross products, the same products and differences as ``np.cross`` (so the same doubles), without
    its type promotion's copies of both inputs."""
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
                     u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", u, v)


def _volume(p: np.ndarray, q: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed volume (x 6) of the tetrahedron p, q, x, y."""
    return _dot(cross_rows(q - p, x - p), y - p)


def _edges_cross_triangle(a: np.ndarray, b: np.ndarray, side: np.ndarray) -> np.ndarray:
    """Does an edge of triangle ``a`` (n, 3, 3) properly cross triangle ``b``? ``side[:, k]``
    is the signed distance-like value of vertex k of ``a`` from ``b``'s plane."""
    hit = np.zeros(len(a), dtype=bool)
    for k in range(3):
        p, q = a[:, k], a[:, (k + 1) % 3]
        opposite = side[:, k] * side[:, (k + 1) % 3] < 0.0
        v0 = _volume(p, q, b[:, 0], b[:, 1])
        v1 = _volume(p, q, b[:, 1], b[:, 2])
        v2 = _volume(p, q, b[:, 2], b[:, 0])
        same = ((v0 > 0) & (v1 > 0) & (v2 > 0)) | ((v0 < 0) & (v1 < 0) & (v2 < 0))
        hit |= opposite & same
    return hit


def _orient2(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])


def _inside2(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Point p (n, 2) strictly inside triangle t (n, 3, 2)."""
    d0 = _orient2(t[:, 0], t[:, 1], p)
    d1 = _orient2(t[:, 1], t[:, 2], p)
    d2 = _orient2(t[:, 2], t[:, 0], p)
    return ((d0 > 0) & (d1 > 0) & (d2 > 0)) | ((d0 < 0) & (d1 < 0) & (d2 < 0))


def _coplanar_overlap(a: np.ndarray, b: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Coplanar triangles (n, 3, 3): projected on the plane of the normal's two minor axes,
    does an edge of one properly cross an edge of the other, or a vertex lie inside the other?"""
    axes = np.array([[1, 2], [0, 2], [0, 1]])[np.argmax(np.abs(normal), axis=1)]
    rows = np.arange(len(a))
    a2 = np.stack([a[rows, :, axes[:, 0]], a[rows, :, axes[:, 1]]], axis=-1)  # (n, 3, 2)
    b2 = np.stack([b[rows, :, axes[:, 0]], b[rows, :, axes[:, 1]]], axis=-1)
    hit = np.zeros(len(a), dtype=bool)
    for k in range(3):
        p, q = a2[:, k], a2[:, (k + 1) % 3]
        for m in range(3):
            r, s = b2[:, m], b2[:, (m + 1) % 3]
            d1, d2 = _orient2(p, q, r), _orient2(p, q, s)
            d3, d4 = _orient2(r, s, p), _orient2(r, s, q)
            hit |= (d1 * d2 < 0) & (d3 * d4 < 0)
        hit |= _inside2(a2[:, k], b2) | _inside2(b2[:, k], a2)
    return hit


def triangles_intersect(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Element-wise: do triangles ``a[i]`` and ``b[i]`` (each (n, 3, 3)) intersect (see module doc)?"""
    na = cross_rows(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0])
    nb = cross_rows(b[:, 1] - b[:, 0], b[:, 2] - b[:, 0])
    side_a = _dot(a - b[:, None, 0], nb[:, None, :])  # vertices of a against b's plane
    side_b = _dot(b - a[:, None, 0], na[:, None, :])
    hit = _edges_cross_triangle(a, b, side_a) | _edges_cross_triangle(b, a, side_b)
    # |side| = distance x |nb|, and sqrt(|nb|) is about b's edge length
    norm_b = np.linalg.norm(nb, axis=1)
    coplanar = np.all(np.abs(side_a) <= (_COPLANAR_REL * norm_b * np.sqrt(norm_b))[:, None], axis=1)
    if coplanar.any():
        hit[coplanar] |= _coplanar_overlap(a[coplanar], b[coplanar], nb[coplanar])
    return hit


#: Edges are tested between these fractions of their length: a crossing within 0.1 % of an edge's end is
#: a touch at a shared vertex (float32 rays, their own triangles' corners), not reported.
EDGE_TRIM = 1e-3
#: An edge's ray runs this many of the scene's float32 offsets (:attr:`raytrace.body.rays.RayScene.offset_m`)
#: beside the edge (module docstring of :func:`edge_crossings`).
EDGE_OFFSETS = 4.0
#: Re-casts past hits that are no crossing (a triangle at an end of the edge), before the edge's remaining
#: candidates are tested exactly.
_ROUNDS = 8


def _segments_cross(p: np.ndarray, q: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Element-wise exact test: segment ``p q`` crosses the closed triangle ``tri``: its ends strictly on
    opposite sides of the plane, and the three signed volumes of one sign, zeros allowed (through an edge or a
    corner of the triangle: a crossing of two closed surfaces all the same), not all zero."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = cross_rows(b - a, c - a)
    sp, sq = _dot(p - a, n), _dot(q - a, n)
    v1 = _volume(p, q, a, b)
    v2 = _volume(p, q, b, c)
    v3 = _volume(p, q, c, a)
    same = (((v1 >= 0) & (v2 >= 0) & (v3 >= 0)) | ((v1 <= 0) & (v2 <= 0) & (v3 <= 0))) & \
        ~((v1 == 0) & (v2 == 0) & (v3 == 0))
    return (sp * sq < 0) & same


def edge_crossings(vertices: np.ndarray, faces: np.ndarray, edges, normals: np.ndarray,
                   scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges of closed surfaces that cross a triangle of ``scene`` (a :class:`raytrace.body.rays.RayScene`
    of the same ``vertices`` and ``faces``), as ``(edge index, triangle index, crossing point)`` arrays.

    ``edges``: the surfaces' :class:`raytrace.body.topology.ClosedEdges` (each edge once, with its two
    triangles); ``normals``: the unit facet normals. Two closed triangle surfaces intersect iff an edge of one
    crosses a triangle of the other, and a surface crosses itself iff an edge crosses a triangle that shares
    no vertex with it. Each edge, trimmed by :data:`EDGE_TRIM` at both ends, is cast as one *segment*
    (a ray ending at the edge's other end, :meth:`RayScene.first_hits` with ``tfar``) that runs parallel to
    the edge, :data:`EDGE_OFFSETS` float32 offsets of the scene beside it along the mean of its two
    triangles' normals. The edge lies in both of its triangles' planes, so a ray along the edge itself
    grazes them in float32 (on the default torso 27 % of the edges' rays hit a neighbour, and a graze before
    a crossing would hide it); the parallel ray runs off both planes and never meets them. A hit is
    confirmed by the exact predicates above in float64 on the edge itself, triangles sharing a vertex with
    it excluded; a hit that is no crossing (a triangle around an end of the edge) is passed and the rest of
    the segment cast again, up to :data:`_ROUNDS` times, after which the edge is tested exactly against
    every triangle near it. What the offset can miss is a crossing less deep than the offset (about a
    micrometre on a body: 4 x 16 float32 ulps of its largest coordinate). The cost is one short segment per
    edge (about 1.5 per triangle): Embree visits only the few BVH nodes along it."""
    pairs, face, twin = edges
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    if not len(pairs):
        return empty
    offset = EDGE_OFFSETS * scene.offset_m
    first, t_first = scene.edge_hits(pairs, face, twin, EDGE_TRIM, offset)
    index = np.flatnonzero(first >= 0)  # the few edges whose segment met a triangle
    if not len(index):
        return empty
    # the candidates' segments again, in float64 (as the compiled pass made them)
    a = vertices[pairs[index, 0]]
    direction = vertices[pairs[index, 1]] - a
    length = np.linalg.norm(direction, axis=1)
    direction /= length[:, None]
    side = normals[face[index]] + normals[twin[index]]
    norm = np.linalg.norm(side, axis=1, keepdims=True)
    side = np.where(norm > 1e-3, side / np.maximum(norm, 1e-300), normals[face[index]])
    start = a + EDGE_TRIM * length[:, None] * direction + offset * side
    span = (1.0 - 2 * EDGE_TRIM) * length
    found_edge, found_tri, found_at = [], [], []
    alive = np.arange(len(index))  # into index
    travelled = np.zeros(len(index))
    tri, t = first[index], t_first[index].astype(float)
    for round_ in range(_ROUNDS):
        if round_:
            tri, t = scene.first_hits(start[alive] + travelled[alive, None] * direction[alive], direction[alive],
                                      span[alive] - travelled[alive])
            hit = tri >= 0
            alive, tri, t = alive[hit], tri[hit], t[hit]
        crossing = _edge_crosses(vertices, faces, pairs[index[alive]], tri)
        found_edge.append(index[alive[crossing]])
        found_tri.append(tri[crossing])
        found_at.append(start[alive[crossing]] + (travelled[alive[crossing]] + t[crossing])[:, None]
                        * direction[alive[crossing]])
        alive, t = alive[~crossing], t[~crossing]
        travelled[alive] += t + scene.offset_m
        alive = alive[travelled[alive] < span[alive]]
        if not len(alive):
            break
    if len(alive):  # still hitting triangles that are no crossing: test the edges exactly against their neighbours
        e, tri = _near_crossings(vertices, faces, pairs[index[alive]])
        found_edge.append(index[alive[e]])
        found_tri.append(tri)
        found_at.append(0.5 * (vertices[pairs[index[alive[e]], 0]] + vertices[pairs[index[alive[e]], 1]]))
    return (np.concatenate(found_edge), np.concatenate(found_tri).astype(np.int64),
            np.concatenate(found_at).reshape(-1, 3))


def _edge_crosses(vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Element-wise: edge ``pairs[i]`` crosses triangle ``tri[i]`` (exactly), sharing no vertex with it."""
    corners = faces[tri]
    shares = (corners == pairs[:, 0, None]).any(axis=1) | (corners == pairs[:, 1, None]).any(axis=1)
    return ~shares & _segments_cross(vertices[pairs[:, 0]], vertices[pairs[:, 1]], vertices[corners])


def _near_crossings(vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edge, triangle) pairs among ``pairs`` and the triangles whose bounding spheres reach the edge's,
    that cross exactly (the fallback of :func:`edge_crossings`; a handful of edges)."""
    from scipy.spatial import cKDTree

    tri = vertices[faces]
    centre = tri.mean(axis=1)
    reach = float(np.max(np.linalg.norm(tri - centre[:, None, :], axis=2)))
    mid = 0.5 * (vertices[pairs[:, 0]] + vertices[pairs[:, 1]])
    half = 0.5 * np.linalg.norm(vertices[pairs[:, 1]] - vertices[pairs[:, 0]], axis=1)
    tree = cKDTree(centre)
    edges, tris = [], []
    for k, near in enumerate(tree.query_ball_point(mid, half + reach)):
        edges.append(np.full(len(near), k, np.int64))
        tris.append(np.asarray(near, np.int64))
    e, t = np.concatenate(edges), np.concatenate(tris)
    crossing = _edge_crosses(vertices, faces, pairs[e], t)
    return e[crossing], t[crossing]
