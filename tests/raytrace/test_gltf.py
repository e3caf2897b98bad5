"""Phantom upload (.glb + manifest) validation, and the export round trip.

Uploads in these tests are written by trimesh's own glTF exporter (not by
``raytrace.body.gltf``), and exports are read back by trimesh's loader, so the
decoder and the encoder are each checked against an independent
implementation. Every rejection must name the organ / field and the defect.
"""

from __future__ import annotations

import copy
import io
import json
import struct

import numpy as np
import pytest
import trimesh

from raytrace.body.gltf import export_glb, export_manifest, load_phantom
from raytrace.body.library import builtin_phantoms
from raytrace.errors import InputError, PhantomValidationError, UnknownTissueError, field_text


def sphere(center, radius, subdivisions=2) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return mesh


def glb_of(meshes: dict[str, trimesh.Trimesh], transforms: dict | None = None) -> bytes:
    """A .glb written by trimesh: one node per mesh, named after it."""
    scene = trimesh.Scene()
    for name, mesh in meshes.items():
        scene.add_geometry(mesh, node_name=name, geom_name=name,
                           transform=(transforms or {}).get(name))
    return scene.export(file_type="glb")


def two_organs() -> tuple[bytes, dict]:
    glb = glb_of({"body": sphere([0, 0, 0], 0.10), "organ": sphere([0.02, 0, 0], 0.03)})
    manifest = {
        "name": "two organs",
        "units": "m",
        "organs": {"body": {"tissue": "muscle"},
                   "organ": {"relative_permittivity": 50.0, "conductivity_s_per_m": 0.5}},
        "sites": {"inside": {"kind": "capsule", "position_m": [0.02, 0.0, 0.0]}, "outside": [0.0, -0.2, 0.0]},
    }
    return glb, manifest


def split(glb: bytes) -> tuple[dict, bytes]:
    json_len = struct.unpack_from("<I", glb, 12)[0]
    document = json.loads(glb[20:20 + json_len])
    return document, glb[20 + json_len + 8:]


def join(document: dict, binary: bytes) -> bytes:
    js = json.dumps(document).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\x00" * (-len(binary) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js
            + struct.pack("<II", len(binary), 0x004E4942) + binary)


def rejected(glb: bytes, manifest: dict, field: str, *words: str, error=PhantomValidationError, **kw):
    with pytest.raises(error) as info:
        load_phantom(glb, manifest, **kw)
    assert info.value.field is not None and field_text(info.value.field).startswith(field), info.value.field
    message = str(info.value).lower()
    for word in words:
        assert word.lower() in message, (word, message)
    assert isinstance(info.value, InputError)
    return info.value


# ------------------------------------------------------------------ accepted
def test_valid_upload_builds_with_materials_and_sites() -> None:
    glb, manifest = two_organs()
    original = copy.deepcopy(manifest)
    phantom = load_phantom(glb, manifest)
    assert manifest == original  # input untouched
    assert [o.name for o in phantom.organs] == ["body", "organ"]
    assert phantom.organs[0].material.tissue == "muscle"
    assert phantom.organs[1].material.relative_permittivity == 50.0
    assert phantom.organs[1].material.conductivity_s_per_m == 0.5
    assert phantom.medium_name(int(phantom.parent[1])) == "body"
    # The kind as stated; a bare-list site in air is a sensor.
    assert (phantom.sites["inside"].kind, phantom.sites["inside"].medium) == ("capsule", "organ")
    assert (phantom.sites["outside"].kind, phantom.sites["outside"].medium) == ("sensor", "air")


def test_node_transforms_match_trimesh_loader() -> None:
    # Oracle: trimesh's own glTF loader and scene graph applied to the same
    # file, with a rotation + non-uniform scale + translation on one node.
    angle = 0.3
    transform = trimesh.transformations.rotation_matrix(angle, [0.2, 0.5, 1.0])
    transform = transform @ np.diag([1.0, 0.7, 1.2, 1.0])
    transform[:3, 3] = [0.01, -0.02, 0.005]
    glb = glb_of({"body": sphere([0, 0, 0], 0.10), "organ": sphere([0, 0, 0], 0.03)},
                 transforms={"organ": transform})
    manifest = {"name": "t", "units": "m",
                "organs": {"body": {"tissue": "muscle"}, "organ": {"tissue": "liver"}}}
    phantom = load_phantom(glb, manifest)
    scene = trimesh.load(io.BytesIO(glb), file_type="glb", force="scene")
    matrix, geometry = scene.graph["organ"]
    expected = trimesh.transform_points(scene.geometry[geometry].vertices, matrix)
    got = phantom.organs[1].mesh.vertices
    # Same vertex set (order may differ after merging); float32 storage.
    ours = np.unique(np.round(got, 6), axis=0)
    theirs = np.unique(np.round(expected, 6), axis=0)
    assert ours.shape == theirs.shape
    np.testing.assert_allclose(ours, theirs, atol=2e-6)
    # Volume scales by det(transform) = 0.7 * 1.2 (rotation and translation
    # preserve it); float32 storage limits the agreement to ~1e-6.
    assert phantom.organs[1].mesh.volume == pytest.approx(
        sphere([0, 0, 0], 0.03).volume * 0.7 * 1.2, rel=1e-5)


