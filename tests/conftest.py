"""Shared test fixtures (generic: any test module may use them), and CI's no-skip rule.

* ``make_settings`` -- a :class:`service.settings.Settings` factory with a private data dir.
* ``api`` -- an in-process ``TestClient`` over ``create_app`` (small limits).
* ``live_url`` -- base URL of a real uvicorn server: ``CAPSULE_RT_URL`` when set
  (the client container), else a subprocess on 127.0.0.1 and a free port,
  started once per session (per pytest-xdist worker: each worker has its own).
  A ``CAPSULE_RT_URL`` server that requires an API key gets ``CAPSULE_RT_KEY`` with
  every write the suite sends it.
* ``glb_phantom`` -- builds a small valid (or deliberately broken) .glb + manifest.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

REPO = Path(__file__).resolve().parent.parent

#: How long a test waits for something (a server to be ready, a job state, a response, a process to go)
#: before it calls itself hung [s]. A hang guard, never a verdict on speed: far beyond what any healthy run
#: takes on a loaded 2-core machine (the slowest single wait measured there is a few minutes), so a busy
#: machine never fails a test that a quiet one passes. Deadlines themselves are tested with injected clocks
#: or work held on purpose (docs: tests never judge speed).
HANG_GUARD_S = 900.0


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """In CI (``CAPSULE_RT_CI=1``, set by ``.ci/run``) a skipped test is a failure: what CI
    needs it installs, so a skip there would hide a missing tool or a broken import."""
    outcome = yield
    report = outcome.get_result()
    if os.environ.get("CAPSULE_RT_CI") == "1" and report.skipped and not hasattr(report, "wasxfail"):
        report.outcome = "failed"
        report.longrepr = f"skipped in CI, where nothing may skip: {report.longrepr}"


@pytest.fixture
def make_settings(tmp_path):
    from service.settings import Settings

    def make(**overrides):
        values = {"data_dir": tmp_path / "data", "log_level": "warning", "max_rays": 5000}
        values.update(overrides)
        return Settings(**values)

    return make


@pytest.fixture
def api(make_settings):
    """In-process client of an app with small limits (rays <= 5000)."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(make_settings()), raise_server_exceptions=False) as client:
        yield client


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_ready(url: str, timeout_s: float = HANG_GUARD_S, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"server exited with code {proc.returncode}")
        try:
            if httpx.get(f"{url}/readyz", timeout=HANG_GUARD_S).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"server at {url} not ready after {timeout_s} s")


def _send_key_to(url: str, key: str) -> None:
    """Every write (POST, PUT, PATCH, DELETE) this process sends to ``url`` without an
    ``X-API-Key`` header gets ``key`` in it, as a user's client configured with the key would
    send it: the server container of CI requires one (docker/podman-ci.sh). Only ``url``: the
    tests of keys start servers of their own and send (or omit) keys themselves."""
    from service.security import API_KEY_HEADER

    def with_key(send):
        def handle(self, request):
            if str(request.url).startswith(url + "/") and request.method in ("POST", "PUT", "PATCH", "DELETE") \
                    and API_KEY_HEADER not in request.headers:
                request.headers[API_KEY_HEADER] = key
            return send(self, request)
        return handle

    httpx.HTTPTransport.handle_request = with_key(httpx.HTTPTransport.handle_request)
    httpx.AsyncHTTPTransport.handle_async_request = with_key(httpx.AsyncHTTPTransport.handle_async_request)


@pytest.fixture(scope="session")
def live_url(tmp_path_factory):
    """A running server: ``CAPSULE_RT_URL`` if set, else ``capsule-rt serve`` in a subprocess."""
    url = os.environ.get("CAPSULE_RT_URL")
    if url:
        url = url.rstrip("/")
        wait_ready(url)
        if os.environ.get("CAPSULE_RT_KEY"):
            _send_key_to(url, os.environ["CAPSULE_RT_KEY"])
        yield url
        return
    port = free_port()
    data_dir = tmp_path_factory.mktemp("live-data")
    log_path = tmp_path_factory.mktemp("live-log") / "server.log"
    env = {
        **os.environ,
        "CAPSULE_RT_DATA_DIR": str(data_dir),
        "CAPSULE_RT_MAX_CONCURRENCY": "2",
        "CAPSULE_RT_MAX_QUEUE": "2",
        "CAPSULE_RT_LOG_LEVEL": "warning",
    }
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1", "--port", str(port)],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(url, proc=proc)
    except RuntimeError:
        proc.kill()
        raise RuntimeError(f"live server failed; log:\n{log_path.read_text()[-4000:]}")
    yield url
    proc.terminate()
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


# ---------------------------------------------------------------- test phantoms
def nested_phantom_meshes(kind: str = "ok"):
    """Meshes of a small two-organ phantom: a 0.2 m muscle box holding a fat sphere.

    ``kind``: ``ok``; ``open`` (the sphere has a hole: not watertight);
    ``intersecting`` (the sphere pokes out of the box).
    """
    import trimesh

    body = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    organ = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    if kind == "open":
        organ = trimesh.Trimesh(organ.vertices, organ.faces[1:], process=False)
    elif kind == "intersecting":
        organ.apply_translation([0.09, 0.0, 0.0])
    return {"body": body, "organ": organ}


def glb_bytes(meshes: dict) -> bytes:
    import trimesh

    scene = trimesh.Scene()
    for name, mesh in meshes.items():
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    return scene.export(file_type="glb")


def phantom_manifest(**overrides) -> dict:
    manifest = {
        "name": "test box",
        "units": "m",
        "organs": {"body": {"tissue": "muscle"},
                   "organ": {"relative_permittivity": 11.6, "conductivity_s_per_m": 0.08}},
        "sites": {"capsule": {"kind": "capsule", "position_m": [0.0, 0.0, 0.01]}, "sensor": [0.0, -0.15, 0.0]},
    }
    manifest.update(overrides)
    return manifest


@pytest.fixture
def glb_phantom():
    """``glb_phantom(kind="ok") -> (glb_bytes, manifest_dict)``."""

    def make(kind: str = "ok", **manifest_overrides):
        return glb_bytes(nested_phantom_meshes(kind)), phantom_manifest(**manifest_overrides)

    return make
