"""Phantom uploads: validation, streaming size cap, atomic durable storage, restart, deletion.

After every rejected upload the data directory must hold nothing new (no
half-written phantom, no temporary directory).
"""

from __future__ import annotations

import json
import os

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.storage import PhantomStore
from tests.service.test_api import assert_field


def upload(api, glb: bytes, manifest, filename: str = "p.glb"):
    manifest_text = manifest if isinstance(manifest, (str, bytes)) else json.dumps(manifest)
    return api.post(
        "/v1/phantoms",
        files={"mesh": (filename, glb, "model/gltf-binary"),
               "manifest": ("manifest.json", manifest_text, "application/json")},
    )


def stored_entries(settings) -> list[str]:
    root = settings.data_dir / "phantoms"
    return sorted(os.listdir(root)) if root.exists() else []


@pytest.fixture
def settings(make_settings):
    return make_settings(max_upload_bytes=64 * 1024)


@pytest.fixture
def client(settings):
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def test_upload_describe_trace_download_reupload_delete(client, settings, glb_phantom):
    glb, manifest = glb_phantom()
    r = upload(client, glb, manifest)
    assert r.status_code == 201, r.text
    info = r.json()
    pid = info["id"]
    assert r.headers["location"] == f"/v1/phantoms/{pid}"
    assert pid.startswith("up-") and not info["builtin"]
    organs = {o["name"]: o for o in info["organs"]}
    assert organs["body"]["tissue"] == "muscle" and organs["body"]["parent"] == "air"
    assert organs["organ"]["relative_permittivity"] == 11.6 and organs["organ"]["parent"] == "body"
    assert info["sites"]["capsule"] == {"kind": "capsule", "position_m": [0.0, 0.0, 0.01], "medium": "organ"}
    assert info["sites"]["sensor"]["medium"] == "air"
    assert stored_entries(settings) == [pid]

    assert pid in [p["id"] for p in client.get("/v1/phantoms").json()["phantoms"]]
    assert client.get(f"/v1/phantoms/{pid}").json() == info

    ch = client.post("/v1/channel", json={"phantom": pid, "transmitter": {"site": "capsule"},
                                          "receivers": [{"site": "sensor"}], "rays": 1000, "max_interactions": 2})
    assert ch.status_code == 200, ch.text
    assert ch.json()["transmitter"]["medium"] == "organ"

    mesh = client.get(f"/v1/phantoms/{pid}/mesh")
    assert mesh.status_code == 200 and mesh.content[:4] == b"glTF"
    again = upload(client, mesh.content, manifest)
    assert again.status_code == 201, again.text
    assert again.json()["id"] != pid and again.json()["organs"] == info["organs"]

    assert client.delete(f"/v1/phantoms/{pid}").status_code == 204
    assert_field(client.get(f"/v1/phantoms/{pid}"), 404, "path", "phantom_id")
    assert_field(client.delete(f"/v1/phantoms/{pid}"), 404, "path", "phantom_id")
    gone = {"phantom": pid, "transmitter": {"site": "capsule"}, "receivers": [{"site": "sensor"}]}
    assert_field(client.post("/v1/channel", json=gone), 404, "body", "phantom")
    assert stored_entries(settings) == [again.json()["id"]]


def test_uploads_survive_a_restart(settings, glb_phantom):
    glb, manifest = glb_phantom()
    with TestClient(create_app(settings)) as first:
        pid = upload(first, glb, manifest).json()["id"]
    with TestClient(create_app(settings)) as second:  # a new process would see the same data dir
        assert second.get(f"/v1/phantoms/{pid}").status_code == 200
        r = second.post("/v1/channel", json={"phantom": pid, "transmitter": {"site": "capsule"},
                                             "receivers": [{"site": "sensor"}], "rays": 500, "max_interactions": 1})
        assert r.status_code == 200, r.text
        assert second.get("/readyz").json()["phantoms"] >= 2


