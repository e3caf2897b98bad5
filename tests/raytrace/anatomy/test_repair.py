"""Repairs: welding, degenerate and duplicate triangles, inward winding, small holes, planar cuts (an open
tube), pieces overlapping (voxel union), overlaps between organs resolved below the tolerance. Volumes
against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from raytrace.body.anatomy import build_phantom
from raytrace.body.anatomy.manifest import Options
from raytrace.body.anatomy.repair import boundary_loops, repair_surface, voxel_union
from tests.raytrace.anatomy.files import polyhedron_volume, sphere, write_surface


def _repair(mesh: trimesh.Trimesh, **options):
    return repair_surface(np.asarray(mesh.vertices) * 1e-3, np.asarray(mesh.faces), "organ", "organ",
                          Options(**options), budget=20_000, max_cells=10**7)


def test_degenerate_duplicate_and_inward_triangles_are_fixed() -> None:
    s = sphere(20.0, subdivisions=2)
    faces = np.vstack([s.faces[:, ::-1], s.faces[:5, ::-1], [[0, 0, 1]]])  # inward, 5 duplicates, 1 degenerate
    out = _repair(trimesh.Trimesh(s.vertices, faces, process=False))
    assert out.mesh.volume == pytest.approx(polyhedron_volume(s.vertices, s.faces) * 1e-9, rel=1e-9)
    text = " ".join(out.repairs)
    assert "1 degenerate" in text and "5 duplicate" in text and "outward" in text


def test_a_small_hole_is_filled_and_a_planar_cut_capped() -> None:
    s = sphere(20.0, subdivisions=3)
    holed = trimesh.Trimesh(s.vertices, s.faces[1:], process=False)  # one triangle (~2.5 mm) missing
    out = _repair(holed)
    assert out.mesh.is_watertight and any("filled 1 hole" in r for r in out.repairs)
    assert out.mesh.volume == pytest.approx(polyhedron_volume(s.vertices, s.faces) * 1e-9, rel=1e-3)
    # An open tube (a cylinder without its end caps): two planar loops 40 mm across, capped.
    tube = trimesh.creation.cylinder(radius=20.0, height=60.0, sections=48)
    side = np.abs(tube.face_normals[:, 2]) < 0.5
    open_tube = trimesh.Trimesh(tube.vertices, tube.faces[side], process=False)
    assert len(boundary_loops(open_tube.faces)) == 2
    out = _repair(open_tube)
    assert out.mesh.is_watertight and any("capped 2 planar cut" in r for r in out.repairs)
    # closed form: the prism inscribed in the cylinder, 48 sides: (48/2) sin(2 pi/48) r^2 h
    assert out.mesh.volume == pytest.approx(24 * math.sin(2 * math.pi / 48) * 20.0**2 * 60.0 * 1e-9, rel=1e-9)


def test_overlapping_pieces_are_joined_as_their_union() -> None:
    """Two closed spheres (r = 20 mm, centres 20 mm apart) given as one organ: the union, by the closed form
    of two intersecting balls (V = 2 * 4/3 pi r^3 - lens, lens = pi (4r + d)(2r - d)^2 / 12). The exact
    boolean union (manifold3d) keeps the spheres' own facets; the voxel remeshing, its fallback, gets it to
    within a fraction of a voxel."""
    a, b = sphere(20.0, subdivisions=4), sphere(20.0, (20.0, 0.0, 0.0), subdivisions=4)
    both = trimesh.util.concatenate([a, b])
    out = _repair(both, voxel_m=0.0005, smoothing_voxels=0.5)
    r, d = 20.0, 20.0
    union = 2 * 4 / 3 * math.pi * r**3 - math.pi * (4 * r + d) * (2 * r - d) ** 2 / 12
    # the icospheres (5120 faces) hold 0.2 % less than the balls, their lens about as much less
    assert out.mesh.volume == pytest.approx(union * 1e-9, rel=0.004)
    assert out.mesh.is_watertight and any("exact boolean union" in r for r in out.repairs)
    shells = [trimesh.Trimesh(m.vertices * 1e-3, m.faces) for m in (a, b)]
    remeshed, note = voxel_union(shells, "organ", "organ", Options(voxel_m=0.0005, smoothing_voxels=0.5),
                                 budget=20_000, max_cells=10**7)
    # voxels of 0.5 mm: the surface within a fraction of a voxel of the balls' (1.5 % of the volume), less
    # the smoothing's rounding of the crease where the balls meet (a ring of ~0.2 mm^2 cross-section)
    assert remeshed.volume == pytest.approx(union * 1e-9, rel=0.02)
    assert remeshed.is_watertight and "remeshed the union of 2" in note


def test_a_shallow_overlap_between_organs_is_clipped_and_reported(tmp_path) -> None:
    write_surface(tmp_path / "body.stl", sphere(80.0, subdivisions=2))
    write_surface(tmp_path / "a.stl", sphere(20.0, (-19.0, 0.0, 0.0), subdivisions=3))
    write_surface(tmp_path / "b.stl", sphere(20.0, (19.0, 0.0, 0.0), subdivisions=3))  # 2 mm into a
    manifest = {"name": "touching", "units": "mm", "body": {"surface": "body.stl"},
                "organs": {"a": {"file": "a.stl", "tissue": "liver"}, "b": {"file": "b.stl", "tissue": "kidney"}},
                "options": {"overlap_tolerance_m": 0.003}}
    result = build_phantom(manifest, tmp_path)
    report = {o["name"]: o for o in result.report["organs"]}
    assert report["a"]["repairs"] == [] and "gave way to 'a'" in report["b"]["repairs"][0]
    phantom = result.phantom
    assert phantom.parent.tolist() == [-1, 0, 0]
    b = phantom.organs[2].mesh
    assert b.vertices[:, 0].min() > 0.0003 - 1e-6 - 0.001  # b now stops about where a begins (a's facets sag)
    assert b.volume < sphere(20.0, subdivisions=3).volume * 1e-9


def test_the_repaired_edges_handed_to_the_phantoms_checks_are_the_surfaces_own() -> None:
    """A surface turned outward by the repairs keeps edges that describe its turned triangles: each edge
    (a, b), a < b, once, ``face`` holding the half-edge a->b and ``twin`` b->a (read off the triangles here)."""
    inward = trimesh.creation.icosphere(2, radius=0.02)
    inward.invert()
    repaired = repair_surface(inward.vertices, inward.faces, "organs.x", "x", Options(), budget=10**6,
                              max_cells=10**8, check_crossings=False)
    assert any("turned" in r for r in repaired.repairs) and repaired.edges is not None
    faces = np.asarray(repaired.mesh.faces)
    holder = {(int(f[k]), int(f[(k + 1) % 3])): i for i, f in enumerate(faces) for k in range(3)}
    pairs = repaired.edges.edges.tolist()
    assert len(pairs) == len(holder) // 2 and len({tuple(p) for p in pairs}) == len(pairs)
    for (a, b), face, twin in zip(pairs, repaired.edges.face.tolist(), repaired.edges.twin.tolist()):
        assert a < b and holder[(a, b)] == face and holder[(b, a)] == twin