def test_millimetre_units_are_applied() -> None:
    glb = glb_of({"body": sphere([0, 0, 0], 100.0), "organ": sphere([20, 0, 0], 30.0)})
    manifest = {"name": "mm", "units": "mm",
                "organs": {"body": {"tissue": "muscle"}, "organ": {"tissue": "liver"}},
                "sites": {"a": [0.0, -150.0, 0.0],  # manifest units (mm)
                          "b": {"position_m": [0.0, -0.2, 0.0]},  # metres, always
                          "c": {"kind": "sensor", "position_m": [-0.05, 0.0, 0.0]}}}
    phantom = load_phantom(glb, manifest)
    np.testing.assert_allclose(phantom.bounds_m, [[-0.1, -0.1, -0.1], [0.1, 0.1, 0.1]], atol=1e-9)
    np.testing.assert_allclose(phantom.sites["a"].position_m, [0.0, -0.15, 0.0])
    assert (phantom.sites["a"].kind, phantom.sites["a"].medium) == ("sensor", "air")
    assert (phantom.sites["b"].kind, phantom.sites["b"].medium) == ("sensor", "air")
    assert (phantom.sites["c"].kind, phantom.sites["c"].medium) == ("sensor", "body")


def test_split_vertices_are_merged() -> None:
    # Exporters write per-face vertices (flat normals/UVs): still watertight after merging.
    mesh = sphere([0, 0, 0], 0.1)
    unmerged = trimesh.Trimesh(mesh.vertices[mesh.faces].reshape(-1, 3),
                               np.arange(len(mesh.faces) * 3).reshape(-1, 3), process=False)
    glb = glb_of({"body": unmerged})
    phantom = load_phantom(glb, {"name": "s", "units": "m", "organs": {"body": {"tissue": "fat_not_infiltrated"}}})
    assert phantom.organs[0].mesh.is_watertight
    assert len(phantom.organs[0].mesh.faces) == len(mesh.faces)


@pytest.mark.parametrize("phantom_id", sorted(builtin_phantoms()))
def test_export_round_trip(phantom_id: str) -> None:
    phantom = builtin_phantoms()[phantom_id]()
    glb, manifest = export_glb(phantom), export_manifest(phantom)
    json.dumps(manifest)  # plain JSON
    again = load_phantom(glb, manifest)
    assert [o.name for o in again.organs] == [o.name for o in phantom.organs]
    assert [len(o.mesh.faces) for o in again.organs] == [len(o.mesh.faces) for o in phantom.organs]
    assert [o.material for o in again.organs] == [o.material for o in phantom.organs]
    np.testing.assert_array_equal(again.parent, phantom.parent)
    assert {n: (s.kind, s.medium) for n, s in again.sites.items()} == \
        {n: (s.kind, s.medium) for n, s in phantom.sites.items()}
    for n, s in phantom.sites.items():
        np.testing.assert_array_equal(again.sites[n].position_m, s.position_m)
    # float32 positions in the file: relative error <= 2^-24 of the scene scale, compared triangle corner by
    # triangle corner (the reader merges identical positions, so two vertices of a surface at one point, where
    # a clipped organ pinches, come back as one: the same triangles, one vertex fewer).
    scale = np.abs(phantom.vertices).max()
    for o, r in zip(phantom.organs, again.organs):
        assert np.abs(r.mesh.vertices[r.mesh.faces] - o.mesh.vertices[o.mesh.faces]).max() <= scale * 2.0**-23
    # An independent reader sees one organ-named node per organ.
    scene = trimesh.load(io.BytesIO(glb), file_type="glb", force="scene")
    assert sorted(scene.graph.nodes_geometry) == sorted(o.name for o in phantom.organs)
    total = sum(len(scene.geometry[scene.graph[n][1]].faces) for n in scene.graph.nodes_geometry)
    assert total == phantom.triangle_count


