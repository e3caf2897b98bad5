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
