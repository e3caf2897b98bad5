"""Broken inputs: each is refused before anything is built, naming the file, organ, label or sensor and why
(PhantomValidationError: a 422 over HTTP, exit 2 from the CLI)."""

from __future__ import annotations

import nibabel
import numpy as np
import pytest

from raytrace.body.anatomy import build_phantom
from raytrace.errors import PhantomValidationError, field_text
from service.cli import main
from tests.raytrace.anatomy.files import sphere, write_manifest, write_surface


def refused(tmp_path, manifest, field: str, *words: str) -> PhantomValidationError:
    with pytest.raises(PhantomValidationError) as info:
        build_phantom(manifest, tmp_path)
    assert field_text(info.value.field).startswith(field), info.value.field
    for word in words:
        assert word.lower() in str(info.value).lower(), (word, str(info.value))
    return info.value


def base(tmp_path) -> dict:
    write_surface(tmp_path / "body.stl", sphere(80.0, subdivisions=2))
    write_surface(tmp_path / "organ.stl", sphere(20.0, subdivisions=2))
    return {"name": "broken", "units": "mm", "body": {"surface": "body.stl"},
            "organs": {"organ": {"file": "organ.stl", "tissue": "liver"}}}


def test_an_open_surface_beyond_the_fill_limit(tmp_path) -> None:
    manifest = base(tmp_path)
    open_sphere = sphere(20.0, subdivisions=3)
    keep = ~((open_sphere.triangles_center[:, 0] > 0) & (open_sphere.triangles_center[:, 2] > 0))  # a quarter off
    write_surface(tmp_path / "open.ply", open_sphere.submesh([np.flatnonzero(keep)])[0])
    manifest["organs"]["organ"] = {"files": ["open.ply"], "tissue": "liver"}
    refused(tmp_path, manifest, "manifest.organs.organ", "open.ply", "open", "max_hole_m", "not a planar cut")


def test_two_organs_crossing(tmp_path) -> None:
    manifest = base(tmp_path)
    write_surface(tmp_path / "other.stl", sphere(20.0, (25.0, 0.0, 0.0), subdivisions=2))
    manifest["organs"]["other"] = {"file": "other.stl", "tissue": "kidney"}
    refused(tmp_path, manifest, "manifest.organs.other", "'organ'", "'other'", "overlap", "around")


def test_a_label_missing(tmp_path) -> None:
    labels = np.zeros((20, 20, 20), np.int16)
    labels[5:15, 5:15, 5:15] = 1
    nibabel.save(nibabel.Nifti1Image(labels, np.diag([4.0, 4.0, 4.0, 1.0])), str(tmp_path / "labels.nii"))
    manifest = {"name": "labels", "units": "mm", "volume": "labels.nii",
                "organs": {"body": {"label": 1, "tissue": "muscle"}, "liver": {"label": 7, "tissue": "liver"}}}
    refused(tmp_path, manifest, "manifest.organs.liver.label", "label 7", "missing", "labels present: 1")


def test_a_label_without_a_tissue_in_the_map(tmp_path) -> None:
    labels = np.zeros((20, 20, 20), np.int16)
    labels[5:15, 5:15, 5:15] = 3
    nibabel.save(nibabel.Nifti1Image(labels, np.diag([4.0, 4.0, 4.0, 1.0])), str(tmp_path / "labels.nii.gz"))
    manifest = {"name": "labels", "units": "mm", "volume": "labels.nii.gz", "labels": {3: "pancreas"},
                "organs": {"pancreas": {"label": 3}}}
    refused(tmp_path, manifest, "manifest.organs.pancreas.tissue", "pancreas", "give its tissue")


def test_a_sensor_outside_the_body(tmp_path) -> None:
    manifest = base(tmp_path)
    manifest["sensors"] = {"points": {"front": [0.0, -79.0, 0.0], "away": [0.0, -120.0, 0.0]}}
    refused(tmp_path, manifest, "manifest.sensors.points.away", "'away'", "outside the body")


def test_a_ten_gigavoxel_volume_is_refused_from_its_header(tmp_path) -> None:
    header = nibabel.Nifti1Header()
    header.set_data_dtype(np.int16)
    header.set_data_shape((2200, 2200, 2200))  # 1.06e10 voxels, 21 GB decoded; the file holds no voxel at all
    with open(tmp_path / "huge.nii", "wb") as fh:
        header.write_to(fh)
    manifest = {"name": "huge", "units": "mm", "volume": "huge.nii", "organs": {"x": {"label": 1, "tissue": "liver"}}}
    refused(tmp_path, manifest, "manifest.volume", "huge.nii", "1.06e+10 voxels", "over the cap")


