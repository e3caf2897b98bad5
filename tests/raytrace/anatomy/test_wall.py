"""The generated body wall on a sphere (closed forms: concentric spheres), giving way to an organ near the
skin, and sensor belts 1 mm under the surface; tracts from JSON and CSV with landmarks."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from raytrace.body.anatomy import build_phantom
from tests.raytrace.anatomy.files import sphere, write_surface

R_MM = 100.0
LAYERS = [{"tissue": "skin_dry", "thickness_m": 0.002}, {"tissue": "fat_average_infiltrated", "thickness_m": 0.010},
          {"tissue": "muscle", "thickness_m": 0.008}]
COARSE = {"wall_grid_m": 0.004, "max_triangles_per_surface": 6000, "decimation_error_m": 0.0008,
          "min_layer_m": 0.0015}


def test_layers_are_concentric_spheres_of_the_stated_depths(tmp_path) -> None:
    body = sphere(R_MM, subdivisions=4)
    write_surface(tmp_path / "body.ply", body)
    write_surface(tmp_path / "organ.ply", sphere(20.0, (0.0, 0.0, -20.0), subdivisions=3))
    manifest = {"name": "layered sphere", "units": "mm",
                "body": {"surface": "body.ply", "layers": LAYERS, "fill": "muscle"},
                "organs": {"organ": {"file": "organ.ply", "tissue": "liver"}},
                "sensors": {"belts": [{"height_m": 0.100, "count": 6}, {"height_m": 0.05, "count": 4, "name": "low"}]},
                "options": COARSE}
    result = build_phantom(manifest, tmp_path)
    phantom = result.phantom
    names = [o.name for o in phantom.organs]
    assert names == ["skin", "subcutaneous_fat", "muscle_wall", "body_fill", "organ"]
    parents = [phantom.medium_name(int(p)) for p in phantom.parent]
    assert parents == ["air", "skin", "subcutaneous_fat", "muscle_wall", "body_fill"]
    # Closed form: the solid under depth D of a sphere of radius R is the sphere of radius R - D. The body
    # mesh is a 5120-face icosphere (0.3 % below the sphere's volume); each boundary is off its level by
    # the marching cubes' interpolation on 4 mm cells and the decimation (at most 0.8 mm, the stated bound):
    # a radius within 0.9 mm, i.e. 3 dR / R of the volume.
    for name, depth in (("subcutaneous_fat", 2.0), ("muscle_wall", 12.0), ("body_fill", 20.0)):
        r = R_MM - depth
        got = phantom.organs[names.index(name)].mesh.volume
        assert got == pytest.approx(4 / 3 * math.pi * (r * 1e-3) ** 3, rel=3 * 0.9 / r + 0.003), name
        radii = np.linalg.norm(phantom.organs[names.index(name)].mesh.vertices, axis=1) * 1e3
        assert np.all(np.abs(radii - r) < 1.0), (name, radii.min(), radii.max())
    # Sensors: on the belts' rings 1 mm under the faceted surface, in the skin.
    belt = {n: s for n, s in phantom.sites.items() if n.startswith("belt1_")}
    assert sorted(belt) == ["belt1_000", "belt1_060", "belt1_120", "belt1_180", "belt1_240", "belt1_300"]
    for site in phantom.sites.values():
        assert site.medium == "skin"
        assert R_MM - 1.4 < np.linalg.norm(site.position_m) * 1e3 < R_MM - 0.9  # facets sag < 0.4 mm here
    # 0.1 m above the bottom, then 1 mm in along the facet's normal, which tilts by a few degrees at most
    np.testing.assert_allclose(belt["belt1_000"].position_m[2], 0.0, atol=1e-4)
    assert belt["belt1_000"].position_m[1] < 0 and abs(belt["belt1_000"].position_m[0]) < 1e-9  # anterior = -y
    assert belt["belt1_060"].position_m[0] > 0  # towards the subject's left (+x)
    layers = {row["name"]: row for row in result.report["layers"]}
    assert layers["muscle_wall"]["thickness_mm"] == pytest.approx(8.0)
    assert layers["body_fill"]["decimation_error_mm"] <= 0.8


def test_wall_gives_way_to_an_organ_near_the_skin(tmp_path) -> None:
    """An organ 4 mm under the skin: the fat and muscle boundaries bend around it, keeping the layers
    nested and at least min_layer_m apart; the organ keeps its margin, clipped only within them of the skin."""
    write_surface(tmp_path / "body.stl", sphere(R_MM, subdivisions=4))
    write_surface(tmp_path / "organ.stl", sphere(25.0, (0.0, -(R_MM - 29.0), 0.0), subdivisions=3))
    manifest = {"name": "near skin", "units": "mm",
                "body": {"surface": "body.stl", "layers": LAYERS},
                "organs": {"organ": {"file": "organ.stl", "tissue": "colon"}}, "options": COARSE}
    result = build_phantom(manifest, tmp_path)
    phantom = result.phantom
    assert phantom.medium_name(int(phantom.parent[-1])) == "body_fill"
    fill = phantom.organs[3].mesh
    assert np.min(np.linalg.norm(fill.vertices, axis=1)) * 1e3 < R_MM - 20.0  # the fill under most of the wall
    assert np.max(np.linalg.norm(fill.vertices, axis=1)) * 1e3 > R_MM - 10.0  # ... and pushed out over the organ
    layers = {row["name"]: row for row in result.report["layers"]}
    assert layers["body_fill"]["gives_way_percent"] > 0
    assert layers["subcutaneous_fat"]["thinnest_depth_mm"] >= 1.5 - 0.8  # min_layer_m less the decimation bound
    organ = result.report["organs"][-1]
    assert organ["parent"] == "body_fill"
    assert organ["volume_ml"] == pytest.approx(4 / 3 * math.pi * 25.0**3 * 1e-3, rel=0.02)  # not clipped


def test_tracts_from_json_and_csv_with_landmarks_and_direction(tmp_path) -> None:
    write_surface(tmp_path / "body.off", sphere(R_MM, subdivisions=3))
    tube_points = np.stack([np.zeros(41), np.zeros(41), np.linspace(-60.0, 60.0, 41)], axis=1)
    import trimesh

    tube = trimesh.creation.cylinder(radius=10.0, height=140.0, sections=32)
    write_surface(tmp_path / "tube.obj", tube)
    (tmp_path / "path.json").write_text(json.dumps({"points": tube_points.tolist(), "tangents": []}))
    (tmp_path / "path.csv").write_text("x,y,z\n" + "\n".join(",".join(f"{v:g}" for v in p) for p in tube_points))
    manifest = {"name": "tract", "units": "mm", "body": {"surface": "body.off"},
                "organs": {"tube": {"file": "tube.obj", "tissue": "small_intestine"}},
                "tracts": {"down": {"file": "path.json", "organ": "tube", "reverse": True, "landmarks": {"top": 40,
                                                                                                        "mid": 20}},
                           "up": {"file": "path.csv", "organ": "tube", "landmarks": {"bottom": 0}}}}
    result = build_phantom(manifest, tmp_path)
    phantom = result.phantom
    down, up = phantom.centrelines["down"], phantom.centrelines["up"]
    assert down.length_m == pytest.approx(0.120) and up.length_m == pytest.approx(0.120)
    np.testing.assert_allclose(down.point_m(0.0), [0, 0, 0.060], atol=1e-12)  # reversed: starts at the last point
    assert phantom.sites["down_top"].kind == "capsule" and phantom.sites["down_top"].medium == "tube"
    np.testing.assert_allclose(phantom.sites["down_mid"].position_m, [0, 0, 0], atol=1e-12)
    tracts = {t["name"]: t for t in result.report["tracts"]}
    assert tracts["down"]["landmarks_s_mm"] == pytest.approx({"top": 0.0, "mid": 60.0})
    assert tracts["up"]["landmarks_s_mm"] == pytest.approx({"bottom": 0.0})
