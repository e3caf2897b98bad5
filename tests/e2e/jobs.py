"""Waiting on a job of the service (a sweep or a full-wave cross-check) over real HTTP."""

from __future__ import annotations

import time

import httpx


def wait_for_job(http: httpx.Client, path: str, until, timeout_s: float, poll_s: float = 0.1) -> dict:
    """GET ``path`` (a job's status) until ``until(status)`` holds; the status then. Fails the test
    with the last status after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    status: dict = {}
    while time.monotonic() < deadline:
        status = http.get(path).json()
        if until(status):
            return status
        time.sleep(poll_s)
    raise AssertionError(f"{path} never got there: {status}")
