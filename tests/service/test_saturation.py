"""Admission control over real HTTP: a uvicorn server in a thread, heavy work held on an event.

The computation is replaced by one that blocks until the test releases it, so
"more concurrent requests than slots" is deterministic (no timing; every wait is a hang guard): with 2
slots and a queue of 1, three of six concurrent channel requests are admitted
and three get 503 + Retry-After at once; /healthz and /metrics answer while
the admitted ones are still in flight; released, the admitted ones complete.
"""

from __future__ import annotations

import json
import socket
import threading
import time

import httpx
import pytest
import uvicorn

from service.app import create_app
from service.routes import channel as channel_route
from tests.conftest import HANG_GUARD_S, free_port
from tests.service.test_api import SMALL_CHANNEL


def _wait(predicate, what: str, timeout_s: float = HANG_GUARD_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


@pytest.fixture
def held_server(make_settings, monkeypatch):
    release = threading.Event()
    started = []
    real_trace = channel_route.trace_channel

    def held_trace(spec, phantom=None, *, budget=None, config=None):
        started.append(spec.phantom)
        assert release.wait(HANG_GUARD_S), "test never released the computation"
        return real_trace(spec, phantom, budget=budget, config=config)

    monkeypatch.setattr(channel_route, "trace_channel", held_trace)
    app = create_app(make_settings(max_concurrency=2, max_queue=1, retry_after_s=7))
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    _wait(lambda: server.started, "server start")
    try:
        yield f"http://127.0.0.1:{port}", app, release, started
    finally:
        release.set()
        server.should_exit = True
        thread.join(HANG_GUARD_S)


def test_excess_heavy_requests_get_503_and_health_stays_up(held_server):
    url, app, release, started = held_server
    gate = app.state.capsule.gate
    results: list[httpx.Response] = []
    lock = threading.Lock()

    def fire():
        r = httpx.post(f"{url}/v1/channel", json=SMALL_CHANNEL, timeout=HANG_GUARD_S)
        with lock:
            results.append(r)

    threads = [threading.Thread(target=fire) for _ in range(6)]
    for t in threads:
        t.start()
    # Three admitted (2 running + 1 queued); the three others are refused without waiting.
    _wait(lambda: len(results) == 3 and gate.admitted == 3 and len(started) == 2, "3 refusals, 3 admitted")
    refused = list(results)
    for r in refused:
        assert r.status_code == 503, r.text
        assert r.headers["retry-after"] == "7"
        item = r.json()["detail"][0]
        assert item["type"] == "saturated" and item["loc"] == ["server"] and "retry after 7 s" in item["msg"]

    # The event loop is free: health, readiness and metrics answer while the others are in flight.
    health = httpx.get(f"{url}/healthz", timeout=HANG_GUARD_S)
    assert health.status_code == 200 and health.json() == {"status": "ok"}
    assert gate.admitted == 3 and len(results) == 3  # still in flight when /healthz answered
    metrics = httpx.get(f"{url}/metrics", timeout=HANG_GUARD_S).text
    assert "capsule_rt_compute_in_flight 2.0" in metrics
    assert "capsule_rt_compute_queue_depth 1.0" in metrics
    assert "capsule_rt_compute_rejected_total 3.0" in metrics

    release.set()
    for t in threads:
        t.join(HANG_GUARD_S)
    accepted = [r for r in results if r not in refused]
    assert len(accepted) == 3
    for r in accepted:
        assert r.status_code == 200, r.text
        assert r.json()["stats"]["rays_launched"] == SMALL_CHANNEL["rays"]
    assert gate.admitted == 0
    # Capacity is back: a new request is admitted.
    assert httpx.post(f"{url}/v1/channel", json=SMALL_CHANNEL, timeout=HANG_GUARD_S).status_code == 200


def test_a_client_that_goes_away_cancels_its_computation(make_settings, monkeypatch):
    """The budget of a computation whose client disconnected is cancelled (the tracer then stops itself).
    The client closes its connection once the computation runs (no client timeout races the server)."""
    seen = {}
    cancelled = threading.Event()

    def watching_trace(spec, phantom=None, *, budget=None, config=None):
        seen["budget"] = budget
        if not budget._cancelled.wait(HANG_GUARD_S):
            raise AssertionError("never cancelled")
        cancelled.set()
        budget.charge(0)  # raises BudgetExceededError(kind="cancelled"), as the tracer would

    monkeypatch.setattr(channel_route, "trace_channel", watching_trace)
    app = create_app(make_settings())
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    _wait(lambda: server.started, "server start")
    try:
        body = json.dumps(SMALL_CHANNEL).encode()
        with socket.create_connection(("127.0.0.1", port), timeout=HANG_GUARD_S) as client:
            client.sendall(b"POST /v1/channel HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                           + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
            _wait(lambda: "budget" in seen, "the computation to start")
        assert cancelled.wait(HANG_GUARD_S), "the computation was not cancelled after the client left"
        _wait(lambda: app.state.capsule.gate.admitted == 0, "slot released")
        metrics = httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=HANG_GUARD_S).text
        assert 'capsule_rt_budget_exceeded_total{kind="cancelled"} 1.0' in metrics
    finally:
        server.should_exit = True
        thread.join(HANG_GUARD_S)
