"""Self-intersection of one organ surface (raytrace.body.selfintersect) and its use in phantom validation.

Oracle for the triangle-triangle predicate: the separating axis theorem, written
here and sharing no code with the implementation (which tests edge crossings with
signed volumes). Two triangles are disjoint iff their projections on some axis
are disjoint, where the candidate axes are the two face normals and the nine
cross products of an edge of one with an edge of the other (for coplanar
triangles: the in-plane normals of their six edges).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace.body.gltf import load_phantom
from raytrace.body.phantom import Material, Organ, Phantom
from raytrace.body.selfintersect import self_intersections, triangles_intersect
from raytrace.errors import PhantomValidationError, field_text
from tests.conftest import glb_bytes


def sat_intersect(a: np.ndarray, b: np.ndarray) -> bool:
    """Oracle: do triangles a, b (3 x 3) overlap with positive depth on every candidate axis?"""
    ea = [a[(k + 1) % 3] - a[k] for k in range(3)]
    eb = [b[(k + 1) % 3] - b[k] for k in range(3)]
    na, nb = np.cross(ea[0], ea[1]), np.cross(eb[0], eb[1])
    axes = [na, nb] + [np.cross(u, v) for u in ea for v in eb]
    if np.linalg.norm(np.cross(na, nb)) < 1e-12 * np.linalg.norm(na) * np.linalg.norm(nb):  # parallel planes
        if abs(na @ (b[0] - a[0])) > 1e-12 * np.linalg.norm(na):
            return False  # distinct parallel planes never meet
        axes = [np.cross(na, e) for e in ea] + [np.cross(nb, e) for e in eb]  # coplanar: in-plane axes
    for axis in axes:
        if np.linalg.norm(axis) < 1e-14:
            continue
        pa, pb = a @ axis, b @ axis
        if pa.max() <= pb.min() or pb.max() <= pa.min():
            return False  # separated (touching counts as disjoint, like the implementation)
    return True


def pulled_sphere(subdivisions: int = 2) -> trimesh.Trimesh:
    """The issue's reproduction: an icosphere with one vertex pulled through the opposite side."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.05)
    vertices = mesh.vertices.copy()
    vertices[0] *= -1.3
    return trimesh.Trimesh(vertices, mesh.faces, process=False)


def test_triangle_predicate_agrees_with_the_separating_axis_oracle() -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(600, 3, 3))
    b = rng.normal(size=(600, 3, 3)) + rng.normal(size=(600, 1, 3)) * 0.3
    got = triangles_intersect(a, b)
    want = np.array([sat_intersect(x, y) for x, y in zip(a, b)])
    # random triangles in general position: no touching cases, both verdicts must agree exactly
    assert 0.2 < want.mean() < 0.8, "the sample must hold both cases"
    np.testing.assert_array_equal(got, want)


def test_coplanar_triangles() -> None:
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    overlapping = base + [0.2, 0.2, 0.0]
    inside = base * 0.2 + [0.1, 0.1, 0.0]
    apart = base + [2.0, 0.0, 0.0]
    a = np.stack([base, base, base])
    b = np.stack([overlapping, inside, apart])
    want = [sat_intersect(x, y) for x, y in zip(a, b)]
    assert want == [True, True, False]
    assert triangles_intersect(a, b).tolist() == want


def test_the_issue_reproduction_passes_every_other_check_but_this_one() -> None:
    mesh = pulled_sphere()
    # watertight, consistently wound, positive volume: the checks that existed before
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    pairs = self_intersections(mesh.vertices, mesh.faces)
    assert len(pairs) > 0
    faces = mesh.faces
    for i, j in pairs:  # every reported pair: no shared vertex, and the oracle agrees they cross
        assert not set(faces[i]) & set(faces[j])
        assert sat_intersect(mesh.vertices[faces[i]], mesh.vertices[faces[j]])
    # and nothing is missed: the oracle over every non-adjacent pair (80 triangles: 3160 pairs)
    mesh = pulled_sphere(subdivisions=1)
    faces = mesh.faces
    pairs = self_intersections(mesh.vertices, faces)
    tri = mesh.vertices[faces]
    expected = {(i, j) for i in range(len(faces)) for j in range(i + 1, len(faces))
                if not set(faces[i]) & set(faces[j]) and sat_intersect(tri[i], tri[j])}
    assert expected and {tuple(p) for p in pairs.tolist()} == expected


@pytest.mark.parametrize("subdivisions", [1, 3, 5])
def test_closed_spheres_have_none(subdivisions: int) -> None:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    assert len(self_intersections(mesh.vertices, mesh.faces)) == 0


def test_mixed_triangle_sizes_are_all_checked() -> None:
    # a large box face crossed by a finely meshed sphere: the coarse triangles land on a
    # coarser grid level than the fine ones, and the crossing pairs span both levels
    box = trimesh.creation.box(extents=[0.2, 0.2, 0.2])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    ball.apply_translation([0.1, 0.0, 0.0])  # straddles the box's +x face
    both = trimesh.util.concatenate([box, ball])
    pairs = self_intersections(both.vertices, both.faces)
    n_box = len(box.faces)
    assert len(pairs) > 0 and all(i < n_box <= j for i, j in pairs)
    assert {int(i) for i, _ in pairs} == {int(k) for k in np.flatnonzero(box.face_normals[:, 0] > 0.99)}


def test_phantom_build_and_upload_refuse_a_self_intersecting_organ() -> None:
    mesh = pulled_sphere()
    with pytest.raises(PhantomValidationError) as info:
        Phantom.build("p", [Organ("body", Material(tissue="muscle"), mesh)])
    assert info.value.field == "organs.body" and "intersects itself" in info.value.reason
    with pytest.raises(PhantomValidationError) as info:
        load_phantom(glb_bytes({"body": mesh}), {"name": "p", "units": "m", "organs": {"body": {"tissue": "muscle"}}})
    assert field_text(info.value.field) == "manifest.organs.body" and "intersects itself" in info.value.reason


def test_builtin_torso_organs_do_not_intersect_themselves() -> None:
    from raytrace.body.torso import default_torso

    torso = default_torso()  # Phantom.build ran the check on every organ; count them again here
    for organ in torso.organs:
        assert len(self_intersections(organ.mesh.vertices, organ.mesh.faces)) == 0, organ.name
