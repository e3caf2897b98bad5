"""The centreline type (raytrace.body.centreline) and the torso's GI tract.

Oracles: hand-made polylines whose lengths, points and projections are written here in
closed form, a brute-force projection (the nearest of 200 000 points sampled on the line,
computed in the test), and the phantom's own medium lookup for "inside the lumen".
"""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.body.centreline import GI_TRACT, Centreline, smooth_polyline
from raytrace.body.torso import build_torso, default_torso, gi_tract
from raytrace.errors import InputError, PhantomValidationError

# An L in the plane z = 0 (lengths 3 and 4), then a jump to a second piece of length 2.
L_PIECES = [("a", [[0, 0, 0], [3, 0, 0], [3, 4, 0]]), ("b", [[10, 0, 0], [10, 0, 2]])]


def test_arc_length_points_tangents_and_organs_in_closed_form():
    line = Centreline(L_PIECES)
    assert line.length_m == 9.0
    assert line.junctions_s_m == (7.0,)
    np.testing.assert_array_equal(line.point_m(1.5), [1.5, 0, 0])
    np.testing.assert_array_equal(line.point_m(5.0), [3, 2, 0])
    # right-continuous at a vertex and at the junction; the end belongs to the last segment
    np.testing.assert_array_equal(line.tangent(3.0), [0, 1, 0])
    np.testing.assert_array_equal(line.point_m(7.0), [10, 0, 0])
    assert line.organ_at(7.0) == "b" and line.organ_at(6.999) == "a"
    np.testing.assert_array_equal(line.point_m(9.0), [10, 0, 2])
    np.testing.assert_array_equal(line.tangent(9.0), [0, 0, 1])
    # vectorised: the shape of s is kept
    pts = line.point_m(np.array([[0.0, 8.0]]))
    assert pts.shape == (1, 2, 3)
    np.testing.assert_array_equal(pts[0, 1], [10, 0, 1])
    assert list(line.organ_at([1.0, 8.0])) == ["a", "b"]
    np.testing.assert_allclose(line.sample_s(2.0), [0, 2, 4, 6, 8])
    np.testing.assert_allclose(line.sample_s(4.5), [0, 4.5, 9.0])


def test_projection_in_closed_form_and_against_brute_force():
    line = Centreline(L_PIECES)
    # closed form: foot of the perpendicular on the nearest segment
    assert line.project([1.0, -2.0, 0.0]) == 1.0
    assert line.distance_m([1.0, -2.0, 0.0]) == 2.0
    assert line.project([5.0, 3.0, 1.0]) == pytest.approx(6.0)  # onto (3, 3, 0): s = 3 + 3
    assert line.project([10.0, 1.0, 1.5]) == pytest.approx(8.5)
    assert line.project(line.point_m(4.25)) == pytest.approx(4.25)
    # brute force on random points near the line: the nearest of dense samples (spacing 4.5e-5)
    rng = np.random.default_rng(3)
    points = rng.uniform([-1, -2, -1], [11, 5, 3], size=(200, 3))
    s_dense = np.linspace(0, line.length_m, 200_001)
    dense = line.point_m(s_dense)
    for p, s in zip(points, line.project(points)):
        d = np.linalg.norm(dense - p, axis=1)
        # distances agree to the sampling (spacing 4.5e-5: the error of a chord sample is <= 2.3e-5)
        assert np.linalg.norm(line.point_m(s) - p) == pytest.approx(d.min(), abs=3e-5)


@pytest.mark.parametrize("pieces,field", [
    ([], "pieces"),
    ([("a", [[0, 0, 0]])], "pieces[0].points_m"),
    ([("a", [[0, 0, 0], [0, 0, 0]])], "pieces[0].points_m"),
    ([("a", [[0, 0, 0], [1, 0, float("nan")]])], "pieces[0].points_m"),
    ([("a", [[0, 0], [1, 0]])], "pieces[0].points_m"),
    ([("", [[0, 0, 0], [1, 0, 0]])], "pieces[0].organ"),
])
def test_invalid_pieces_name_the_field(pieces, field):
    with pytest.raises(InputError) as info:
        Centreline(pieces)
    assert info.value.field == field


def test_out_of_range_arc_length_is_refused():
    line = Centreline(L_PIECES)
    for bad in (-0.1, 9.1, float("nan")):
        with pytest.raises(InputError) as info:
            line.point_m(bad)
        assert info.value.field == "s_m"


def test_json_round_trip_and_errors():
    line = Centreline(L_PIECES)
    again = Centreline.from_dict(line.to_dict())
    assert again.length_m == line.length_m
    np.testing.assert_array_equal(again.point_m([0.5, 7.5]), line.point_m([0.5, 7.5]))
    mm = Centreline.from_dict({"pieces": [{"organ": "a", "points": [[0, 0, 0], [1000, 0, 0]]}]},
                              scale=1e-3, points_key="points")
    assert mm.length_m == 1.0
    with pytest.raises(InputError) as info:
        Centreline.from_dict({"pieces": [{"organ": "a", "points_m": [[0, 0, 0]]}]}, field="x")
    assert info.value.field == "x.pieces[0].points_m"
    with pytest.raises(InputError) as info:
        Centreline.from_dict({"pieces": [{"organ": "a", "points_m": [[0, 0, 0], [1, 0, 0]], "w": 1}]}, field="x")
    assert info.value.field == "x.pieces[0].w"


def test_smooth_polyline_passes_through_its_control_points():
    control = np.array([[0, 0, 0], [0.01, 0.02, 0], [0.03, 0.0, 0.01], [0.05, 0.01, 0.0]])
    dense = smooth_polyline(control, 1e-3)
    for c in control:
        assert np.min(np.linalg.norm(dense - c, axis=1)) < 1e-15
    steps = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    assert steps.max() < 1.6e-3  # about step_m: a span's chord over ceil(span / step) pieces, plus its curvature


