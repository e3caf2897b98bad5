"""Tracts cut to a range of their file's points, joined into the capsule's journey (the ``gi_tract``
centreline), and mid-lines grazing their lumen's wall moved inside it (docs/phantoms.md, "Tracts, sensors and
sites"). Oracles: straight lines and prisms whose lengths and distances are written in the tests."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from raytrace.body.anatomy import build_phantom
from raytrace.body.centreline import GI_TRACT
from raytrace.errors import PhantomValidationError, field_text
from tests.raytrace.anatomy.files import sphere, write_surface

N_SIDES = 32
R_MM = 10.0


def _tube(z0: float, z1: float) -> trimesh.Trimesh:
    tube = trimesh.creation.cylinder(radius=R_MM, height=z1 - z0, sections=N_SIDES)
    tube.apply_translation([0.0, 0.0, (z0 + z1) / 2])
    return tube


def _files(tmp_path, points) -> None:
    write_surface(tmp_path / "body.stl", sphere(120.0, subdivisions=3))
    write_surface(tmp_path / "lower.ply", _tube(-60.0, 0.0))
    write_surface(tmp_path / "upper.ply", _tube(0.0, 60.0))
    (tmp_path / "path.json").write_text(json.dumps({"points": np.asarray(points).tolist()}))


def _manifest(**extra) -> dict:
    return {"name": "journey", "units": "mm", "body": {"surface": "body.stl"},
            "organs": {"upper": {"file": "upper.ply", "tissue": "stomach"},
                       "lower": {"file": "lower.ply", "tissue": "small_intestine"}}, **extra}


def test_tracts_cut_by_range_join_into_the_journey(tmp_path) -> None:
    # one mid-line at z = -49, -47, ..., 49 mm (50 points, k = 0..49), read top down (reverse) as a capsule
    # goes: through 'upper' (z > 0), across the shared cut (the later organ gives way by 0.3 mm there),
    # into 'lower'; no point lies within the 0.5 mm tract clearance of a cap (the nearest are 1 mm off z = 0)
    z = np.linspace(-49.0, 49.0, 50)
    _files(tmp_path, np.stack([np.zeros(50), np.zeros(50), z], axis=1))
    tracts = {"up": {"file": "path.json", "organ": "upper", "reverse": True, "range": [23, 49],
                     "landmarks": {"top": 49, "mid": 37, "below": 24}},
              "down": {"file": "path.json", "organ": "lower", "reverse": True, "range": [0, 26],
                       "landmarks": {"cut": 24, "end": 0}}}
    result = build_phantom(_manifest(tracts=tracts, journey=["up", "down"]), tmp_path)
    phantom = result.phantom
    line = phantom.centrelines[GI_TRACT]
    assert "up" not in phantom.centrelines and "down" not in phantom.centrelines  # the journey replaces them
    assert [p.organ for p in line.pieces] == ["upper", "lower"]
    # 'up' keeps z = 49 .. 1 (k = 49..25; k = 24, 23 lie in 'lower'), 'down' keeps z = -1 .. -49 (k = 24..0;
    # k = 26, 25 lie in 'upper'): 48 + 48 mm, the jump from z = 1 to z = -1 not counted
    assert line.length_m == pytest.approx(0.096, abs=1e-12)
    assert line.junctions_s_m == pytest.approx((0.048,), abs=1e-12)
    np.testing.assert_allclose(line.point_m(0.0), [0, 0, 0.049], atol=1e-12)
    np.testing.assert_allclose(line.point_m(line.junctions_s_m[0]), [0, 0, -0.001], atol=1e-12)  # the next piece
    sites = phantom.metadata["journey"]["sites_s_m"]
    assert sites == pytest.approx({"up_top": 0.0, "up_mid": 0.024, "down_cut": 0.048, "down_end": 0.096})
    assert phantom.sites["up_mid"].medium == "upper" and phantom.sites["down_end"].medium == "lower"
    assert "up_below" not in phantom.sites  # a landmark in a trimmed end gets no site
    report = result.report
    assert report["journey"]["length_m"] == pytest.approx(0.096, abs=1e-12)
    notes = {t["name"]: " ".join(t["notes"]) for t in report["tracts"]}
    assert "trimmed 2 end point(s)" in notes["up"] and "trimmed 2 end point(s)" in notes["down"]
    assert "landmark below (point 24) lies in a trimmed end" in notes["up"] and "moved" not in notes["up"]


def test_a_mid_line_grazing_its_wall_moves_inside_it(tmp_path) -> None:
    """A point 0.2 mm outside the tube's flat face is moved to 0.5 mm inside it along the face's normal: to the
    apothem r cos(pi / n) less 0.5 mm from the axis. Outside by more than the clearance it is refused."""
    apothem = R_MM * math.cos(math.pi / N_SIDES)
    # trimesh's cylinder puts its ring vertices at angles 2 pi k / n: face k's normal points at pi (2k + 1) / n
    phi = math.pi / N_SIDES
    direction = np.array([math.cos(phi), math.sin(phi), 0.0])
    z = np.linspace(-50.0, -10.0, 21)
    points = np.stack([np.zeros(21), np.zeros(21), z], axis=1)
    points[10] = (apothem + 0.2) * direction + [0.0, 0.0, z[10]]
    _files(tmp_path, points)
    tracts = {"t": {"file": "path.json", "organ": "lower", "landmarks": {"graze": 10}}}
    result = build_phantom(_manifest(tracts=tracts), tmp_path)
    moved = result.phantom.sites["t_graze"].position_m * 1e3
    np.testing.assert_allclose(moved, (apothem - 0.5) * direction + [0.0, 0.0, z[10]], atol=1e-6)
    note = " ".join(result.report["tracts"][0]["notes"])
    assert "moved 1 point(s) by up to 0.70 mm" in note
    points[10] = (apothem + 2.0) * direction + [0.0, 0.0, z[10]]
    (tmp_path / "path.json").write_text(json.dumps({"points": points.tolist()}))
    with pytest.raises(PhantomValidationError) as info:
        build_phantom(_manifest(tracts=tracts), tmp_path)
    assert field_text(info.value.field) == "manifest.tracts.t" and "point 10 " in str(info.value)


@pytest.mark.parametrize("change, field, words", [
    ({"range": [30, 10]}, "manifest.tracts.t.range", "must come after"),
    ({"range": [0]}, "manifest.tracts.t.range", "[first, last]"),
    ({"range": [0, 10], "landmarks": {"far": 15}}, "manifest.tracts.t.landmarks.far", "outside the tract's range"),
    ({"range": [0, 99]}, "manifest.tracts.t.range", "runs past the file's 21 points"),
])
def test_bad_ranges_are_refused_naming_the_entry(tmp_path, change, field, words) -> None:
    _files(tmp_path, np.stack([np.zeros(21), np.zeros(21), np.linspace(-50.0, -10.0, 21)], axis=1))
    tracts = {"t": {"file": "path.json", "organ": "lower", **change}}
    with pytest.raises(PhantomValidationError) as info:
        build_phantom(_manifest(tracts=tracts), tmp_path)
    assert field_text(info.value.field) == field and words in str(info.value)


@pytest.mark.parametrize("journey, tracts, field", [
    (["t", "nope"], {"t": {}}, "manifest.journey.1"),
    (["t", "t"], {"t": {}}, "manifest.journey"),
    ("t", {"t": {}}, "manifest.journey"),
    (["gi_tract"], {"gi_tract": {}}, "manifest.tracts.gi_tract"),
])
def test_bad_journeys_are_refused_naming_the_entry(tmp_path, journey, tracts, field) -> None:
    _files(tmp_path, np.stack([np.zeros(21), np.zeros(21), np.linspace(-50.0, -10.0, 21)], axis=1))
    tracts = {name: {"file": "path.json", "organ": "lower"} for name in tracts}
    with pytest.raises(PhantomValidationError) as info:
        build_phantom(_manifest(tracts=tracts, journey=journey), tmp_path)
    assert field_text(info.value.field) == field
