"""An organ exported as segments cut at planes, each segment closed by its own caps (as the shared CT
abdomen's SegmentedSurfaces): the caps two segments share are walls inside the organ; the pipeline removes
both copies and the segments join into the one closed surface they were cut from."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace.body.anatomy import build_phantom
from tests.raytrace.anatomy.files import polyhedron_volume, sphere, write_surface


def test_capped_segments_join_into_the_organ(tmp_path) -> None:
    below, above = (trimesh.creation.cylinder(radius=15.0, height=45.0, sections=32) for _ in range(2))
    below.apply_translation([0, 0, -22.5])
    above.apply_translation([0, 0, 22.5])
    assert below.is_watertight and above.is_watertight  # each segment closed by its own cap at z = 0
    write_surface(tmp_path / "body.stl", sphere(80.0, subdivisions=3))
    write_surface(tmp_path / "below.obj", below)
    write_surface(tmp_path / "above.off", above)
    manifest = {"name": "segments", "units": "mm", "body": {"surface": "body.stl"},
                "organs": {"tube": {"files": ["below.obj", "above.off"], "tissue": "colon"}}}
    result = build_phantom(manifest, tmp_path)
    mesh = result.phantom.organs[1].mesh
    repairs = " ".join(result.report["organs"][1]["repairs"])
    # the shared cap appears in both files with opposite windings: both copies removed, no voxel remeshing
    assert "opposite windings" in repairs and "remeshed" not in repairs
    # closed form of the tube (a 32-sided prism): the two segments' volumes add up exactly
    prism = 16 * np.sin(2 * np.pi / 32) * 15.0**2 * 90.0 * 1e-9
    assert mesh.volume == pytest.approx(prism, rel=1e-9)
    assert mesh.volume == pytest.approx((polyhedron_volume(below.vertices, below.faces)
                                         + polyhedron_volume(above.vertices, above.faces)) * 1e-9, rel=1e-9)


def _segment(z0: float, z1: float, n: int, radius: float, cap0, cap1) -> trimesh.Trimesh:
    """A closed n-sided prism between z0 and z1; each cap is ("apex", height) -- a fan from a centre raised
    by ``height`` along the outward axis -- or ("strip",) -- a fan from the ring's first vertex (flat)."""
    angle = 2 * np.pi * np.arange(n) / n
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    vertices = [np.column_stack([ring, np.full(n, z0)]), np.column_stack([ring, np.full(n, z1)])]
    faces = []
    for k in range(n):
        a, b = k, (k + 1) % n
        faces += [[a, b, n + b], [a, n + b, n + a]]
    for cap, base, z, outward in ((cap0, 0, z0, -1.0), (cap1, n, z1, 1.0)):
        if cap[0] == "apex":
            centre = sum(len(v) for v in vertices)
            vertices.append(np.array([[0.0, 0.0, z + outward * cap[1]]]))
            faces += [[base + k, base + (k + 1) % n, centre] for k in range(n)]
        else:
            faces += [[base, base + k, base + k + 1] for k in range(1, n - 1)]
    mesh = trimesh.Trimesh(np.vstack(vertices), np.array(faces), process=False)
    trimesh.repair.fix_normals(mesh)
    return mesh


def test_segments_whose_shared_cap_is_triangulated_differently_join_exactly(tmp_path) -> None:
    """The shared CT's small-intestine segments meet at caps that span the same cut loop but are triangulated
    differently (and not in one plane): no triangle is given twice, the joined surface has edges of four
    triangles and caps crossing each other. The organ is then the exact boolean union of its files (each
    closed), not a voxel remesh. Here: below's top cap is a cone raised 2 mm into above, above's bottom cap a
    flat fan from one ring vertex; the cone lies inside above, so the union is the two flat prisms."""
    n, r = 32, 15.0
    below = _segment(-45.0, 0.0, n, r, ("apex", 0.0), ("apex", 2.0))
    above = _segment(0.0, 45.0, n, r, ("strip",), ("apex", 0.0))
    for piece in (below, above):
        assert piece.is_watertight and piece.is_winding_consistent and piece.volume > 0
    write_surface(tmp_path / "body.stl", sphere(80.0, subdivisions=3))
    write_surface(tmp_path / "below.vtk", below)
    write_surface(tmp_path / "above.ply", above)
    manifest = {"name": "segments", "units": "mm", "body": {"surface": "body.stl"},
                "organs": {"tube": {"files": ["below.vtk", "above.ply"], "tissue": "small_intestine"}}}
    result = build_phantom(manifest, tmp_path)
    mesh = result.phantom.organs[1].mesh
    repairs = " ".join(result.report["organs"][1]["repairs"])
    assert "exact boolean union" in repairs and "remeshed" not in repairs
    assert mesh.is_watertight and mesh.is_winding_consistent
    # closed form: two n-sided prisms of height 45 mm; manifold3d works in float32 (relative 6e-8 per
    # coordinate), so the volume agrees to ~1e-6: 1e-5 allowed
    prism = n / 2 * np.sin(2 * np.pi / n) * r**2 * 90.0 * 1e-9
    assert mesh.volume == pytest.approx(prism, rel=1e-5)
    # and no cap is left inside: the surface is only the tube's side and its two end caps
    inner = np.abs(mesh.vertices[:, 2]) < 45e-3 - 1e-6
    assert np.allclose(np.hypot(mesh.vertices[inner, 0], mesh.vertices[inner, 1]), r * 1e-3, rtol=1e-5)
