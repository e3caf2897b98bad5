"""The default torso phantom: validity, anatomy, sites, resolution scaling.

Oracles are independent of ``raytrace.body.torso``: the expected media, parents
and layer thicknesses are written out here from docs/tissues.md, and geometric
checks use trimesh's own proximity / ray queries on the organ meshes rather
than the phantom's medium lookup where possible.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from raytrace.body.phantom import Phantom
from raytrace.body.torso import (
    DEFAULT_RESOLUTION,
    MIN_RESOLUTION,
    SENSOR_DEPTH_M,
    build_torso,
    default_torso,
    expected_site_media,
)

EXPECTED_TISSUE = {
    "skin": "skin_dry",
    "subcutaneous_fat": "fat_average_infiltrated",
    "muscle_wall": "muscle",
    "visceral_cavity": "muscle",
    "liver": "liver",
    "stomach": "stomach",
    "small_intestine": "small_intestine",
    "ascending_colon": "colon",
    "transverse_colon": "colon",
    "descending_colon": "colon",
    "left_kidney": "kidney",
    "right_kidney": "kidney",
    "spine": "bone_cortical",
    "left_lung": "lung_inflated",
    "right_lung": "lung_inflated",
}
EXPECTED_PARENT = {
    "skin": "air",
    "subcutaneous_fat": "skin",
    "muscle_wall": "subcutaneous_fat",
    "visceral_cavity": "muscle_wall",
    **{name: "visceral_cavity" for name in list(EXPECTED_TISSUE)[4:]},
}
EXPECTED_SITE_MEDIUM = {
    "stomach": "stomach",
    "small_intestine_1": "small_intestine",
    "small_intestine_2": "small_intestine",
    "ascending_colon": "ascending_colon",
    "transverse_colon": "transverse_colon",
    "descending_colon": "descending_colon",
    **{
        f"belt_{d}": "skin"
        for d in ("anterior", "anterior_left", "left", "posterior_left", "posterior", "posterior_right",
                  "anterior_right")
    },
    **{f"upper_{d}": "skin" for d in ("anterior_left", "left", "posterior", "right", "anterior_right")},
}


@pytest.fixture(scope="module")
def torso() -> Phantom:
    return default_torso()


def test_organs_tissues_and_containment_tree(torso: Phantom) -> None:
    assert {o.name: o.material.tissue for o in torso.organs} == EXPECTED_TISSUE
    parents = {o.name: torso.medium_name(int(p)) for o, p in zip(torso.organs, torso.parent)}
    assert parents == EXPECTED_PARENT


def test_every_organ_closed_and_outward(torso: Phantom) -> None:
    # Re-checked here with trimesh directly (Phantom.build checks it too).
    for organ in torso.organs:
        mesh = organ.mesh
        assert mesh.is_watertight, organ.name
        assert mesh.is_winding_consistent, organ.name
        assert mesh.volume > 0, organ.name


def _crossing_edges(target: trimesh.Trimesh, other: trimesh.Trimesh) -> int:
    """Number of edges of ``other`` that cross the surface of ``target``
    (two triangle surfaces intersect iff an edge of one crosses the other)."""
    edges = np.asarray(other.edges_unique)
    v = np.asarray(other.vertices)
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    lo, hi = target.bounds
    keep = np.all((np.maximum(a, b) >= lo) & (np.minimum(a, b) <= hi), axis=1)
    a, b = a[keep], b[keep]
    if not len(a):
        return 0
    length = np.linalg.norm(b - a, axis=1)
    direction = (b - a) / length[:, None]
    _, ray, loc = RayMeshIntersector(target).intersects_id(
        a, direction, multiple_hits=False, return_locations=True
    )
    return int(np.sum(np.linalg.norm(loc - a[ray], axis=1) <= length[ray]))


def test_no_two_organ_surfaces_intersect(torso: Phantom) -> None:
    # Independent of Phantom's vertex-containment test: an edge-crossing test
    # catches surfaces that cross without any vertex of one inside the other.
    for i, target in enumerate(torso.organs):
        for j, other in enumerate(torso.organs):
            if i != j:
                assert _crossing_edges(target.mesh, other.mesh) == 0, (target.name, other.name)


def test_sites_are_in_their_media(torso: Phantom) -> None:
    assert {n: s.medium for n, s in torso.sites.items()} == EXPECTED_SITE_MEDIUM
    assert expected_site_media() == EXPECTED_SITE_MEDIUM
    kinds = [s.kind for s in torso.sites.values()]
    assert kinds.count("capsule") >= 4 and kinds.count("sensor") >= 8
    for site in torso.sites.values():
        assert site.kind == ("sensor" if site.medium == "skin" else "capsule")


def test_capsule_sites_are_well_inside_their_organs(torso: Phantom) -> None:
    # "strictly inside, not near surfaces": >= 10 mm from the organ's surface,
    # measured with trimesh's closest-point query (independent of the lookup).
    for site in torso.sites.values():
        if site.kind != "capsule":
            continue
        organ = torso.organs[torso.organ_index(site.medium)]
        assert organ.mesh.contains(site.position_m[None, :])[0], site.name
        _, distance, _ = trimesh.proximity.closest_point(organ.mesh, site.position_m[None, :])
        assert distance[0] >= 0.010, (site.name, distance[0])


def test_sensor_sites_are_contact_sensors_mid_skin(torso: Phantom) -> None:
    # Contact sensors: inside the 2 mm skin layer, 1 mm below its outer
    # surface. Oracle: trimesh's own point-in-mesh and closest-point queries on
    # the organ meshes (not the phantom's Embree medium lookup).
    skin = torso.organs[torso.organ_index("skin")].mesh
    fat = torso.organs[torso.organ_index("subcutaneous_fat")].mesh
    sensors = [s for s in torso.sites.values() if s.kind == "sensor"]
    points = np.array([s.position_m for s in sensors])
    assert skin.contains(points).all()
    assert not fat.contains(points).any()
    _, to_outer, _ = trimesh.proximity.closest_point(skin, points)
    _, to_inner, _ = trimesh.proximity.closest_point(fat, points)
    # 1 mm along the analytic normal; the facet normal differs from it by at
    # most half a ring step (pi/48), so the closest-point distance is within
    # 1 mm * (1 - cos(pi/48)) ~ 2e-6 m of 1 mm, plus float rounding.
    np.testing.assert_allclose(to_outer, SENSOR_DEPTH_M, atol=1e-5)
    assert np.all(to_inner >= 0.0009), to_inner  # mid-skin: ~1 mm from the fat too
    belt = np.array([s.position_m for n, s in torso.sites.items() if n.startswith("belt_")])
    assert len(belt) == 7
    np.testing.assert_allclose(belt[:, 2], 0.05)  # one belt, 50 mm above the small-intestine mid-plane
    # the public placement helper puts a sensor exactly where the sites are
    from raytrace.body.torso import contact_point

    np.testing.assert_array_equal(contact_point(torso, 0.0, 0.05), torso.sites["belt_anterior"].position_m)
    np.testing.assert_array_equal(contact_point(torso, 285, 0.125), torso.sites["upper_right"].position_m)
    with pytest.raises(ValueError, match="straight side"):
        contact_point(torso, 0.0, 0.40)  # above the trunk's straight side (rounded top rim)


def test_anterior_layers_have_the_cited_thicknesses(torso: Phantom) -> None:
    # Cast a ray from the trunk axis (inside the small intestine) towards the
    # anterior (-y) and read where it crosses each organ surface (trimesh
    # multi-hit on the combined mesh). Expected from docs/tissues.md: outer skin at
    # the ANSUR II male waist depth/2 = 119 mm, skin 2 mm, fat 17.5 mm
    # (CT L3-L4), rectus 10 mm. A vertex lies exactly on this ray (theta =
    # 270 deg, z = 0 ring), so the tolerance is float rounding only.
    origin = np.array([[0.0, 0.0, 0.0]])
    direction = np.array([[0.0, -1.0, 0.0]])
    tri, _, loc = torso.intersector.intersects_id(
        origin, direction, multiple_hits=True, return_locations=True
    )
    crossings = {torso.organs[torso.face_organ[t]].name: -p[1] for t, p in zip(tri, loc)}
    assert crossings["skin"] == pytest.approx(0.119, abs=1e-9)
    assert crossings["skin"] - crossings["subcutaneous_fat"] == pytest.approx(0.002, abs=1e-9)
    assert crossings["subcutaneous_fat"] - crossings["muscle_wall"] == pytest.approx(0.0175, abs=1e-9)
    assert crossings["muscle_wall"] - crossings["visceral_cavity"] == pytest.approx(0.010, abs=1e-9)
    # The small intestine's anterior boundary: MIRD y = -48.6 mm; here -48 mm.
    assert crossings["small_intestine"] == pytest.approx(0.048, abs=1e-9)
    media = torso.medium_names(torso.medium_index(np.array([[0.0, -y, 0.0] for y in
                                                            (0.118, 0.110, 0.095, 0.070, 0.020)])))
    assert media == ["skin", "subcutaneous_fat", "muscle_wall", "visceral_cavity", "small_intestine"]


def test_api_example_positions_are_meaningful(torso: Phantom) -> None:
    # positions the API's earliest examples used: transmitter (0.02, -0.03, 0) in the small
    # intestine, receiver (0, -0.125, 0) in air in front of the abdomen.
    media = torso.medium_names(torso.medium_index(np.array([[0.02, -0.03, 0.0], [0.0, -0.125, 0.0]])))
    assert media == ["small_intestine", "air"]


def test_frame_is_anatomical(torso: Phantom) -> None:
    # x = subject's left: the liver lies on the right (-x), the stomach and the
    # descending colon on the left (+x); -y anterior: the spine is posterior.
    centre = {o.name: o.mesh.bounds.mean(axis=0) for o in torso.organs}
    assert centre["liver"][0] < 0 < centre["stomach"][0]
    assert centre["ascending_colon"][0] < 0 < centre["descending_colon"][0]
    assert centre["right_kidney"][0] < 0 < centre["left_kidney"][0]
    assert centre["spine"][1] > 0 > centre["small_intestine"][1]
    assert centre["left_lung"][2] > centre["liver"][2] > centre["small_intestine"][2]


def test_default_is_cached_and_in_the_benchmark_size(torso: Phantom) -> None:
    assert default_torso() is torso
    assert default_torso(DEFAULT_RESOLUTION) is torso
    assert 2e4 <= torso.triangle_count <= 6e4
    assert torso.metadata["resolution"] == DEFAULT_RESOLUTION


@pytest.mark.parametrize("resolution", [MIN_RESOLUTION, 32, 96])
def test_other_resolutions_validate(resolution: int) -> None:
    # The coarsest allowed mesh is where thin layers are closest to crossing.
    phantom = build_torso(resolution)
    assert {n: s.medium for n, s in phantom.sites.items()} == EXPECTED_SITE_MEDIUM
    # 15 organs x 2 x resolution x (resolution // 2 - 1) triangles.
    assert phantom.triangle_count == 15 * 2 * resolution * (resolution // 2 - 1)


def test_triangle_count_spans_the_benchmark_range() -> None:
    # Without building the big ones: the count formula checked above at three
    # resolutions covers ~1e4 at the minimum and >= 1e6 at the maximum.
    from raytrace.body.torso import MAX_RESOLUTION

    count = lambda r: 15 * 2 * r * (r // 2 - 1)  # noqa: E731
    assert count(MIN_RESOLUTION) <= 1e4
    assert count(MAX_RESOLUTION) >= 1e6


@pytest.mark.parametrize("bad", [0, MIN_RESOLUTION - 1, 10_000])
def test_bad_resolution_rejected(bad: int) -> None:
    with pytest.raises(ValueError, match="resolution"):
        build_torso(bad)
    with pytest.raises(TypeError):
        build_torso(48.0)  # type: ignore[arg-type]
