"""Checks and repairs of one organ's surface (docs/phantoms.md, "Checks and repairs").

:func:`repair_surface` takes the triangles of every file of an organ (already in metres, in the
project's frame) and answers one closed, consistently outward-wound, self-intersection-free
surface, or refuses naming the organ and what to fix. In order, each step recorded in the report
only when it changed something:

1. **join and weld**: the files' triangles are concatenated and vertices closer than
   ``weld_m`` merged (so pieces that share their cut edges become one surface);
2. **degenerate and duplicate faces**: triangles with a repeated vertex or an area below
   ``weld_m**2``, and second copies of a triangle, are removed; a triangle given twice with opposite
   windings is the wall between two pieces that share it (the caps of an organ cut into segments), and
   both copies are removed, so the pieces join into one surface;
3. **holes**: boundary loops are found; a loop whose span is at most ``max_hole_m`` is filled,
   and so is a loop of any size that is planar within ``planar_fraction`` of its span (a planar
   cut: an organ cut into segments, an open tube end where it leaves the scan). A fill is a fan
   of triangles from the loop to its centroid. A loop that is neither is refused, naming its size
   and where it is;
4. **winding**: every shell is wound consistently and outward (trimesh ``fix_normals``);
5. **pieces**: when the surface still has edges shared by more than two triangles, or crosses
   itself (pieces that overlap or touch, caps that cut through each other), it is made the union of
   its closed pieces (the organ's files when each is closed on its own, e.g. segments cut at landmarks
   whose shared caps are triangulated differently, else the surface's closed shells): first **exactly**,
   by manifold3d's boolean union of the pieces' own triangles (:func:`exact_union`), kept when it is
   closed, consistently wound and does not cross itself; otherwise **remeshed on a voxel grid** of
   ``voxel_m``: the cells inside any shell (ray parity, :func:`raytrace.body.anatomy.grid.inside_mask`),
   smoothed by a Gaussian of ``smoothing_voxels`` cells and meshed by marching cubes at the half level,
   then decimated to the organ's triangle budget (:mod:`raytrace.body.anatomy.decimate`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from raytrace.body.anatomy.grid import Grid, inside_mask, surface_from_field
from raytrace.body.anatomy.manifest import Options
from raytrace.body.selfintersect import cross_rows
from raytrace.body.topology import ClosedEdges, closed_edges
from raytrace.errors import Field, PhantomValidationError

__all__ = ["Repaired", "boundary_loops", "exact_union", "repair_surface", "voxel_union"]


#: Pieces of an exact union smaller than this are float32 slivers, dropped [m^3] (one cubic millimetre).
MIN_PIECE_M3 = 1e-9


@dataclass
class Repaired:
    mesh: trimesh.Trimesh
    repairs: list[str] = field(default_factory=list)
    #: The organ's files as closed surfaces, when there are several and each is closed on its own (for the
    #: union of step 5, also when the build later finds the joined surface crossing itself).
    pieces: list[trimesh.Trimesh] = field(default_factory=list)
    #: remeshed on a voxel grid and decimated there (its error measured from the marching-cubes surface): a
    #: second decimation would add its error to the first one's
    remeshed: bool = False
    #: the closed edges of ``mesh`` as repaired (None when remeshed): the build hands them to the phantom's
    #: checks (:func:`raytrace.body.phantom.check_surfaces`) instead of sorting the half-edges again
    edges: ClosedEdges | None = None


def _fail(reason: str, where: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=where)


def _mm(x: float) -> str:
    return f"{x * 1e3:.3g} mm"


#: The sweep direction of :func:`close_pairs`: no coordinate axis (grids of vertices line up along those).
_SWEEP = np.array([0.5773502691896258, 0.5345224838248488, 0.6172133998483676])


def close_pairs(points: np.ndarray, distance: float) -> np.ndarray:
    """Every pair ``i < j`` of points at most ``distance`` apart, (K, 2). Points that close have projections
    on any direction at most that far apart, so after one sort of the projections on :data:`_SWEEP` only the
    neighbours within ``distance`` in that order are candidates, each then measured (a sweep: no false
    negative, and on a mesh a handful of candidates, where a k-d tree builds a hierarchy of every point).
    When the candidates would be many (a distance wide against the points' spacing), a k-d tree answers."""
    projection = points @ _SWEEP
    order = np.argsort(projection, kind="stable")
    ordered = projection[order]
    span = np.searchsorted(ordered, ordered + distance, side="right") - np.arange(len(ordered)) - 1
    first = np.flatnonzero(span > 0)
    if not len(first):
        return np.zeros((0, 2), np.int64)
    counts = span[first]
    if int(counts.sum()) > 8 * len(points) + 1000:  # a distance wide against the points' spacing: a k-d tree
        from scipy.spatial import cKDTree

        return cKDTree(points).query_pairs(distance, output_type="ndarray").astype(np.int64)
    i = np.repeat(first, counts)
    j = i + 1 + (np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts))
    a, b = order[i], order[j]
    near = np.einsum("ij,ij->i", points[a] - points[b], points[a] - points[b]) <= distance * distance
    a, b = a[near], b[near]
    return np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)


