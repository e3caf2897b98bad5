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


def _corner_normals_numpy(vertices, faces, face_normals, crease_deg):
    """The numpy expressions the compiled corner normals replaced (edge keys sorted, scipy's
    connected components, sums by np.bincount): the oracle, bit for bit."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, np.int64)
    nf = len(faces)
    fn = np.asarray(face_normals, float)
    crease = np.broadcast_to(np.asarray(crease_deg, float), (nf,))
    v = vertices[faces]
    weights = np.empty((nf, 3, 3))
    for i in range(3):
        e1 = v[:, (i + 1) % 3] - v[:, i]
        e2 = v[:, (i + 2) % 3] - v[:, i]
        weights[:, i] = np.cross(e1, e2) / (np.einsum("ij,ij->i", e1, e1) * np.einsum("ij,ij->i", e2, e2))[:, None]
    hf = np.repeat(np.arange(nf), 3)
    hc = np.tile(np.arange(3), nf)
    a, b = faces[hf, hc], faces[hf, (hc + 1) % 3]
    key = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    k = key[order]
    same = np.all(k[1:] == k[:-1], axis=1)
    starts = np.flatnonzero(np.concatenate([[True], ~same]))
    counts = np.diff(np.concatenate([starts, [len(k)]]))
    runs = np.repeat(counts, counts)
    pair = same & (runs[:-1] == 2)
    h1, h2 = order[:-1][pair], order[1:][pair]
    f1, f2 = hf[h1], hf[h2]
    limit = np.cos(np.radians(np.minimum(crease[f1], crease[f2])))
    smooth = np.einsum("ij,ij->i", fn[f1], fn[f2]) >= limit
    h1, h2, f1, f2 = h1[smooth], h2[smooth], f1[smooth], f2[smooth]
    c1a, c1b = hc[h1], (hc[h1] + 1) % 3
    va, vb = faces[f1, c1a], faces[f1, c1b]
    c2a = np.argmax(faces[f2] == va[:, None], axis=1)
    c2b = np.argmax(faces[f2] == vb[:, None], axis=1)
    node1 = np.concatenate([3 * f1 + c1a, 3 * f1 + c1b])
    node2 = np.concatenate([3 * f2 + c2a, 3 * f2 + c2b])
    graph = coo_matrix((np.ones(len(node1), np.int8), (node1, node2)), shape=(3 * nf, 3 * nf))
    _, label = connected_components(graph, directed=False)
    acc = np.zeros((label.max() + 1, 3))
    flat = weights.reshape(-1, 3)
    for j in range(3):
        acc[:, j] = np.bincount(label, weights=flat[:, j], minlength=len(acc))
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    out = (acc / np.where(norm > 0.0, norm, 1.0))[label].reshape(nf, 3, 3)
    alone = np.bincount(label, minlength=len(acc))[label].reshape(nf, 3) == 1
    degenerate = (norm[label, 0] <= 0.0).reshape(nf, 3)
    return np.where((alone | degenerate)[..., None], fn[:, None, :], out)


def _unit_normals(mesh):
    fn = np.asarray(mesh.face_normals, float)
    return fn / np.linalg.norm(fn, axis=1, keepdims=True)


@pytest.mark.parametrize("case", ["torso", "box", "cylinder", "per-face creases", "non-manifold"])
def test_corner_normals_are_the_numpy_expressions_bit_for_bit(torso, case):
    """The compiled corner normals against the numpy expressions they replaced, exactly, on the
    torso (one crease angle per organ), a box (every edge a crease), a coarse cylinder (smooth
    sides, creased rims), random crease angles per face (the smaller of two faces' applies) and a
    mesh with an edge shared by three faces (joins nothing)."""
    from raytrace.engine.scene import CREASE_ANGLE_DEG, corner_normals

    rng = np.random.default_rng(3)
    if case == "torso":
        vertices, faces = np.asarray(torso.vertices, float), np.asarray(torso.faces, np.int64)
        fn = np.asarray(torso.face_normals, float)
        fn = fn / np.linalg.norm(fn, axis=1, keepdims=True)
        crease = np.array([CREASE_ANGLE_DEG if o.crease_angle_deg is None else o.crease_angle_deg
                           for o in torso.organs])[np.asarray(torso.face_organ, np.int64)]
    else:
        if case == "box":
            mesh = trimesh.creation.box(extents=[0.3, 0.1, 0.05])
        elif case == "non-manifold":
            mesh = trimesh.util.concatenate([trimesh.creation.box(), trimesh.creation.box()])
            mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # merged: edges of 4 faces
            extra = mesh.faces[:1][:, [1, 0, 2]].copy()
            extra[0, 2] = len(mesh.vertices)
            mesh = trimesh.Trimesh(np.vstack([mesh.vertices, [[0.3, 0.7, 0.1]]]), np.vstack([mesh.faces, extra]),
                                   process=False)
        else:
            mesh = trimesh.creation.cylinder(radius=0.2, height=0.5, sections=24)
        vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
        fn = _unit_normals(mesh)
        crease = rng.uniform(10.0, 100.0, len(faces)) if case == "per-face creases" else CREASE_ANGLE_DEG
    np.testing.assert_array_equal(corner_normals(vertices, faces, fn, crease),
                                  _corner_normals_numpy(vertices, faces, fn, crease))
    # exact zeros' signs too (assert_array_equal takes -0.0 == 0.0)
    assert corner_normals(vertices, faces, fn, crease).tobytes() == \
        _corner_normals_numpy(vertices, faces, fn, crease).tobytes()


def test_a_pickled_embree_scene_is_built_again_where_it_is_loaded(tmp_path):
    """An Embree scene pickled (a phantom's scene of every face travels with the phantom to a
    sweep's worker or a bench's child) casts in the process that loads it: the same first hits
    as the scene it was pickled from. Run in a fresh interpreter: a scene that pickled its
    handle (a pointer into the first process) crashed there."""
    import pickle
    import subprocess
    import sys

    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    faces = np.asarray(box.faces)
    geometry = (np.array([0, 6]), np.array([6, 12]), np.array([1, 2], np.uint32))
    from raytrace.engine.embree import Geometry

    scene = EmbreeScene(np.asarray(box.vertices), faces, geometry=Geometry(*geometry))
    rng = np.random.default_rng(5)
    d = rng.normal(size=(200, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    o = np.zeros((200, 3), np.float32)
    expected = [np.asarray(a) for a in scene.intersect(o, d, 2)]
    (tmp_path / "scene.pkl").write_bytes(pickle.dumps((scene, o, d, expected)))
    code = ("import pickle, sys, numpy as np\n"
            f"scene, o, d, expected = pickle.load(open({str(tmp_path / 'scene.pkl')!r}, 'rb'))\n"
            "got = scene.intersect(o, d, 2)\n"
            "assert all(np.array_equal(np.asarray(a), b) for a, b in zip(got, expected)), 'hits differ'\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