# ------------------------------------------------------------------ rejected
def test_truncated_and_garbage_files_rejected() -> None:
    glb, manifest = two_organs()
    rejected(glb[:-10], manifest, "mesh", "truncated")
    rejected(glb[:15], manifest, "mesh", "header")
    rejected(b"PK\x03\x04" + glb[4:], manifest, "mesh", "magic")
    rejected(b"", manifest, "mesh")
    document, binary = split(glb)
    rejected(join(document, binary[: len(binary) // 2]), manifest, "mesh")  # accessors past the end
    broken = bytearray(glb)
    broken[20:24] = b"\xff\xfe{["  # JSON chunk garbage
    rejected(bytes(broken), manifest, "mesh", "json")


def test_non_watertight_mesh_rejected_naming_the_organ() -> None:
    body = sphere([0, 0, 0], 0.1)
    holed = trimesh.Trimesh(body.vertices, body.faces[1:], process=False)
    glb = glb_of({"body": holed})
    rejected(glb, {"name": "h", "units": "m", "organs": {"body": {"tissue": "muscle"}}},
             "manifest.organs.body", "watertight")


def test_inward_mesh_rejected() -> None:
    body = sphere([0, 0, 0], 0.1)
    inverted = trimesh.Trimesh(body.vertices, body.faces[:, ::-1], process=False)
    rejected(glb_of({"body": inverted}), {"name": "i", "units": "m", "organs": {"body": {"tissue": "muscle"}}},
             "manifest.organs.body", "inward")


def test_manifest_node_mismatch_rejected() -> None:
    glb, manifest = two_organs()
    missing = copy.deepcopy(manifest)
    missing["organs"]["kidney"] = {"tissue": "kidney"}
    rejected(glb, missing, "manifest.organs.kidney", "kidney", "no mesh node")
    extra = copy.deepcopy(manifest)
    del extra["organs"]["organ"]
    del extra["sites"]["inside"]
    error = rejected(glb, extra, "manifest.organs", "'organ'", "mesh.nodes[1]", "not named in the manifest")
    assert "organ" in str(error)


def test_intersecting_spheres_rejected_naming_both() -> None:
    glb = glb_of({"a": sphere([0, 0, 0], 0.05), "b": sphere([0.06, 0, 0], 0.05)})
    manifest = {"name": "x", "units": "m",
                "organs": {"a": {"tissue": "muscle"}, "b": {"tissue": "fat_not_infiltrated"}}}
    error = rejected(glb, manifest, "manifest.organs.", "intersects")
    assert "'a'" in str(error) and "'b'" in str(error)


def test_crossing_without_any_vertex_inside_rejected() -> None:
    # A plus sign of two thin boxes: no vertex of either lies inside the
    # other, yet the surfaces cross: only the edge-crossing test sees it.
    a = trimesh.creation.box(extents=[0.2, 0.02, 0.02])
    b = trimesh.creation.box(extents=[0.02, 0.2, 0.021])
    assert not a.contains(b.vertices).any() and not b.contains(a.vertices).any()
    manifest = {"name": "x", "units": "m", "organs": {"a": {"tissue": "muscle"}, "b": {"tissue": "liver"}}}
    error = rejected(glb_of({"a": a, "b": b}), manifest, "manifest.organs.", "intersects")
    assert "edges cross" in str(error)


@pytest.mark.parametrize(
    "mutate, field, words",
    [
        (lambda m: m.pop("units"), "manifest.units", ["required"]),
        (lambda m: m.update(units="cm"), "manifest.units", ["'m' or 'mm'"]),
        (lambda m: m.update(colour="red"), "manifest.colour", ["unknown key"]),
        (lambda m: m.pop("name"), "manifest.name", ["name"]),
        (lambda m: m.update(organs={}), "manifest.organs", ["non-empty"]),
        (lambda m: m["organs"].update(body={"tissue": "muscle", "relative_permittivity": 3.0}),
         "manifest.organs.body.relative_permittivity", ["either"]),
        (lambda m: m["organs"].update(body={"tisue": "muscle"}), "manifest.organs.body.tisue", ["unknown key"]),
        (lambda m: m["organs"].update(organ={"relative_permittivity": 0.5}),
         "manifest.organs.organ.relative_permittivity", [">= 1", "[1"]),
        (lambda m: m["organs"].update(organ={"relative_permittivity": 50.0, "conductivity_s_per_m": -1}),
         "manifest.organs.organ.conductivity_s_per_m", ["[0"]),
        (lambda m: m["organs"].update(organ={"relative_permittivity": float("nan")}),
         "manifest.organs.organ.relative_permittivity", ["finite"]),
        (lambda m: m["sites"].update({"bad name": [0, 0, 0]}), "manifest.sites.bad name", ["must match"]),
        (lambda m: m["sites"].update(s=[0, 0]), "manifest.sites.s", ["three numbers"]),
        (lambda m: m["sites"].update(s={"kind": "tag", "position_m": [0, 0, 0]}), "manifest.sites.s.kind", ["capsule"]),
        (lambda m: m["sites"].update(s={"pos": [0, 0, 0]}), "manifest.sites.s.pos", ["unknown key"]),
        (lambda m: m["sites"].update(s=[0.1, 0.0, 0.0]), "manifest.sites.s", ["surface"]),  # on the body surface
    ],
)
def test_bad_manifests_rejected(mutate, field, words) -> None:
    glb, manifest = two_organs()
    mutate(manifest)
    with pytest.raises(PhantomValidationError) as info:
        load_phantom(glb, manifest)
    assert field_text(info.value.field) == field
    assert any(w in str(info.value) for w in words), str(info.value)


def test_unknown_tissue_rejected_with_typed_error() -> None:
    glb, manifest = two_organs()
    manifest["organs"]["body"] = {"tissue": "unobtainium"}
    rejected(glb, manifest, "manifest.organs.body.tissue", "unobtainium", error=UnknownTissueError)


def test_caps_are_enforced_before_decoding() -> None:
    glb, manifest = two_organs()
    rejected(glb, manifest, "mesh", "over the cap", max_bytes=len(glb) - 1)
    rejected(glb, manifest, "mesh", "exceed the cap", max_triangles=100)
    # The triangle cap is checked from the declared counts: a file claiming a
    # huge index count is refused without allocating it.
    document, binary = split(glb)
    document["accessors"][0]["count"] = 3 * 10**9
    rejected(join(document, binary), manifest, "mesh", "exceed the cap")


def test_unsupported_gltf_features_rejected() -> None:
    glb, manifest = two_organs()
    document, binary = split(glb)
    cases = []
    d = copy.deepcopy(document)
    d["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    cases.append((d, "mesh.extensionsRequired", "draco"))
    d = copy.deepcopy(document)
    d["meshes"][0]["primitives"][0]["mode"] = 5
    cases.append((d, "mesh.meshes[0].primitives[0].mode", "triangles"))
    d = copy.deepcopy(document)
    d["buffers"][0]["uri"] = "http://example.com/evil.bin"
    cases.append((d, "mesh.buffers[0]", "external"))
    d = copy.deepcopy(document)
    d["nodes"][1]["name"] = d["nodes"][0]["name"]
    cases.append((d, "mesh.nodes", "more than one node"))
    d = copy.deepcopy(document)
    d["nodes"][0]["name"] = "bad name!"
    cases.append((d, "mesh.nodes[0].name", "must match"))
    d = copy.deepcopy(document)
    d["nodes"][0]["children"] = [0]
    cases.append((d, "mesh.nodes[0]", "reachable twice"))
    d = copy.deepcopy(document)
    d["accessors"][0]["bufferView"] = 99
    cases.append((d, "mesh.meshes", "out of range"))
    for doc, field, word in cases:
        rejected(join(doc, binary), manifest, field, word)


def test_index_out_of_range_and_nan_vertices_rejected() -> None:
    glb, manifest = two_organs()
    document, binary = split(glb)
    index_view = document["bufferViews"][document["accessors"][
        document["meshes"][0]["primitives"][0]["indices"]]["bufferView"]]
    patched = bytearray(binary)
    struct.pack_into("<I", patched, index_view.get("byteOffset", 0), 10**6)
    rejected(join(document, bytes(patched)), manifest, "mesh.meshes[0].primitives[0].indices", "out of range")
    position_view = document["bufferViews"][document["accessors"][
        document["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["bufferView"]]
    patched = bytearray(binary)
    struct.pack_into("<f", patched, position_view.get("byteOffset", 0), float("nan"))
    rejected(join(document, bytes(patched)), manifest, "mesh.meshes[0].primitives[0].attributes.POSITION",
             "non-finite")


# ------------------------------------------------------------------ units, site kinds and sites (issue 25)
def test_units_are_checked_against_the_mesh_extent() -> None:
    glb, manifest = two_organs()  # a 0.2 m body
    manifest["sites"] = {}
    as_mm = dict(manifest, units="mm")  # would be a 0.2 mm body
    error = rejected(glb, as_mm, "manifest.units", "'mm'", "0.0002 m", "declare units 'm'")
    assert "metres" in error.reason
    # the same body written in millimetres but declared in metres: a 200 m body
    big = glb_of({"body": sphere([0, 0, 0], 100.0), "organ": sphere([20, 0, 0], 30.0)})
    rejected(big, manifest, "manifest.units", "200 m", "declare units 'mm'")
    # a room of a few metres, how users compare with other ray tracers, stays valid
    room = trimesh.creation.box(extents=[6.0, 4.0, 3.0])
    load_phantom(glb_of({"room": room}), {"name": "room", "units": "m", "organs": {"room": {"tissue": "air"}}})


def test_a_site_inside_tissue_must_state_its_kind() -> None:
    glb, manifest = two_organs()
    for spec in ([0.0, 0.095, 0.0], {"position_m": [0.0, 0.095, 0.0]}):  # in the body, 5 mm under its surface
        manifest["sites"] = {"belt": spec}
        error = rejected(glb, manifest, "manifest.sites.belt", "inside 'body'", "capsule", "sensor")
        assert error.field == ("manifest", "sites", "belt")
    manifest["sites"] = {"belt": {"kind": "sensor", "position_m": [0.0, 0.095, 0.0]}}
    assert load_phantom(glb, manifest).sites["belt"].kind == "sensor"
    manifest["sites"] = {"off_body": [0.0, -0.2, 0.0]}  # in air: a sensor, no kind needed
    assert load_phantom(glb, manifest).sites["off_body"].kind == "sensor"


def test_a_site_the_channel_endpoint_would_refuse_is_refused_at_upload() -> None:
    glb, manifest = two_organs()
    phantom = load_phantom(glb, manifest)
    far = [5.0, 5.0, 5.0]
    with pytest.raises(InputError, match="outside the phantom's bounds"):
        phantom.antenna_medium(far)  # the rule a channel request's antenna obeys
    manifest["sites"] = {"far": far}
    rejected(glb, manifest, "manifest.sites.far", "outside the phantom's bounds")


def test_names_with_dots_keep_their_place_in_the_field() -> None:
    glb, manifest = two_organs()
    manifest["sites"] = {"Sphere.001": [0.0, 0.0, 0.0]}  # inside 'organ' without a kind
    error = rejected(glb, manifest, "manifest.sites.Sphere.001", "inside")
    assert error.field == ("manifest", "sites", "Sphere.001")  # one name, not two path parts


def test_unreadable_manifest_and_json_chunk_text_is_refused() -> None:
    from raytrace.body.gltf import parse_manifest

    for text in ("[" * 100_000 + "]" * 100_000,          # nests past the parser's recursion limit
                 '{"name": ' + "9" * 5000 + "}",          # past Python's limit on integer digits
                 b"\xff\xfe{}", "{not json"):
        with pytest.raises(PhantomValidationError) as info:
            parse_manifest(text)
        assert info.value.field == "manifest"
    glb, manifest = two_organs()
    document, binary = split(glb)
    for patch in ('"scene": ' + "1" * 5000, '"scene": ' + "[" * 100_000 + "]" * 100_000):
        js = json.dumps(document)
        broken = js[:-1] + ", " + patch + "}"
        text = broken.encode() + b" " * (-len(broken) % 4)
        binary_padded = binary + b"\x00" * (-len(binary) % 4)
        total = 12 + 8 + len(text) + 8 + len(binary_padded)
        data = (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(text), 0x4E4F534A) + text
                + struct.pack("<II", len(binary_padded), 0x004E4942) + binary_padded)
        rejected(data, manifest, "mesh", "json")


def test_huge_integers_in_the_manifest_are_refused_by_name() -> None:
    glb, manifest = two_organs()
    manifest["organs"]["organ"] = {"relative_permittivity": 10**400}  # parses, but is no float
    rejected(glb, manifest, "manifest.organs.organ.relative_permittivity", "finite number")


def test_mutated_json_chunks_only_ever_give_validation_errors() -> None:
    """Replace values of the glTF JSON chunk by hostile ones (types, huge numbers, nesting): the
    loader answers PhantomValidationError, never another exception (which the service would turn
    into a 500). Deterministic: a seeded generator over every value of the document."""
    glb, manifest = two_organs()
    document, binary = split(glb)
    hostile = [None, True, -1, 2**64, 10**400, 1e308, -0.0, "x", [], {}, [[[]]], {"a": {"b": {}}},
               [0] * 17, [1e308] * 16, "glTF"]
    paths = []

    def walk(node, path):
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, path + [k])
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, path + [i])
        if path:
            paths.append(path)

    walk(document, [])
    rng = np.random.default_rng(25)
    for _ in range(400):
        doc = copy.deepcopy(document)
        path = paths[rng.integers(len(paths))]
        target = doc
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = hostile[rng.integers(len(hostile))]
        try:
            load_phantom(join(doc, binary), manifest)
        except PhantomValidationError:
            pass