def weld(vertices: np.ndarray, faces: np.ndarray, weld_m: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Merge every group of vertices linked by distances of at most ``weld_m`` (pairs from
    :func:`close_pairs`, groups as connected components); answers the new arrays and how many vertices
    merged away."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = close_pairs(vertices, weld_m)
    if not len(pairs):
        return vertices, faces, 0
    n = len(vertices)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, group = connected_components(graph, directed=False)
    _, first = np.unique(group, return_index=True)
    return vertices[first], group[faces], n - count


def clean_faces(vertices: np.ndarray, faces: np.ndarray, weld_m: float) -> tuple[np.ndarray, int, int, int]:
    """Faces without degenerate triangles, duplicates and inner walls; answers (faces, degenerate, duplicates,
    inner walls). A triangle given twice with the same winding is a duplicate (one copy kept); twice with
    opposite windings it is the wall between two pieces that share it (the caps of an organ cut into
    segments), and both copies go, so the pieces become one surface."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    degenerate = repeated | (area <= weld_m**2)
    faces = faces[~degenerate]
    low, high = np.minimum(faces[:, 0], faces[:, 1]), np.maximum(faces[:, 0], faces[:, 1])
    key = _keys(np.stack([np.minimum(low, faces[:, 2]), np.maximum(low, np.minimum(high, faces[:, 2])),
                          np.maximum(high, faces[:, 2])], axis=1))  # each row sorted
    ordered = np.sort(key)
    if not np.any(ordered[1:] == ordered[:-1]):  # no triangle twice: nothing more to remove
        return faces, int(degenerate.sum()), 0, 0
    _, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    # the winding of a face: its rotation that starts at its smallest vertex, as a key
    start = np.argmin(faces, axis=1)
    rotated = np.stack([faces[np.arange(len(faces)), (start + k) % 3] for k in range(3)], axis=1)
    winding = _keys(rotated)
    opposite = np.zeros(len(counts), dtype=bool)
    pairs = np.flatnonzero(counts == 2)
    if len(pairs):
        members = np.argsort(inverse, kind="stable")
        offsets = np.concatenate([[0], np.cumsum(counts)])
        a = members[offsets[pairs]]
        b = members[offsets[pairs] + 1]
        opposite[pairs] = winding[a] != winding[b]
    keep = np.zeros(len(faces), dtype=bool)
    keep[first] = True
    keep &= ~opposite[inverse]
    walls = int(opposite.sum())
    duplicates = len(faces) - int(keep.sum()) - 2 * walls
    return faces[keep], int(degenerate.sum()), duplicates, walls


def _keys(rows: np.ndarray) -> np.ndarray:
    """One int64 per row of 2 or 3 vertex indices (below 2**21 for three, 2**31 for two), so that
    ``np.unique`` sorts numbers instead of rows."""
    rows = np.asarray(rows, np.int64)
    if rows.shape[1] == 2:
        return (rows[:, 0] << 31) | rows[:, 1]
    if rows.max(initial=0) < (1 << 21):
        return (rows[:, 0] << 42) | (rows[:, 1] << 21) | rows[:, 2]
    return np.unique(rows, axis=0, return_inverse=True)[1].ravel()


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed loops of boundary edges (edges of one triangle only), each as vertex indices in the
    order of the triangles' winding; edges of a vertex where several holes meet are followed in turn."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, inverse, counts = np.unique(_keys(np.sort(edges, axis=1)), return_inverse=True, return_counts=True)
    boundary = edges[counts[inverse.ravel()] == 1]
    nxt: dict[int, list[int]] = {}
    for a, b in boundary.tolist():
        nxt.setdefault(a, []).append(b)
    loops = []
    while nxt:
        start = next(iter(nxt))
        loop = [start]
        current = start
        while True:
            targets = nxt.get(current)
            if not targets:
                break
            b = targets.pop()
            if not targets:
                del nxt[current]
            if b == start:
                break
            loop.append(b)
            current = b
            if len(loop) > len(boundary):
                break
        if len(loop) >= 3:
            loops.append(np.array(loop, dtype=np.int64))
    return loops


def _cap(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fan from the loop's centroid; the boundary edge (a, b) of a face is used as (b, a)."""
    centre = vertices[loop].mean(axis=0)
    c = len(vertices)
    a = loop
    b = np.roll(loop, -1)
    fan = np.stack([b, a, np.full(len(loop), c)], axis=1)
    return np.vstack([vertices, centre]), np.vstack([faces, fan])


def _planarity(points: np.ndarray) -> tuple[float, float]:
    """(largest distance from the best-fit plane, span) of a loop."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    off = float(np.max(np.abs(centred @ vt[2])))
    span = float(np.max(np.linalg.norm(points[:, None, :] - points[None, ::max(1, len(points) // 64), :], axis=2)))
    return off, span


def repair_surface(vertices: np.ndarray, faces: np.ndarray, where: Field, label: str, options: Options,
                   *, budget: int, max_cells: int, check_crossings: bool = True,
                   pieces: "list[int] | None" = None) -> Repaired:
    """One closed outward surface from the triangles of an organ's files (module docstring).
    ``check_crossings=False`` leaves the self-crossing test of step 5 to the caller (the build tests every
    organ at once, :func:`raytrace.body.anatomy.overlap.crossing_pairs`, and calls :func:`union_of` then).
    ``pieces``: the number of triangles each file gave, in the order of ``faces`` (the files' own closed
    surfaces are the pieces of step 5's union when each is closed)."""
    repairs: list[str] = []
    closed = _closed_files(np.asarray(vertices, float), np.asarray(faces, np.int64), pieces)
    vertices, faces, merged = weld(np.asarray(vertices, float), np.asarray(faces, np.int64), options.weld_m)
    if merged:
        repairs.append(f"welded {merged} vertices closer than {_mm(options.weld_m)}")
    faces, degenerate, duplicate, walls = clean_faces(vertices, faces, options.weld_m)
    if degenerate:
        repairs.append(f"removed {degenerate} degenerate triangles")
    if duplicate:
        repairs.append(f"removed {duplicate} duplicate triangles")
    if walls:
        repairs.append(f"removed {walls} triangles given twice with opposite windings (the walls between pieces "
                       "that share a cap: the pieces joined into one surface)")
    vertices, faces = _drop_unused(vertices, faces)
    if len(faces) < 4:
        raise _fail(f"{label}: fewer than 4 triangles are left after removing degenerate ones", where)
    filled, capped = 0, 0
    edges = closed_edges(faces)  # closed and consistently wound (most files): no holes, nothing to turn
    for loop in boundary_loops(faces) if edges is None else []:
        points = vertices[loop]
        off, span = _planarity(points)
        if span <= options.max_hole_m:
            filled += 1
        elif off <= options.planar_fraction * span:
            capped += 1
        else:
            centre = np.round(points.mean(axis=0) * 1e3, 1).tolist()
            raise _fail(
                f"{label} is open: a hole {_mm(span)} across (boundary of {len(loop)} edges, around {centre} mm in "
                f"the project frame) is larger than the fill limit max_hole_m = {_mm(options.max_hole_m)} and not a "
                f"planar cut (it leaves its best-fit plane by {_mm(off)}, over {options.planar_fraction:g} of its "
                "span); close the surface, or raise options.max_hole_m", where)
        vertices, faces = _cap(vertices, faces, loop)
    if filled:
        repairs.append(f"filled {filled} hole(s) up to {_mm(options.max_hole_m)} across")
    if capped:
        repairs.append(f"capped {capped} planar cut(s)")
    needs_union = edges is None and _non_manifold(faces)
    if not needs_union:
        if edges is None:
            edges = closed_edges(faces)
        if edges is None:  # wound inconsistently: trimesh turns each shell's triangles one way
            mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
            trimesh.repair.fix_normals(mesh, multibody=True)
            faces = np.asarray(mesh.faces, np.int64)
            edges = closed_edges(faces)
            needs_union = edges is None
            if edges is not None:
                repairs.append("made the triangles' winding consistent and outward")
        if edges is not None:
            faces, turned, flip = _outward(vertices, faces, edges)
            if flip is not None:  # a turned triangle holds its edges' other half-edges: face and twin swap
                swap = flip[edges.face]
                edges = ClosedEdges(edges.edges, np.where(swap, edges.twin, edges.face),
                                    np.where(swap, edges.face, edges.twin))
                repairs.append("turned the surface outward (it was wound inward)" if turned == "all" else
                               f"turned {turned} of its shells outward (they were wound inward)")
    mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
    if not needs_union and check_crossings:
        needs_union = crosses_itself(mesh)
    remeshed = False
    if needs_union:
        mesh, note, remeshed = _union(closed or _closed_shells(mesh), where, label, options, budget=budget,
                                      max_cells=max_cells, files=bool(closed))
        repairs.append(note)
    return Repaired(mesh, repairs, closed, remeshed=remeshed, edges=None if needs_union else edges)


def _closed_files(vertices: np.ndarray, faces: np.ndarray, pieces: "list[int] | None") -> list[trimesh.Trimesh]:
    """Each file's triangles as a surface, oriented outward, when there are several and every one is closed
    and consistently wound on its own; else none."""
    if not pieces or len(pieces) < 2 or sum(pieces) != len(faces):
        return []
    out = []
    for part in np.split(faces, np.cumsum(pieces)[:-1]):
        mesh = trimesh.Trimesh(vertices, part, process=False, validate=False)
        mesh.remove_unreferenced_vertices()
        if len(mesh.faces) < 4 or not (mesh.is_watertight and mesh.is_winding_consistent):
            return []
        if mesh.volume < 0:
            mesh.invert()
        out.append(mesh)
    return out


def exact_union(shells: list[trimesh.Trimesh]) -> trimesh.Trimesh | None:
    """The boolean union of closed shells by manifold3d (exact arithmetic on the shells' own triangles:
    walls they share, such as the caps of segments cut at one plane, vanish whatever their triangulation),
    or None unless that union is one or more closed, consistently wound surfaces that do not cross
    themselves (the voxel remeshing is the fallback, module docstring step 5)."""
    import manifold3d

    origin = np.mean([s.bounds.mean(axis=0) for s in shells], axis=0)
    try:
        union = None
        for shell in shells:
            m = manifold3d.Manifold(manifold3d.Mesh(
                vert_properties=np.asarray(shell.vertices - origin, np.float32),
                tri_verts=np.asarray(shell.faces, np.uint32)))
            if m.status() != manifold3d.Error.NoError:
                return None
            union = m if union is None else union + m
        if union is None:  # no shells
            return None
        out = union.to_mesh()
    except Exception:  # manifold3d refuses what it cannot treat as a closed manifold: fall back
        return None
    mesh = trimesh.Trimesh(np.asarray(out.vert_properties, float)[:, :3] + origin,
                           np.asarray(out.tri_verts, np.int64), process=True, validate=False)
    # float32 coordinates leave slivers where the pieces' seams do not meet exactly: zero-area triangles and
    # specks of no volume, split off and dropped (below a cubic millimetre, far under any organ's features)
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-12))
    mesh.remove_unreferenced_vertices()
    parts = mesh.split(only_watertight=False)
    if len(parts) > 1:
        keep = [p for p in parts if abs(p.volume) >= MIN_PIECE_M3]
        mesh = trimesh.util.concatenate(keep) if keep else mesh
    if not len(mesh.faces) or not (mesh.is_watertight and mesh.is_winding_consistent) or mesh.volume <= 0:
        return None
    if _non_manifold(np.asarray(mesh.faces)) or crosses_itself(mesh):
        return None
    return mesh


