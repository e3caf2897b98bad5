"""A real ``capsule-rt serve`` for the job flows (sweeps, full-wave cross-checks), and waiting on a job."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import httpx

from service.client import Client
from tests.conftest import HANG_GUARD_S, REPO, free_port, wait_ready


class JobServer:
    """The service in a child process on 127.0.0.1 with ``data_dir`` and extra environment ``env``
    (settings), logging to ``log``; ``http`` a raw client, ``api`` the typed one."""

    def __init__(self, data_dir: Path, log: Path, env: dict[str, str]) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        environ = {**os.environ, "CAPSULE_RT_DATA_DIR": str(data_dir), "CAPSULE_RT_LOG_LEVEL": "warning", **env}
        with open(log, "ab") as fh:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port)],
                cwd=REPO, env=environ, stdout=fh, stderr=subprocess.STDOUT)
        wait_ready(self.url, proc=self.proc)
        self.http = httpx.Client(base_url=self.url, timeout=HANG_GUARD_S)
        self.api = Client(self.url, timeout=HANG_GUARD_S)

    def stop(self) -> None:
        self.http.close()
        self.api.close()
        self.proc.terminate()  # a graceful stop: what the tests check after it needs it to finish
        try:
            self.proc.wait(timeout=HANG_GUARD_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def wait_for_job(http: httpx.Client, path: str, until, timeout_s: float = HANG_GUARD_S, poll_s: float = 0.1) -> dict:
    """GET ``path`` (a job's status) until ``until(status)`` holds; the status then. Fails the test
    with the last status after ``timeout_s`` (a hang guard, tests.conftest.HANG_GUARD_S)."""
    deadline = time.monotonic() + timeout_s
    status: dict = {}
    while time.monotonic() < deadline:
        status = http.get(path).json()
        if until(status):
            return status
        time.sleep(poll_s)
    raise AssertionError(f"{path} never got there: {status}")
