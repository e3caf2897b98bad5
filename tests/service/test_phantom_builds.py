"""POST /v1/phantoms with an `archive` (a zip of anatomy files + a build manifest): checked before the 202,
built as a job on the service's queue, stored like an upload; every broken archive a 4xx naming the
entry, and a build refused in the job names the organ in its `error` with nothing stored."""

from __future__ import annotations

import io
import json
import time
import zipfile

import nibabel
import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient

from service.app import create_app
from tests.raytrace.anatomy.files import sphere, write_surface

MANIFEST = {"name": "zipped", "units": "mm", "body": {"surface": "body.stl"},
            "organs": {"organ": {"file": "organ.ply", "tissue": "liver"}},
            "tracts": {"path": {"file": "path.json", "organ": "organ", "landmarks": {"start": 0}}},
            "sensors": {"points": {"front": [0.0, -79.0, 0.0]}}}


@pytest.fixture
def client(make_settings):
    with TestClient(create_app(make_settings(load_builtins=False)), raise_server_exceptions=False) as c:
        yield c


def archive(tmp_path, manifest=MANIFEST, extra: dict[str, bytes] | None = None, prefix: str = "") -> bytes:
    write_surface(tmp_path / "body.stl", sphere(80.0, subdivisions=2))
    write_surface(tmp_path / "organ.ply", sphere(20.0, subdivisions=2))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(prefix + "manifest.yaml", yaml.safe_dump(manifest))
        zf.write(tmp_path / "body.stl", prefix + "body.stl")
        zf.write(tmp_path / "organ.ply", prefix + "organ.ply")
        zf.writestr(prefix + "path.json", json.dumps({"points": [[0, 0, -10], [0, 0, 0], [0, 0, 10]]}))
        for name, data in (extra or {}).items():
            zf.writestr(name, data)
    return buf.getvalue()


def wait(client, build_id: str) -> dict:
    for _ in range(1200):  # a hang guard (10 min), not a speed verdict
        status = client.get(f"/v1/phantoms/builds/{build_id}").json()
        if status["state"] not in ("queued", "running"):
            return status
        time.sleep(0.5)
    raise AssertionError(f"build {build_id} still {status['state']}")


def test_an_archive_is_built_as_a_job_and_stored(client, tmp_path) -> None:
    r = client.post("/v1/phantoms", files={"archive": ("anatomy.zip", archive(tmp_path, prefix="case/"),
                                                       "application/zip")})
    assert r.status_code == 202, r.text
    build_id = r.json()["id"]
    assert r.headers["location"] == f"/v1/phantoms/builds/{build_id}" and r.json()["state"] == "queued"
    status = wait(client, build_id)
    assert status["state"] == "done" and status["progress"] == 1.0, status
    phantom = client.get(f"/v1/phantoms/{status['phantom_id']}").json()
    assert [o["name"] for o in phantom["organs"]] == ["body", "organ"]
    assert phantom["sites"]["front"]["medium"] == "body" and phantom["sites"]["path_start"]["kind"] == "capsule"
    assert status["report"]["organs"][1]["triangles"] == 320
    assert client.get("/v1/phantoms/builds").json()["builds"][0]["id"] == build_id
    # the stored phantom is an upload like any other: its mesh and manifest upload again
    glb = client.get(f"/v1/phantoms/{status['phantom_id']}/mesh").content
    manifest = client.get(f"/v1/phantoms/{status['phantom_id']}/manifest").json()
    again = client.post("/v1/phantoms", files={"mesh": ("m.glb", glb), "manifest": (None, json.dumps(manifest))})
    assert again.status_code == 201, again.text
    assert client.delete(f"/v1/phantoms/builds/{build_id}").json()["deleted"] is True