def _truncated(glb: bytes) -> bytes:
    return glb[: len(glb) // 2]


BAD_UPLOADS = {
    "not a glb (magic)": (lambda g: b"PK\x03\x04" + g[4:], {}, ("body", "mesh")),
    "malformed glb": (lambda g: b"glTF" + b"\x02\x00\x00\x00" + os.urandom(200), {}, ("body",)),
    "truncated glb": (_truncated, {}, ("body",)),
    "empty": (lambda g: b"", {}, ("body", "mesh")),
}


@pytest.mark.parametrize("case", list(BAD_UPLOADS))
def test_bad_meshes_are_rejected_without_leftovers(client, settings, glb_phantom, case):
    mutate, kw, loc = BAD_UPLOADS[case]
    glb, manifest = glb_phantom()
    r = upload(client, mutate(glb), manifest, **kw)
    assert r.status_code == 422, r.text
    assert_field(r, 422, *loc)
    assert stored_entries(settings) == []


@pytest.mark.parametrize(
    "kind, manifest_patch, loc",
    [
        ("open", {}, ("organs", "organ")),  # not watertight: names the organ
        ("intersecting", {}, ("organs",)),
        ("ok", {"organs": {"body": {"tissue": "muscle"}}}, ("organs",)),  # mesh node 'organ' not in the manifest
        ("ok", {"organs": {"body": {"tissue": "muscle"}, "organ": {"tissue": "fat_average_infiltrated"},
                           "ghost": {"tissue": "liver"}}}, ("ghost",)),
        ("ok", {"organs": {"body": {"tissue": "unobtainium"}, "organ": {"tissue": "muscle"}}}, ("tissue",)),
        ("ok", {"organs": {"body": {"tissue": "muscle", "relative_permittivity": 3.0}, "organ": {"tissue": "muscle"}}},
         ("manifest", "organs", "body")),
        ("ok", {"sites": {"on_face": [0.1, 0.0, 0.0]}}, ("on_face",)),  # on the box surface: ambiguous medium
        ("ok", {"sites": {"bad": [0.0, "x", 0.0]}}, ("manifest", "sites", "bad")),
        ("ok", {"units": "furlong"}, ("manifest", "units")),
        ("ok", {"extra_key": 1}, ("manifest", "extra_key")),
    ],
)
def test_invalid_phantoms_are_rejected_naming_the_problem(client, settings, glb_phantom, kind, manifest_patch, loc):
    glb, manifest = glb_phantom(kind, **manifest_patch)
    r = upload(client, glb, manifest)
    assert r.status_code == 422, r.text
    locs = [item["loc"] for item in r.json()["detail"]]
    flat = [str(x) for one in locs for x in one]
    for part in loc:
        assert part in flat, (part, locs)
    assert stored_entries(settings) == []


def test_the_content_decides_not_the_file_name(client, glb_phantom):
    """Browsers name a blob as they like: a binary glTF is taken whatever its file name (the
    magic bytes and the loader decide)."""
    glb, manifest = glb_phantom()
    r = upload(client, glb, manifest, filename="blob")
    assert r.status_code == 201, r.text


def test_manifest_must_be_json(client, settings, glb_phantom):
    glb, _ = glb_phantom()
    assert_field(upload(client, glb, "{not json"), 422, "body", "manifest")
    assert_field(upload(client, glb, b"\xff\xfe"), 422, "body", "manifest")
    assert stored_entries(settings) == []


def test_missing_or_extra_parts(client, glb_phantom):
    glb, manifest = glb_phantom()
    r = client.post("/v1/phantoms", files={"mesh": ("p.glb", glb, "model/gltf-binary")})
    assert_field(r, 422, "body", "manifest")
    r = client.post("/v1/phantoms", files={"manifest": ("m.json", json.dumps(manifest), "application/json")})
    assert_field(r, 422, "body", "mesh")
    r = client.post("/v1/phantoms", json=manifest)
    assert_field(r, 422, "header", "content-type")
    r = client.post(
        "/v1/phantoms",
        files={"mesh": ("p.glb", glb, "model/gltf-binary"),
               "manifest": ("m.json", json.dumps(manifest), "application/json"), "other": ("x", b"1", "text/plain")},
    )
    assert_field(r, 422, "body", "other")


def test_upload_over_the_size_cap_is_413_while_streaming(make_settings, glb_phantom):
    settings = make_settings(max_upload_bytes=2048)
    glb, manifest = glb_phantom()
    assert len(glb) > 2048
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        assert_field(upload(client, glb, manifest), 413, "body", "mesh")
        # A declared Content-Length over the cap is refused before reading.
        boundary = "capsuleboundary"
        r = client.post(
            "/v1/phantoms",
            content=b"x" * 1_000_000,
            headers={"content-type": f"multipart/form-data; boundary={boundary}"},
        )
        assert r.status_code == 413
    assert stored_entries(settings) == []


def test_triangle_cap(make_settings, glb_phantom):
    settings = make_settings(max_triangles=100)
    glb, manifest = glb_phantom()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        r = upload(client, glb, manifest)
        assert r.status_code == 422 and "100" in r.text
    assert stored_entries(settings) == []


def test_upload_count_cap_is_507(make_settings, glb_phantom):
    settings = make_settings(max_uploads=1)
    glb, manifest = glb_phantom()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        assert upload(client, glb, manifest).status_code == 201
        assert_field(upload(client, glb, manifest), 507, "body", "mesh")


def test_a_failure_while_storing_leaves_nothing(client, settings, glb_phantom, monkeypatch):
    import service.storage as storage

    real = storage._write_durable
    calls = {"n": 0}

    def flaky(path, data):
        calls["n"] += 1
        if path.name == storage.META_FILE:
            raise OSError(28, "No space left on device")
        real(path, data)

    monkeypatch.setattr(storage, "_write_durable", flaky)
    glb, manifest = glb_phantom()
    r = upload(client, glb, manifest)
    assert r.status_code == 507, r.text
    assert calls["n"] == 3
    assert stored_entries(settings) == []


def test_leftover_temporary_directories_are_cleaned_at_start(settings, glb_phantom):
    root = settings.data_dir / "phantoms"
    (root / ".tmp-up-0123456789abcdef-dead").mkdir(parents=True)
    (root / ".tmp-up-0123456789abcdef-dead" / "mesh.glb").write_bytes(b"glTF half")
    (root / "up-0123456789abcdef").mkdir()  # no meta.json: incomplete, never listed
    with TestClient(create_app(settings)) as client:
        ids = [p["id"] for p in client.get("/v1/phantoms").json()["phantoms"]]
        assert "up-0123456789abcdef" not in ids
    assert ".tmp-up-0123456789abcdef-dead" not in os.listdir(root)


def test_store_refuses_ids_that_are_not_generated_ones(tmp_path):
    store = PhantomStore(tmp_path)
    store.init()
    for bad in ["../x", "up-../../etc", "torso", "up-0123456789ABCDEF", "up-0123456789abcdef/../x"]:
        with pytest.raises(ValueError):
            store.save(bad, b"glTF", {}, {})
        assert not store.exists(bad)
    assert os.listdir(tmp_path / "phantoms") == []


def test_the_reader_stops_pulling_the_body_at_the_cap(glb_phantom):
    """read_upload on a 640 MB chunked stream (no Content-Length) pulls only about the cap."""
    import anyio
    from starlette.requests import Request

    from service.errors import UploadTooLarge
    from service.uploads import read_upload

    _, manifest = glb_phantom()
    boundary = "capsuleboundary"
    head = (
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"manifest\"\r\n\r\n{json.dumps(manifest)}\r\n"
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"mesh\"; filename=\"p.glb\"\r\n"
        "Content-Type: model/gltf-binary\r\n\r\n"
    ).encode()
    chunk = b"glTF" + b"\0" * (64 * 1024 - 4)
    pulled = {"bytes": 0}
    total_chunks = 10_000  # 640 MB if it were all read

    async def receive():
        if pulled["bytes"] == 0:
            pulled["bytes"] += len(head)
            return {"type": "http.request", "body": head, "more_body": True}
        pulled["bytes"] += len(chunk)
        return {"type": "http.request", "body": chunk, "more_body": pulled["bytes"] < total_chunks * len(chunk)}

    scope = {
        "type": "http",
        "method": "POST",
        "path": "/v1/phantoms",
        "headers": [(b"content-type", f"multipart/form-data; boundary={boundary}".encode())],
    }

    async def main():
        with pytest.raises(UploadTooLarge) as info:
            await read_upload(Request(scope, receive), max_mesh_bytes=1_000_000, max_manifest_bytes=10_000)
        return info.value

    err = anyio.run(main)
    assert err.loc == ["body", "mesh"] and "1000000" in err.reason
    # Stopped within one chunk of the mesh cap, not after 640 MB.
    assert pulled["bytes"] <= 1_000_000 + 10_000 + 16 * 1024 + 2 * len(chunk)


def test_builtin_phantom_round_trips_through_mesh_and_manifest(client, settings):
    """GET /mesh + GET /manifest of a built-in re-upload as the same organs, sites and media."""
    mesh = client.get("/v1/phantoms/thesis-fig-5-6/mesh").content
    manifest = client.get("/v1/phantoms/thesis-fig-5-6/manifest").json()
    big = TestClient(create_app(settings.model_copy(update={"max_upload_bytes": 20 * 2**20})))
    with big:
        r = upload(big, mesh, manifest)
        assert r.status_code == 201, r.text
        original = client.get("/v1/phantoms/thesis-fig-5-6").json()
        copy = r.json()
        # .glb stores float32 coordinates: geometry agrees to float32 precision, the rest exactly.
        def strip(organs):
            return [{k: v for k, v in o.items() if k != "bounds_m"} for o in organs]

        assert strip(copy["organs"]) == strip(original["organs"])
        for a, b in zip(copy["organs"], original["organs"]):
            assert sum(a["bounds_m"], []) == pytest.approx(sum(b["bounds_m"], []), abs=1e-6)
        assert copy["sites"].keys() == original["sites"].keys()
        for name, site in copy["sites"].items():
            want = original["sites"][name]
            assert (site["kind"], site["medium"]) == (want["kind"], want["medium"])
            assert site["position_m"] == pytest.approx(original["sites"][name]["position_m"], abs=1e-6)
        assert_field(big.get("/v1/phantoms/up-0000000000000000/manifest"), 404, "path", "phantom_id")


def test_the_documented_manifest_example_uploads(client, glb_phantom):
    from service.schemas.phantoms import Manifest

    glb, _ = glb_phantom()
    example = Manifest.model_config["json_schema_extra"]["examples"][0]
    r = upload(client, glb, example)
    assert r.status_code == 201, r.text
    assert r.json()["sites"]["sensor"]["kind"] == "sensor"


def test_antenna_on_an_organ_surface_is_422_naming_it(client, glb_phantom):
    glb, manifest = glb_phantom()
    pid = upload(client, glb, manifest).json()["id"]
    on_face = {"phantom": pid, "transmitter": {"position_m": [0.1, 0.0, 0.0]}, "receivers": [{"site": "sensor"}],
               "rays": 500}
    body = assert_field(client.post("/v1/channel", json=on_face), 422, "body", "transmitter", "position_m")
    assert "surface" in body["detail"][0]["msg"]
    on_sphere = {"phantom": pid, "transmitter": {"site": "capsule"},
                 "receivers": [{"name": "s", "position_m": [0.0, 0.0, 0.04]}], "rays": 500}
    # 0.04 m is the icosphere's vertex radius: a vertex lies exactly there.
    assert_field(client.post("/v1/channel", json=on_sphere), 422, "body", "receivers", 0, "position_m")