def _union(shells: list[trimesh.Trimesh], where: Field, label: str, options: Options, *, budget: int,
           max_cells: int, files: bool) -> tuple[trimesh.Trimesh, str, bool]:
    """Step 5: the exact union of the shells when it is clean, else the voxel remeshing; and whether it was
    remeshed (then already decimated from its voxels: Repaired.remeshed)."""
    if len(shells) >= 2:
        joined = exact_union(shells)
        if joined is not None:
            what = "files, each closed," if files else "closed pieces"
            return joined, (f"joined its {len(shells)} {what} by an exact boolean union (manifold3d): "
                            f"{len(joined.faces)} triangles, {joined.volume * 1e6:.4g} mL"), False
    return (*voxel_union(shells, where, label, options, budget=budget, max_cells=max_cells), True)


def _drop_unused(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices some triangle uses (in their order) and the faces renumbered."""
    used = np.bincount(faces.ravel(), minlength=len(vertices)) > 0
    if used.all():
        return vertices, faces
    remap = np.cumsum(used) - 1
    return vertices[used], remap[faces]


def _outward(vertices: np.ndarray, faces: np.ndarray,
             edges: ClosedEdges) -> tuple[np.ndarray, str | int, np.ndarray | None]:
    """Closed, consistently wound ``faces`` with every shell (connected through its edges) wound outward
    (positive volume, by the divergence theorem); ``"all"``, the number of shells turned, or 0; and which
    triangles were turned (None when none)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    signed = np.einsum("ij,ij->i", v0, cross_rows(v1, v2))
    n = len(vertices)
    count, shell = connected_components(coo_matrix((np.ones(len(edges.edges)), (edges.edges[:, 0], edges.edges[:, 1])),
                                                   shape=(n, n)), directed=False)
    face_shell = shell[faces[:, 0]]
    inward = np.bincount(face_shell, weights=signed, minlength=count) < 0
    if not inward.any():
        return faces, 0, None
    flip = inward[face_shell]
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return faces, "all" if inward.all() else int(inward.sum()), flip


def crosses_itself(mesh: trimesh.Trimesh) -> bool:
    """Whether an edge of the closed surface crosses one of its triangles (one Embree segment per edge,
    :func:`raytrace.body.phantom.surface_crossings`)."""
    from raytrace.body.phantom import check_surfaces, surface_crossings

    return bool(surface_crossings(check_surfaces([mesh], ["surface"])).crossings)


def union_of(mesh: trimesh.Trimesh, where: Field, label: str, options: Options, *, budget: int,
             max_cells: int, pieces: "list[trimesh.Trimesh] | None" = None) -> tuple[trimesh.Trimesh, str]:
    """Step 5 for a surface found crossing itself after the repairs (``pieces``: :attr:`Repaired.pieces`),
    decimated to ``budget`` like every remeshed surface."""
    from raytrace.body.anatomy.decimate import decimate

    out, note, _ = _union(pieces or _closed_shells(mesh), where, label, options, budget=budget, max_cells=max_cells,
                          files=bool(pieces))
    if len(out.faces) > budget:  # an exact union keeps the pieces' triangles (the voxel union decimated already)
        out, error = decimate(out, budget, options.decimation_error_m)
        note += f", decimated to {len(out.faces)} triangles within {_mm(error)}"
    return out, note


def _non_manifold(faces: np.ndarray) -> bool:
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(_keys(edges), return_counts=True)
    return bool(np.any(counts > 2))


def _closed_shells(mesh: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    """The surface's connected pieces (through shared vertices: a non-manifold edge joins them), each
    oriented outward; a piece that is not closed cannot say what is inside it and is refused by the caller."""
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    shells = []
    for k in np.unique(labels):
        part = trimesh.Trimesh(mesh.vertices, mesh.faces[labels == k], process=False)
        part.remove_unreferenced_vertices()
        trimesh.repair.fix_normals(part, multibody=True)
        if part.volume < 0:
            part.invert()
        shells.append(part)
    return shells


def voxel_union(shells: list[trimesh.Trimesh], where: Field, label: str, options: Options, *, budget: int,
                max_cells: int) -> tuple[trimesh.Trimesh, str]:
    """One surface around the union of closed shells, remeshed on a voxel grid (module docstring, step 5)."""
    from scipy.ndimage import gaussian_filter

    from raytrace.body.anatomy.decimate import decimate

    lo = np.min([s.bounds[0] for s in shells], axis=0)
    hi = np.max([s.bounds[1] for s in shells], axis=0)
    h = options.voxel_m
    grid = Grid.around(lo, hi, h, 3, max_cells, where, f"remeshing {label}")
    inside = np.zeros(grid.shape, dtype=bool)
    bad = 0
    for shell in shells:
        m = inside_mask(shell, grid)
        inside |= m.mask
        bad += m.bad_columns
    if not inside.any():
        raise _fail(f"{label}: its pieces enclose no volume at {_mm(h)} voxels (open sheets, or thinner than a "
                    "voxel): give closed surfaces or a smaller options.voxel_m", where)
    raw_volume = float(inside.sum()) * h**3
    field = gaussian_filter(inside.astype(np.float32), sigma=options.smoothing_voxels) if options.smoothing_voxels \
        else inside.astype(np.float32)
    mesh = surface_from_field(0.5 - field, grid, 0.0)
    if mesh.volume < 0:
        mesh.invert()
    parts = mesh.split(only_watertight=False)
    if len(parts) > 1:  # specks of a voxel or two: keep the pieces that hold volume
        keep = [p for p in parts if abs(p.volume) >= 8 * h**3]
        mesh = trimesh.util.concatenate(keep) if keep else mesh
    mesh, error = decimate(mesh, budget, options.decimation_error_m)
    over = f", over the budget of {budget}: no fewer kept it closed" if len(mesh.faces) > budget else ""
    decimated = (f"decimated to {len(mesh.faces)} triangles, within {_mm(error)}{over}" if error > 0 or
                 len(mesh.faces) <= budget else f"{len(mesh.faces)} triangles: no decimation kept it closed")
    note = (f"remeshed the union of {len(shells)} closed piece(s) on a {_mm(h)} voxel grid (smoothing "
            f"{options.smoothing_voxels:g} voxel, {decimated}); voxel volume {raw_volume * 1e6:.4g} mL")
    if bad:
        note += f"; {bad} grid column(s) of ambiguous parity left out"
    return mesh, note
