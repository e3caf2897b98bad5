"""The scene build (raytrace/engine/scene.py): one set of face tables and one pair of Embree
scenes per phantom, queried with a ray mask for the faces a trace keeps.

Oracles: the numpy expressions the compiled face-table pass replaced (written out here, bit for
bit); Embree scenes built of the visible faces alone, as the scene module did before (the same
first hits, exactly: the robust traversal is watertight and the tables identical); brute-force
minimum distances between boxes for the return lengths' bound.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace.body.phantom import Material, Organ, Phantom
from raytrace.body.torso import default_torso
from raytrace.engine.boxgap import least_gap
from raytrace.engine.embree import EmbreeScene
from raytrace.engine.scene import MASK_BITS, TracerScene, scene_for
from raytrace.solver import sbr
from raytrace.solver.media import MediaTable


@pytest.fixture(scope="module")
def torso():
    return default_torso(24)


def test_face_tables_are_the_numpy_expressions_bit_for_bit(torso):
    """Every table but the corner normals (the creases' code computes those) against the numpy
    expressions the compiled pass replaced, exactly: the exact kernels read them."""
    scene = scene_for(torso)
    vertices, faces = np.asarray(torso.vertices, float), np.asarray(torso.faces, np.int64)
    fn = np.asarray(torso.face_normals, float)
    fn = fn / np.linalg.norm(fn, axis=1, keepdims=True)
    corners = scene.corner_normals
    tri = vertices[faces]
    a = tri[:, 0]
    v0, v1 = tri[:, 1] - a, tri[:, 2] - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    frame = np.concatenate([a, v0, v1, np.stack([d00, d01, d11, d00 * d11 - d01 * d01], axis=1),
                            corners.reshape(-1, 9)], axis=1)
    table = np.concatenate([corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=1)
    curvature = np.zeros(len(faces))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        cos = np.clip(np.einsum("ij,ij->i", corners[:, i], corners[:, j]), -1.0, 1.0)
        curvature = np.maximum(curvature, np.arccos(cos) / np.maximum(np.linalg.norm(tri[:, i] - tri[:, j], axis=1),
                                                                       1e-12))
    np.testing.assert_array_equal(scene.face_normals, fn)
    np.testing.assert_array_equal(scene.plane_d, np.einsum("fj,fj->f", fn, vertices[faces[:, 0]]))
    np.testing.assert_array_equal(scene._barycentric_frame, frame)
    np.testing.assert_array_equal(scene.face_normals32, fn.astype(np.float32))
    np.testing.assert_array_equal(scene.corner_table32, table.astype(np.float32))
    np.testing.assert_array_equal(scene.face_curvature32, curvature.astype(np.float32))


def _rays(phantom, count, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = phantom.bounds_m
    origins = lo + (hi - lo) * rng.random((count, 3))
    d = rng.normal(size=(count, 3))
    return origins, d / np.linalg.norm(d, axis=1, keepdims=True)


def _alone(phantom, visible):
    """First hits among the ``visible`` faces from a scene of those faces alone (the old way)."""
    faces = np.flatnonzero(visible)
    vertices = np.asarray(phantom.vertices, float)
    center = scene_for(phantom).center
    alone = EmbreeScene(vertices - center, np.asarray(phantom.faces)[faces])

    def first(o, d):
        prim = alone.intersect(o - center, d).prim
        return np.where(prim >= 0, faces[np.maximum(prim, 0)], -1)

    return first


def test_the_scene_without_transparent_faces_is_a_ray_mask(torso):
    """The torso's cavity wall (muscle on both sides) is left out by the mask of the other organs:
    the same first hits as a scene built of the visible faces alone."""
    media = MediaTable.build(torso, np.array([402e6]))
    visible = ~media.face_transparent
    assert visible.sum() < len(visible)
    scene = scene_for(torso, visible)
    assert scene._own is None and scene.tables is scene_for(torso).tables  # shared, no scenes of its own
    o, d = _rays(torso, 20_000)
    face, _t = scene.first_hit(o, d)
    np.testing.assert_array_equal(face, _alone(torso, visible)(o, d))
    assert not np.any(media.face_transparent[face[face >= 0]])
    # the full scene still hits them
    full, _t = scene_for(torso).first_hit(o, d)
    assert np.any(media.face_transparent[full[full >= 0]])


def test_a_subset_no_mask_expresses_gets_scenes_of_its_own(torso):
    """Half of one organ's faces: no mask bit separates them, so the subset gets its own Embree
    scenes (still over the shared tables), with the same hits as a scene of those faces alone."""
    visible = np.ones(torso.triangle_count, bool)
    skin = np.flatnonzero(torso.face_organ == 0)
    visible[skin[::2]] = False
    scene = TracerScene.build(torso, visible, scene_for(torso).tables)
    assert scene._own is not None
    o, d = _rays(torso, 20_000, seed=1)
    np.testing.assert_array_equal(scene.first_hit(o, d)[0], _alone(torso, visible)(o, d))
    assert scene.shot_tables.handle != scene_for(torso).shot_tables.handle


def _spheres(count):
    """``count`` small spheres side by side in air, every third of another material."""
    organs = []
    for k in range(count):
        mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.01)
        mesh.apply_translation([0.03 * k, 0.0, 0.0])
        organs.append(Organ(f"o{k}", Material(tissue="muscle" if k % 3 else "fat_average_infiltrated"), mesh))
    return Phantom.build("spheres", organs)


def test_more_organs_than_mask_bits_share_bits_by_how_they_are_seen():
    phantom = _spheres(MASK_BITS + 4)
    tables = scene_for(phantom).tables
    assert len(np.unique(tables.organ_mask)) <= 4
    # the subsets a trace asks for are masks: here every organ borders air, all visible
    visible = np.ones(phantom.triangle_count, bool)
    assert TracerScene.build(phantom, visible, tables)._own is None
    # one organ alone among organs sharing its bit is not: its own scenes, the same hits
    visible = phantom.face_organ == 1
    scene = TracerScene.build(phantom, visible, tables)
    assert scene._own is not None
    o, d = _rays(phantom, 5_000, seed=2)
    np.testing.assert_array_equal(scene.first_hit(o, d)[0], _alone(phantom, visible)(o, d))


def _brute_gap(lo_a, hi_a, lo_b, hi_b):
    d = np.maximum(np.maximum(lo_b[None] - hi_a[:, None], lo_a[:, None] - hi_b[None]), 0.0)
    return float(np.sqrt((d * d).sum(axis=2)).min())


def _face_boxes(mesh):
    tri = np.asarray(mesh.triangles)
    return tri.min(axis=1), tri.max(axis=1)


@pytest.mark.parametrize("offset", [0.0005, 0.02, 0.3])
def test_least_gap_on_meshes_is_the_brute_force_minimum(offset):
    """Two nested spheres (a layer of ``offset``) and a sphere beside another: the dual-tree
    search finds the least distance between face boxes of a test of every pair, bit for bit."""
    inner = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    outer = trimesh.creation.icosphere(subdivisions=3, radius=0.1 + offset)
    beside = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    beside.apply_translation([0.15 + offset, 0.0, 0.0])
    for a, b in ((inner, outer), (outer, inner), (inner, beside)):
        boxes = (*_face_boxes(a), *_face_boxes(b))
        assert least_gap(*boxes) == _brute_gap(*boxes)


def test_least_gap_on_scattered_boxes():
    """Boxes of very different sizes scattered at random, some overlapping, sets of 1 to 400."""
    rng = np.random.default_rng(3)
    for n_a, n_b in ((400, 300), (1, 1), (1, 17), (9, 2), (33, 400)):
        for _ in range(5):
            c_a, c_b = rng.random((n_a, 3)), rng.random((n_b, 3)) + 0.5
            s_a, s_b = rng.random((n_a, 3)) ** 4 * 0.2, rng.random((n_b, 3)) ** 4 * 0.2
            boxes = (c_a - s_a, c_a + s_a, c_b - s_b, c_b + s_b)
            assert least_gap(*boxes) == _brute_gap(*boxes)
    assert least_gap(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((1, 3)), np.ones((1, 3))) == np.inf


def test_return_lengths_are_made_once_per_receiver_pattern(torso):
    scene = scene_for(torso)
    media = MediaTable.build(torso, np.array([402e6]))
    zone = sbr.zones(media)
    alpha = np.abs(media.n[0].imag) + 1.0
    need = sbr._interactions_needed(media, np.array([0]))
    first = sbr.return_lengths(scene, media, zone, need, alpha)
    assert sbr.return_lengths(scene, media, zone, need, alpha) is first
    other = sbr.return_lengths(scene, media, zone, sbr._interactions_needed(media, np.array([-1])), alpha)
    assert other is not first