def test_a_build_refused_in_the_job_names_the_organ_and_stores_nothing(client, tmp_path) -> None:
    manifest = {**MANIFEST, "organs": {**MANIFEST["organs"], "other": {"file": "other.stl", "tissue": "kidney"}}}
    write_surface(tmp_path / "other.stl", sphere(20.0, (25.0, 0.0, 0.0), subdivisions=2))
    other = (tmp_path / "other.stl").read_bytes()
    r = client.post("/v1/phantoms", files={"archive": ("a.zip", archive(tmp_path, manifest, {"other.stl": other}))})
    assert r.status_code == 202, r.text
    status = wait(client, r.json()["id"])
    assert status["state"] == "failed" and status["phantom_id"] is None
    assert status["error"]["loc"] == ["body", "archive", "manifest", "organs", "other"], status["error"]
    assert "overlap" in status["error"]["msg"]
    assert client.get("/v1/phantoms").json()["phantoms"] == []


def _zip(entries: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_broken_archives_are_refused_before_the_job_naming_the_entry(client, tmp_path) -> None:
    def refused(body: bytes, loc: list, *words: str, status: int = 422) -> None:
        r = client.post("/v1/phantoms", files={"archive": ("a.zip", body)})
        assert r.status_code == status, r.text
        detail = r.json()["detail"][0]
        assert detail["loc"] == loc, detail
        for word in words:
            assert word in detail["msg"], (word, detail["msg"])

    refused(b"not a zip at all", ["body", "archive"], "not a zip")
    refused(_zip({"../evil.stl": b"x", "manifest.yaml": b"name: x"}), ["body", "archive", "../evil.stl"], "'..'")
    refused(_zip({"body.stl": b"x"}), ["body", "archive"], "manifest")
    missing = {**MANIFEST, "organs": {"organ": {"file": "liver.stl", "tissue": "liver"}}}
    refused(archive(tmp_path, missing), ["body", "archive", "manifest", "organs", "organ", "files", 0], "liver.stl",
            "no such file")
    refused(archive(tmp_path, {**MANIFEST, "units": "inch"}), ["body", "archive", "manifest", "units"])
    header = nibabel.Nifti1Header()
    header.set_data_dtype(np.int16)
    header.set_data_shape((2200, 2200, 2200))
    huge = io.BytesIO()
    header.write_to(huge)
    big = {"name": "huge", "units": "mm", "volume": "huge.nii", "organs": {"liver": {"label": 5}}}
    refused(_zip({"manifest.yaml": yaml.safe_dump(big).encode(), "huge.nii": huge.getvalue()}),
            ["body", "archive", "manifest", "volume"], "voxels", "over the cap")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("manifest.yaml", yaml.safe_dump(MANIFEST))
        zf.writestr("body.stl", b"\0" * (300 * 2**20))  # 300 MiB of zeros in ~300 kB
    refused(buf.getvalue(), ["body", "archive", "body.stl"], "more than", status=413)
    r = client.post("/v1/phantoms", files={"archive": ("a.zip", b"PK"), "mesh": ("m.glb", b"glTF")})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "mesh"]
    assert client.get("/v1/phantoms/builds").json()["builds"] == []


def test_a_json_gltf_with_its_buffer_files_in_the_archive_builds(client, tmp_path) -> None:
    """trimesh's JSON glTF (buffers in files beside it) inside the zip: built; its organ the written sphere
    (320 triangles). Without a buffer file the archive is refused before the job, naming the organ."""
    from tests.raytrace.anatomy.files import write_gltf

    written = write_gltf(tmp_path / "organ.gltf", sphere(20.0, subdivisions=2))
    entries = {p.name: p.read_bytes() for p in written}
    manifest = {**MANIFEST, "organs": {"organ": {"file": "organ.gltf", "tissue": "liver"}}}
    r = client.post("/v1/phantoms", files={"archive": ("a.zip", archive(tmp_path, manifest, entries))})
    assert r.status_code == 202, r.text
    status = wait(client, r.json()["id"])
    assert status["state"] == "done", status
    assert status["report"]["organs"][1]["triangles"] == 320
    entries.pop("gltf_buffer_0.bin")
    r = client.post("/v1/phantoms", files={"archive": ("a.zip", archive(tmp_path, manifest, entries))})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert detail["loc"][:5] == ["body", "archive", "manifest", "organs", "organ"], detail
    assert "organ.gltf" in detail["msg"] and "no such file" in detail["msg"], detail
