"""Saturation over real HTTP with real heavy traces (no patching).

Eight concurrent channel requests that each take seconds go to a server with
2 slots + 2 queued (the session server, and docker/compose.yaml): every answer
is 200 or 503 with Retry-After, at least one is refused, and /healthz answers
while computations are still in flight (ordering, not durations).
"""

from __future__ import annotations

import os
import threading

import httpx
import pytest

from tests.conftest import HANG_GUARD_S

pytestmark = pytest.mark.e2e

HEAVY = {"scenario": "torso-small-intestine", "rays": 200_000, "max_interactions": 6}


def test_real_saturation(live_url):
    scenarios = httpx.get(f"{live_url}/v1/scenarios", timeout=HANG_GUARD_S).json()["scenarios"]
    assert "torso-small-intestine" in {s["id"] for s in scenarios}
    results: list[httpx.Response] = []
    done = threading.Event()
    lock = threading.Lock()
    n = 8

    def fire():
        r = httpx.post(f"{live_url}/v1/channel", json=HEAVY, timeout=HANG_GUARD_S)
        with lock:
            results.append(r)
            if len(results) == n:
                done.set()

    threads = [threading.Thread(target=fire) for _ in range(n)]
    for t in threads:
        t.start()
    # Wait until the server has refused at least one or is computing, then probe health.
    health = None
    while not done.is_set():
        with lock:
            refused = any(r.status_code == 503 for r in results)
        if refused:
            health = httpx.get(f"{live_url}/healthz", timeout=HANG_GUARD_S)
            break
        done.wait(0.05)
    health_answered_in_flight = health is not None and not done.is_set()
    for t in threads:
        t.join(HANG_GUARD_S)
    assert len(results) == n
    codes = sorted(r.status_code for r in results)
    assert set(codes) <= {200, 503}, codes
    for r in results:
        if r.status_code == 503:
            assert int(r.headers["retry-after"]) >= 1
            assert r.json()["detail"][0]["type"] == "saturated"
        else:
            assert r.json()["stats"]["rays_launched"] == HEAVY["rays"]
    assert codes.count(200) >= 1
    if not os.environ.get("CAPSULE_RT_URL"):  # our server: 2 running + 2 queued < 8
        assert codes.count(503) >= 1, codes
        assert health_answered_in_flight and health.status_code == 200
