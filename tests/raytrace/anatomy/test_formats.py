"""Every input format builds the same phantom: surfaces the test writes (meshio, trimesh, its own legacy
POLYDATA and XML PolyData writers: no library the project may use writes those) read back by the pipeline,
volumes against the divergence-theorem volume of the written mesh and the sphere's closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from raytrace.body.anatomy import build_phantom
from tests.raytrace.anatomy.files import polyhedron_volume, sphere, write_surface

FORMATS = ["organ.vtk", "organ_ug.vtk", "organ.vtu", "organ_v22.vtu", "organ_ascii.vtp", "organ_binary.vtp",
           "organ_appended.vtp", "organ_zlib.vtp", "organ_vtk9.vtp", "organ.stl", "organ.ply", "organ.obj",
           "organ.off", "organ.glb", "organ.gltf", "organ_embed.gltf"]


@pytest.mark.parametrize("filename", FORMATS)
def test_every_format_builds_with_the_written_volume(tmp_path, filename) -> None:
    body, organ = sphere(80.0), sphere(30.0, (10.0, 0.0, 0.0))
    write_surface(tmp_path / "body.stl", body)
    write_surface(tmp_path / filename, organ)
    manifest = {"name": "spheres", "units": "mm",
                "body": {"surface": "body.stl", "fill": "muscle"},
                "organs": {"organ": {"files": [filename], "tissue": "liver"}}}
    result = build_phantom(manifest, tmp_path)
    phantom = result.phantom
    assert [o.name for o in phantom.organs] == ["body", "organ"]
    assert phantom.parent.tolist() == [-1, 0]
    got = phantom.organs[1].mesh.volume
    # Oracle 1: the written mesh's own volume (divergence theorem in the test), mm^3 -> m^3; the
    # pipeline may only merge duplicate vertices (STL stores three per triangle), so it is exact up to the
    # files' float precision (STL, glTF and binary VTP store float32: 1e-6 relative).
    want = polyhedron_volume(organ.vertices, organ.faces) * 1e-9
    assert got == pytest.approx(want, rel=2e-6)
    # Oracle 2: the closed form; a 1280-face icosphere inscribed in the sphere holds 1.3 % less.
    assert got == pytest.approx(4.0 / 3.0 * math.pi * 0.030**3, rel=0.015)
    np.testing.assert_allclose(phantom.organs[1].mesh.bounds.mean(axis=0), [0.010, 0.0, 0.0], atol=1e-4)
    row = next(o for o in result.report["organs"] if o["name"] == "organ")
    assert row["triangles"] == len(organ.faces) and row["volume_ml"] == pytest.approx(got * 1e6)


def test_several_files_per_organ_are_joined_and_welded(tmp_path) -> None:
    """Two halves of a sphere in two formats, sharing their cut edge: one closed organ, the sphere's volume."""
    whole = sphere(30.0)
    up = whole.triangles_center[:, 2] > 0
    top, bottom = whole.submesh([np.flatnonzero(up)])[0], whole.submesh([np.flatnonzero(~up)])[0]
    write_surface(tmp_path / "body.stl", sphere(80.0))
    write_surface(tmp_path / "top.ply", top)
    write_surface(tmp_path / "bottom.obj", bottom)
    manifest = {"name": "halves", "units": "mm", "body": {"surface": "body.stl"},
                "organs": {"organ": {"files": ["top.ply", "bottom.obj"], "tissue": "liver"}}}
    result = build_phantom(manifest, tmp_path)
    mesh = result.phantom.organs[1].mesh
    assert mesh.is_watertight and len(mesh.faces) == len(whole.faces)
    assert mesh.volume == pytest.approx(polyhedron_volume(whole.vertices, whole.faces) * 1e-9, rel=1e-6)
    assert any("welded" in r for r in result.report["organs"][1]["repairs"])


def test_transform_maps_axes_and_origin(tmp_path) -> None:
    """axes [-x, z, y] with an origin: each vertex p becomes (-(px - ox), pz - oz, py - oy) * scale, and the
    mirror keeps the surface outward (positive volume)."""
    organ = sphere(20.0, (40.0, 5.0, -7.0), subdivisions=2)
    write_surface(tmp_path / "body.off", sphere(90.0, (30.0, 0.0, 0.0)))
    write_surface(tmp_path / "organ.off", organ)
    manifest = {"name": "moved", "scale": 0.001, "transform": {"axes": ["-x", "z", "y"], "origin": [30.0, 0.0, 0.0]},
                "body": {"surface": "body.off"}, "organs": {"organ": {"file": "organ.off", "tissue": "kidney"}}}
    phantom = build_phantom(manifest, tmp_path).phantom
    centre = phantom.organs[1].mesh.bounds.mean(axis=0)
    np.testing.assert_allclose(centre, [-0.010, -0.007, 0.005], atol=2e-4)
    assert phantom.organs[1].mesh.volume > 0
