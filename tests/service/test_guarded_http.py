"""Over real HTTP, a server started here with access control and tight limits (issue 25):
API keys and phantom ownership, CORS, the upload cap under concurrent uploads. (The ranging deadline
and a client's departure reaching the estimators' loops: tests/service/test_ranging_budget.py, with an
injected clock and work held on purpose.)

The server is ``capsule-rt serve`` in a subprocess (no built-in phantoms: faster to start,
and none of these needs them), with settings no other test wants.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading

import httpx
import pytest

from tests.conftest import (
    HANG_GUARD_S,
    REPO,
    free_port,
    glb_bytes,
    nested_phantom_meshes,
    phantom_manifest,
    wait_ready,
)

KEY_A = "key-a-0123456789abcdef"
KEY_B = "key-b-0123456789abcdef"
ORIGIN = "https://lab.example:8443"


@pytest.fixture(scope="module")
def guarded(tmp_path_factory):
    port = free_port()
    data_dir = tmp_path_factory.mktemp("guarded-data")
    log_path = tmp_path_factory.mktemp("guarded-log") / "server.log"
    env = {
        **os.environ,
        "CAPSULE_RT_DATA_DIR": str(data_dir),
        "CAPSULE_RT_LOAD_BUILTINS": "false",
        "CAPSULE_RT_API_KEYS": f"{KEY_A},{KEY_B}",
        "CAPSULE_RT_CORS_ORIGINS": ORIGIN,
        "CAPSULE_RT_MAX_UPLOADS": "3",
        "CAPSULE_RT_MAX_CONCURRENCY": "2",
        "CAPSULE_RT_MAX_QUEUE": "16",
        "CAPSULE_RT_LOG_LEVEL": "warning",
    }
    with open(log_path, "wb") as log:
        command = [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1", "--port", str(port)]
        proc = subprocess.Popen(command, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(url, proc=proc)
        yield url, data_dir
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()


def upload(url: str, key: str | None = None, origin: str | None = None) -> httpx.Response:
    headers = {k: v for k, v in (("X-API-Key", key), ("Origin", origin)) if v is not None}
    files = {"mesh": ("p.glb", glb_bytes(nested_phantom_meshes()), "model/gltf-binary"),
             "manifest": ("m.json", json.dumps(phantom_manifest()), "application/json")}
    return httpx.post(f"{url}/v1/phantoms", files=files, headers=headers, timeout=HANG_GUARD_S)


def stored(url: str) -> list[str]:
    return [p["id"] for p in httpx.get(f"{url}/v1/phantoms", timeout=HANG_GUARD_S).json()["phantoms"]]


def delete_all(url: str) -> None:
    for pid in stored(url):
        for key in (KEY_A, KEY_B):
            r = httpx.delete(f"{url}/v1/phantoms/{pid}", headers={"X-API-Key": key}, timeout=HANG_GUARD_S)
            if r.status_code == 204:
                break


def test_keys_guard_writes_and_only_the_uploader_deletes(guarded):
    url, data_dir = guarded
    r = upload(url)
    assert r.status_code == 401 and r.json()["detail"][0]["loc"] == ["header", "x-api-key"], r.text
    assert upload(url, key="not-a-key-but-long-enough").status_code == 401
    r = upload(url, key=KEY_A)
    assert r.status_code == 201, r.text
    pid = r.json()["id"]
    # the key is never written to disk, only an id derived from it
    on_disk = b"".join(p.read_bytes() for p in (data_dir / "phantoms" / pid).iterdir())
    assert KEY_A.encode() not in on_disk
    assert httpx.get(f"{url}/v1/phantoms/{pid}", timeout=HANG_GUARD_S).status_code == 200  # reads stay open
    assert httpx.delete(f"{url}/v1/phantoms/{pid}", timeout=HANG_GUARD_S).status_code == 401
    r = httpx.delete(f"{url}/v1/phantoms/{pid}", headers={"X-API-Key": KEY_B}, timeout=HANG_GUARD_S)
    assert r.status_code == 403 and "another API key" in r.json()["detail"][0]["msg"], r.text
    r = httpx.delete(f"{url}/v1/phantoms/{pid}", headers={"X-API-Key": KEY_A}, timeout=HANG_GUARD_S)
    assert r.status_code == 204
    # the served contract says so
    paths = httpx.get(f"{url}/openapi.json", timeout=HANG_GUARD_S).json()["paths"]
    assert paths["/v1/phantoms"]["post"]["security"] == [{"ApiKey": []}]
    assert paths["/v1/phantoms/{phantom_id}"]["delete"]["security"] == [{"ApiKey": []}]
    assert "security" not in paths["/v1/phantoms"]["get"]


def test_cors_allow_list(guarded):
    url, _ = guarded
    preflight = {"Origin": ORIGIN, "Access-Control-Request-Method": "POST",
                 "Access-Control-Request-Headers": "x-api-key"}
    r = httpx.options(f"{url}/v1/phantoms", headers=preflight, timeout=HANG_GUARD_S)
    assert r.status_code == 200 and r.headers["access-control-allow-origin"] == ORIGIN
    r = httpx.get(f"{url}/healthz", headers={"Origin": ORIGIN}, timeout=HANG_GUARD_S)
    assert r.headers["access-control-allow-origin"] == ORIGIN
    assert "x-request-id" in r.headers["access-control-expose-headers"].lower()
    foreign = {**preflight, "Origin": "https://evil.example"}
    r = httpx.options(f"{url}/v1/phantoms", headers=foreign, timeout=HANG_GUARD_S)
    assert "access-control-allow-origin" not in r.headers
    # writes: the listed origin passes, another is refused before anything is read
    r = upload(url, key=KEY_A, origin=ORIGIN)
    assert r.status_code == 201, r.text
    assert upload(url, key=KEY_A, origin="https://evil.example").status_code == 403
    delete_all(url)


def test_the_upload_cap_holds_under_concurrent_uploads(guarded):
    url, data_dir = guarded
    delete_all(url)
    assert upload(url, key=KEY_A).status_code == 201  # 1 stored, cap 3
    results: list[int] = []
    lock = threading.Lock()
    start = threading.Barrier(8)

    def one():
        start.wait()
        r = upload(url, key=KEY_A)
        with lock:
            results.append(r.status_code)

    threads = [threading.Thread(target=one) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(HANG_GUARD_S)
    assert sorted(results) == [201, 201] + [507] * 6, results
    assert len(stored(url)) == 3
    assert len([p for p in (data_dir / "phantoms").iterdir() if re.fullmatch(r"up-[0-9a-f]{16}", p.name)]) == 3
    delete_all(url)


def _metric(url: str, name: str, labels: str = "") -> float:
    text = httpx.get(f"{url}/metrics", timeout=HANG_GUARD_S).text
    match = re.search(rf"^{re.escape(name)}{re.escape(labels)} (\S+)$", text, flags=re.M)
    return float(match.group(1)) if match else 0.0