def test_a_file_that_is_not_a_mesh(tmp_path) -> None:
    manifest = base(tmp_path)
    (tmp_path / "notes.stl").write_text("these are my notes, not a mesh\n" * 10)
    manifest["organs"]["organ"]["file"] = "notes.stl"
    refused(tmp_path, manifest, "manifest.organs.organ", "notes.stl", "not a readable .stl")
    (tmp_path / "scan.vtk").write_bytes(b"\x00\x01garbage" * 100)
    manifest["organs"]["organ"]["file"] = "scan.vtk"
    refused(tmp_path, manifest, "manifest.organs.organ", "scan.vtk")
    manifest["organs"]["organ"]["file"] = "missing.obj"
    refused(tmp_path, manifest, "manifest.organs.organ", "missing.obj", "no such file")
    manifest["organs"]["organ"]["file"] = "organ.docx"
    (tmp_path / "organ.docx").write_bytes(b"PK")
    refused(tmp_path, manifest, "manifest.organs.organ", "organ.docx", "unknown surface format")


def test_manifest_mistakes_name_their_key(tmp_path) -> None:
    manifest = base(tmp_path)
    refused(tmp_path, {**manifest, "organz": {}}, "manifest.organz", "unknown key")
    refused(tmp_path, {**manifest, "units": "cm"}, "manifest.units", "'m' or 'mm'")
    bad_layer = {**manifest, "body": {"surface": "body.stl", "layers": [{"tissue": "skin_dry", "thickness_m": 2}]}}
    refused(tmp_path, bad_layer, "manifest.body.layers.0.thickness_m", "in metres")
    refused(tmp_path, {**manifest, "tracts": {"t": {"file": "p.json", "organ": "colon"}}}, "manifest.tracts.t.organ")


def test_the_cli_exits_2_naming_the_organ(tmp_path, capsys) -> None:
    manifest = base(tmp_path)
    write_surface(tmp_path / "other.stl", sphere(20.0, (25.0, 0.0, 0.0), subdivisions=2))
    manifest["organs"]["other"] = {"file": "other.stl", "tissue": "kidney"}
    path = write_manifest(tmp_path, manifest)
    assert main(["phantom", "build", str(path), "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "manifest.organs.other" in err and "overlap" in err
    assert not (tmp_path / "out" / "phantom.glb").exists()  # nothing half-built
    manifest["organs"].pop("other")
    path = write_manifest(tmp_path, manifest, "ok.json")
    assert main(["phantom", "build", str(path), "--out", str(tmp_path / "out"), "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["manifest.json", "phantom.glb", "report.json",
                                                                   "report.md"]


def test_a_gltf_buffer_outside_the_manifests_directory_or_a_url(tmp_path) -> None:
    """A JSON glTF (trimesh's writer) whose buffer names a file outside the manifest's directory, an absolute
    path, a URL or a missing file: refused naming the organ, the file and the buffer; nothing is fetched."""
    import json

    from tests.raytrace.anatomy.files import write_gltf

    case = tmp_path / "case"
    case.mkdir()
    manifest = base(case)
    manifest["organs"]["organ"]["file"] = "organ.gltf"
    written = write_gltf(case / "organ.gltf", sphere(20.0, subdivisions=2))
    buffer_file = next(p for p in written if p.name == "gltf_buffer_0.bin")  # trimesh's name of buffer 0
    outside = tmp_path / buffer_file.name
    outside.write_bytes(buffer_file.read_bytes())
    document = json.loads((case / "organ.gltf").read_text())
    for uri, words in ((f"../{buffer_file.name}", ("outside the manifest's directory",)),
                       (str(outside), ("absolute",)),
                       ("http://example.invalid/organ.bin", ("URLs",)),
                       ("missing.bin", ("no such file",))):
        document["buffers"][0]["uri"] = uri
        (case / "organ.gltf").write_text(json.dumps(document))
        refused(case, manifest, "manifest.organs.organ", "organ.gltf", "buffer 0", *words)


def test_an_xml_vtk_with_a_document_type_is_refused(tmp_path) -> None:
    """No entity expansion: a .vtp declaring entities is refused before its XML is parsed."""
    from tests.raytrace.anatomy.files import write_vtp

    manifest = base(tmp_path)
    write_vtp(tmp_path / "organ.vtp", sphere(20.0, subdivisions=2))
    text = (tmp_path / "organ.vtp").read_text()
    head = '<?xml version="1.0"?>\n<!DOCTYPE VTKFile [<!ENTITY a "aaaaaaaaaa">]>\n'
    (tmp_path / "organ.vtp").write_text(head + text.split("\n", 1)[1])
    manifest["organs"]["organ"]["file"] = "organ.vtp"
    refused(tmp_path, manifest, "manifest.organs.organ", "organ.vtp", "document type")