# ----------------------------------------------------------------- the torso's GI tract
def test_torso_has_its_gi_tract_in_anatomical_order():
    line = default_torso().centrelines[GI_TRACT]
    assert [p.organ for p in line.pieces] == ["stomach", "small_intestine", "ascending_colon",
                                               "transverse_colon", "descending_colon"]
    assert 0.5 < line.length_m < 0.8
    # moving along s never goes back: organ order along s is the piece order
    s = line.sample_s(1e-3)
    organs = line.organ_at(s)
    changes = [organs[0]] + [o for prev, o in zip(organs[:-1], organs[1:]) if o != prev]
    assert changes == [p.organ for p in line.pieces]


@pytest.mark.parametrize("resolution", [24, 48, 96])
def test_gi_tract_stays_inside_its_lumens_with_a_margin(resolution):
    """Every point (every 1 mm and every vertex) lies in its piece's organ (medium_index), and
    so do the points 3 mm away along +-x, +-y, +-z: the line keeps >= 3 mm from the walls at
    the coarsest and finer meshes (facets are inscribed, so coarser meshes are tighter)."""
    phantom = build_torso(resolution) if resolution != 48 else default_torso()
    line = gi_tract()
    line.check_inside(phantom, step_m=1e-3)
    s = line.sample_s(1e-3)
    names = [o.name for o in phantom.organs]
    want = np.array([names.index(o) for o in line.organ_at(s)])
    for offset in np.vstack([np.eye(3), -np.eye(3)]) * 3e-3:
        media = phantom.medium_index(line.point_m(s) + offset)
        assert np.array_equal(media, want), (offset, s[media != want][:3])


def test_capsule_sites_lie_on_the_gi_tract_in_their_organ():
    phantom = default_torso()
    line = phantom.centrelines[GI_TRACT]
    capsules = {n: s for n, s in phantom.sites.items() if s.kind == "capsule"}
    assert len(capsules) == 6
    order = []
    for name, site in capsules.items():
        assert line.distance_m(site.position_m) < 1e-9, name
        s = line.project(site.position_m)
        assert line.organ_at(s) == site.medium
        order.append((s, name))
    assert [n for _, n in sorted(order)] == ["stomach", "small_intestine_1", "small_intestine_2",
                                             "ascending_colon", "transverse_colon", "descending_colon"]


def test_check_inside_names_a_piece_that_leaves_its_organ():
    phantom = default_torso()
    bad = Centreline([("stomach", [[0.064, -0.034, 0.155], [0.064, -0.034, 0.30]])])  # out through the top
    with pytest.raises(PhantomValidationError) as info:
        bad.check_inside(phantom, field="centrelines.x")
    assert info.value.field == "centrelines.x.pieces[0]"
    wrong = Centreline([("liver", [[0.064, -0.034, 0.155], [0.064, -0.034, 0.16]])])
    with pytest.raises(PhantomValidationError):
        wrong.check_inside(phantom)


# ----------------------------------------------------------------- uploads
def _box_upload(centrelines):
    from raytrace.body import gltf
    from tests.conftest import glb_bytes, nested_phantom_meshes, phantom_manifest

    manifest = phantom_manifest(units="mm", centrelines=centrelines)
    meshes = nested_phantom_meshes()
    for mesh in meshes.values():
        mesh.apply_scale(1000.0)  # the manifest says mm
    manifest["sites"] = {}
    return gltf, glb_bytes(meshes), manifest


def test_upload_manifest_declares_a_centreline_in_its_units():
    # body: 200 mm muscle box; organ: 40 mm sphere at the origin
    line = {"pieces": [{"organ": "organ", "points": [[-20, 0, 0], [20, 0, 0]]},
                       {"organ": "body", "points": [[0, 60, 0], [0, 90, 0]]}]}
    gltf, glb, manifest = _box_upload({"gi_tract": line})
    phantom = gltf.load_phantom(glb, manifest)
    loaded = phantom.centrelines["gi_tract"]
    assert loaded.length_m == pytest.approx(0.070)
    np.testing.assert_allclose(loaded.point_m(0.045), [0.0, 0.065, 0.0], atol=1e-15)
    # exported (metres) and re-loaded: the same line
    again = gltf.load_phantom(gltf.export_glb(phantom), gltf.export_manifest(phantom))
    np.testing.assert_allclose(again.centrelines["gi_tract"].point_m([0.01, 0.05]), loaded.point_m([0.01, 0.05]),
                               atol=1e-6)  # float32 mesh round trip moves nothing of the line; 1e-6 is the mm->m scale


@pytest.mark.parametrize("line,field", [
    ({"pieces": [{"organ": "organ", "points": [[-20, 0, 0], [60, 0, 0]]}]}, "pieces[0]"),
    ({"pieces": [{"organ": "liver", "points": [[0, 0, 0], [1, 0, 0]]}]}, "pieces[0].organ"),
    ({"pieces": [{"organ": "organ", "points": [[0, 0, 0]]}]}, "pieces[0].points"),
    ({"pieces": []}, "pieces"),
    ({"stops": []}, "stops"),
])
def test_upload_with_a_bad_centreline_is_refused_naming_it(line, field):
    gltf, glb, manifest = _box_upload({"gi_tract": line})
    with pytest.raises(PhantomValidationError) as info:
        gltf.load_phantom(glb, manifest)
    assert info.value.field == f"manifest.centrelines.gi_tract.{field}"
