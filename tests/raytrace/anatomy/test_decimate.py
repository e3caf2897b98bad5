"""Decimation of voxel-remeshed tubes pressed together (docs/phantoms.md, "Decimation"): the budget is reached
and the surface is not pinched. The oracles share no code with the decimator or trimesh's checks: closedness
and genus from the test's own count of edges and pieces (V - E + F per piece), the gaps between the tubes
from trimesh's exact point-to-triangle distances against the same surface before decimation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from raytrace.body.anatomy.manifest import Options
from raytrace.body.anatomy.repair import voxel_union

RADIUS_M, GAP_M, LENGTH_M, TUBES = 0.004, 0.0015, 0.08, 6


def tubes() -> list[trimesh.Trimesh]:
    """Six parallel capsules, 1.5 mm apart wall to wall (1.5 voxels of the default 1 mm remeshing grid)."""
    out = []
    for k in range(TUBES):
        capsule = trimesh.creation.capsule(height=LENGTH_M, radius=RADIUS_M, count=[24, 24])
        capsule.apply_translation([k * (2 * RADIUS_M + GAP_M), 0.0, 0.0])
        out.append(capsule)
    return out


def pieces_and_euler(faces: np.ndarray, n_vertices: int) -> tuple[list[np.ndarray], list[int], np.ndarray]:
    """(face indices of each piece joined through shared vertices, V - E + F of each, how many triangles share
    each edge), counted here."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, per_edge = np.unique(edges, axis=0, return_counts=True)
    graph = coo_matrix((np.ones(len(unique)), (unique[:, 0], unique[:, 1])), shape=(n_vertices, n_vertices))
    _, label = connected_components(graph, directed=False)
    pieces, euler = [], []
    for k in np.unique(label[faces[:, 0]]):
        mine = np.flatnonzero(label[faces[:, 0]] == k)
        v = len(np.unique(faces[mine]))
        e = len(np.unique(edges.reshape(3, -1, 2)[:, mine].reshape(-1, 2), axis=0))
        pieces.append(mine)
        euler.append(v - e + len(mine))
    return pieces, euler, per_edge


def gaps(mesh: trimesh.Trimesh) -> list[float]:
    """Smallest distance between neighbouring tubes: from every vertex and triangle centroid of one to the
    other's triangles, both ways (trimesh's exact closest points)."""
    pieces, _, _ = pieces_and_euler(np.asarray(mesh.faces), len(mesh.vertices))
    parts = sorted((mesh.submesh([p], append=True) for p in pieces), key=lambda m: m.bounds[0][0])
    out = []
    for a, b in zip(parts, parts[1:]):
        d_ab = trimesh.proximity.closest_point(b, np.vstack([a.vertices, a.triangles_center]))[1]
        d_ba = trimesh.proximity.closest_point(a, np.vstack([b.vertices, b.triangles_center]))[1]
        out.append(float(min(d_ab.min(), d_ba.min())))
    return out


def test_remeshed_tubes_pressed_together_reach_the_budget_without_a_pinch() -> None:
    options = Options()  # 1 mm voxels, 1 voxel of smoothing, 0.5 mm decimation error
    before, _ = voxel_union(tubes(), "organs.tubes", "tubes", options, budget=10**9, max_cells=10**8)
    budget = 20_000
    assert len(before.faces) > 1.5 * budget  # the remeshing gives enough to decimate (31.7 k triangles)
    after, note = voxel_union(tubes(), "organs.tubes", "tubes", options, budget=budget, max_cells=10**8)
    # the budget is reached (before, every reduction was refused as pinched and the surface kept whole)
    assert len(after.faces) <= budget, note
    pieces, euler, per_edge = pieces_and_euler(np.asarray(after.faces), len(after.vertices))
    # closed and not pinched: every edge shared by exactly two triangles (a pinch shares one by four)
    assert per_edge.min() == 2 and per_edge.max() == 2
    # topology kept: six pieces, each a sphere (V - E + F = 2: no handle, no piece joined or lost)
    assert len(pieces) == TUBES and euler == [2] * TUBES
    # the walls stay apart: each gap moves by at most twice the decimation error (each wall by at most
    # decimation_error_m), and none closes
    for gap_before, gap_after in zip(gaps(before), gaps(after)):
        assert gap_before > 0.001  # the remeshing kept the tubes apart
        assert gap_after == pytest.approx(gap_before, abs=2 * options.decimation_error_m)
        assert gap_after > 0.5 * gap_before
    # the volume moves by at most the decimation error times the area
    assert abs(after.volume - before.volume) <= options.decimation_error_m * before.area


def tori() -> list[trimesh.Trimesh]:
    """Eight tori (5 mm ring, 2 mm tube: handles two voxels wide), turned at random (a fixed seed) and
    13.5 mm apart: a shape on which fast-simplification's collapses pinch the remeshed surface at 70 %."""
    rng = np.random.default_rng(1)
    rng.random((16, 3))
    out = []
    for k in range(8):
        torus = trimesh.creation.torus(major_radius=0.005, minor_radius=0.002, major_sections=48, minor_sections=16)
        torus.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        torus.apply_translation([k * 0.0135, 0.0, 0.0])
        out.append(torus)
    return out


def test_where_quadric_collapses_pinch_the_surface_stays_a_closed_manifold() -> None:
    import fast_simplification

    options = Options()
    before, _ = voxel_union(tori(), "organs.rings", "rings", options, budget=10**9, max_cells=10**8)
    budget = int(0.7 * len(before.faces))
    # the premise: fast-simplification alone leaves an edge shared by four triangles at this budget
    _, faces = fast_simplification.simplify(np.asarray(before.vertices), np.asarray(before.faces),
                                            1 - budget / len(before.faces), agg=3)
    assert pieces_and_euler(faces, int(faces.max()) + 1)[2].max() > 2
    after, note = voxel_union(tori(), "organs.rings", "rings", options, budget=budget, max_cells=10**8)
    assert len(after.faces) <= budget, note
    pieces, euler, per_edge = pieces_and_euler(np.asarray(after.faces), len(after.vertices))
    assert per_edge.min() == 2 and per_edge.max() == 2  # closed, no pinch
    assert len(pieces) == 8 and euler == [0] * 8  # eight rings, each still one handle (V - E + F = 0)
    # within the decimation bound of the remeshed surface (trimesh's exact distances to its triangles)
    distance = trimesh.proximity.closest_point(before, np.vstack([after.vertices, after.triangles_center]))[1]
    assert distance.max() <= options.decimation_error_m
    assert abs(after.volume - before.volume) <= options.decimation_error_m * before.area
