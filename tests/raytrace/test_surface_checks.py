"""The phantom's surface checks: edges of closed surfaces (raytrace.body.topology), segments through the
Embree binding (raytrace.engine.segments, raytrace.body.rays) and the crossing test built on them
(raytrace.body.selfintersect.edge_crossings, Phantom.build).

Oracles: trimesh's own watertightness and winding checks and its unique edges (code the implementation does
not use on the fast path); closed forms for ray distances; and for crossings the exact pairwise
triangle-triangle test of the same module (a uniform-grid broad phase over every pair of triangles, sharing
no code with the Embree segments)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace.body.phantom import Material, Organ, Phantom, check_surfaces, surface_crossings
from raytrace.body.rays import RayScene
from raytrace.body.selfintersect import self_intersections
from raytrace.body.topology import closed_edges
from raytrace.errors import PhantomValidationError


def _broken_meshes() -> dict[str, trimesh.Trimesh]:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    flipped = sphere.faces.copy()
    flipped[7] = flipped[7][::-1]
    doubled = np.vstack([sphere.faces, sphere.faces[:1]])
    return {
        "closed": sphere,
        "two shells": trimesh.util.concatenate([sphere, trimesh.creation.box().apply_translation([3, 0, 0])]),
        "open": trimesh.Trimesh(sphere.vertices, sphere.faces[1:], process=False),
        "one face turned": trimesh.Trimesh(sphere.vertices, flipped, process=False),
        "a face twice": trimesh.Trimesh(sphere.vertices, doubled, process=False),
    }


@pytest.mark.parametrize("name", list(_broken_meshes()))
def test_closed_edges_agree_with_trimesh(name: str) -> None:
    mesh = _broken_meshes()[name]
    edges = closed_edges(mesh.faces)
    closed = mesh.is_watertight and mesh.is_winding_consistent
    assert (edges is not None) == closed
    if edges is None:
        return
    # every edge once, as trimesh's unique edges, and each between the two triangles that hold it
    assert {tuple(e) for e in edges.edges.tolist()} == {tuple(sorted(e)) for e in mesh.edges_unique.tolist()}
    for (a, b), f, g in zip(edges.edges.tolist(), edges.face.tolist(), edges.twin.tolist()):
        fa, fg = mesh.faces[f].tolist(), mesh.faces[g].tolist()
        assert fa[(fa.index(a) + 1) % 3] == b and fg[(fg.index(b) + 1) % 3] == a


def _square(z: float) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], float), np.array([[0, 1, 2], [0, 2, 3]]))


def test_segments_end_at_their_far_distance() -> None:
    """A plane at z = 0.5 above rays from z = 0: a segment of length 0.4 misses it, one of 0.6 hits it at 0.5
    (closed form; Embree's float32 answer within 4 ulps)."""
    vertices, faces = _square(0.5)
    scene = RayScene(vertices, faces)
    origins = np.array([[0.2, 0.3, 0.0], [0.2, 0.3, 0.0], [-0.4, 0.1, 0.0]])
    up = np.tile([0.0, 0.0, 1.0], (3, 1))
    face, t = scene.first_hits(origins, up, np.array([0.4, 0.6, np.inf]))
    assert face[0] == -1 and t[0] == np.inf
    assert face[1] in (0, 1) and face[2] in (0, 1)
    assert t[1] == pytest.approx(0.5, abs=1e-15) and t[2] == pytest.approx(0.5, abs=1e-15)


def test_distances_to_a_hit_are_float64() -> None:
    """A point 1 nm under a plane at z = 0.3: its distance along +z is 1e-9 m to float64 rounding (float32
    coordinates near 0.3 are 3e-8 apart: the plane's own distance, recomputed, is what makes it exact)."""
    vertices, faces = _square(0.3)
    scene = RayScene(vertices, faces)
    _, t = scene.first_hits(np.array([[0.1, 0.2, 0.3 - 1e-9]]), np.array([[0.0, 0.0, 1.0]]))
    assert t[0] == pytest.approx(1e-9, rel=1e-6)


def _organs(*meshes: trimesh.Trimesh) -> list[Organ]:
    return [Organ(f"o{k}", Material(tissue="muscle"), m) for k, m in enumerate(meshes)]


def _crossing_oracle(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    both = trimesh.util.concatenate([a, b])
    pairs = self_intersections(both.vertices, both.faces)
    n = len(a.faces)
    return bool(np.any((pairs[:, 0] < n) != (pairs[:, 1] < n))) if len(pairs) else False


@pytest.mark.parametrize("depth_m", [-2e-4, -2e-5, 2e-5, 2e-4, 3e-3])
def test_a_shallow_crossing_through_a_finely_faceted_surface_is_found(depth_m: float) -> None:
    """A small ball pushed ``depth_m`` into a UV sphere of 192 x 96 facets (whose edges' own rays would graze
    their neighbours in float32), or held that far outside it: refused exactly when the pairwise test finds
    a crossing (the oracle); the micrometre offset of the segments is far below these depths. (The facets of
    both lie inside their spheres by under 1 um: the ball crosses from a depth of a few um.)"""
    big = trimesh.creation.uv_sphere(radius=0.1, count=[96, 192])
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.004)
    direction = np.array([0.3, -0.5, 0.81])
    direction /= np.linalg.norm(direction)
    ball.apply_translation(direction * (0.1 + 0.004 - depth_m))
    crosses = _crossing_oracle(big, ball)
    assert crosses == (depth_m > 0)
    if crosses:
        with pytest.raises(PhantomValidationError, match="intersects organ"):
            Phantom.build("p", _organs(big, ball))
    else:
        assert Phantom.build("p", _organs(big, ball)).parent.tolist() == [-1, -1]


def test_self_crossings_and_crossing_pairs_are_named() -> None:
    """surface_crossings answers every crossing pair, a surface crossing itself as (i, i): a sphere pulled
    through itself, two spheres crossing, a third apart."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    pulled = sphere.vertices.copy()
    pulled[0] *= -1.3
    pulled_sphere = trimesh.Trimesh(pulled, sphere.faces, process=False)
    a = sphere.copy().apply_translation([0.3, 0, 0])
    b = sphere.copy().apply_translation([0.36, 0, 0])
    c = sphere.copy().apply_translation([0.0, 0.4, 0])
    checked = surface_crossings(check_surfaces([pulled_sphere, a, b, c], ["p", "a", "b", "c"]))
    assert checked.crossings == {(0, 0), (1, 2)}


def test_a_checked_set_hands_its_scene_to_the_phantom() -> None:
    """Phantom.build takes the checks and the Embree scene of surface_crossings for the same meshes (no second
    scene), and makes its own when a mesh differs; the phantom's lookups are the same either way."""
    outer = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    checked = surface_crossings(check_surfaces([outer, inner], ["outer", "inner"]))
    phantom = Phantom.build("p", _organs(outer, inner), checked=checked)
    assert phantom.intersector is checked.scene and phantom.parent.tolist() == [-1, 0]
    other = Phantom.build("p", _organs(outer, inner.copy()), checked=checked)
    assert other.intersector is not checked.scene and other.parent.tolist() == [-1, 0]
    points = np.array([[0.0, 0.0, 0.0], [0.06, 0.0, 0.0], [0.2, 0.0, 0.0]])
    assert phantom.medium_index(points).tolist() == other.medium_index(points).tolist() == [1, 0, -1]
    np.testing.assert_allclose(phantom.volumes_m3, [outer.volume, inner.volume], rtol=1e-12)
    np.testing.assert_allclose(phantom.areas_m2, [outer.area, inner.area], rtol=1e-12)


def test_edges_left_after_the_recasts_are_tested_exactly(monkeypatch) -> None:
    """With no re-casts allowed, every edge whose segment met a triangle goes to the exact fallback (its
    triangles near it, by the pairwise predicate): the same verdicts as the oracle."""
    import raytrace.body.selfintersect as si

    monkeypatch.setattr(si, "_ROUNDS", 0)
    big = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    for depth_m, crosses in ((3e-3, True), (-3e-3, False)):
        ball = trimesh.creation.icosphere(subdivisions=2, radius=0.01).apply_translation([0.11 - depth_m, 0, 0])
        assert _crossing_oracle(big, ball) == crosses
        checked = surface_crossings(check_surfaces([big, ball], ["big", "ball"]))
        assert checked.crossings == ({(0, 1)} if crosses else set())
