"""A ranging request's budget reaches the estimators' loops: past its deadline it answers 504, and when its
client leaves it is cancelled, at the next chunk of trials. Neither verdict depends on how fast the machine
is: the deadline is tested with an injected clock (a budget whose clock advances one second per check), the
departure with the estimator held on purpose (its checks wait until the budget is cancelled) and a client
that closes its connection once the estimator is at its first check. (Before, these ran a real multi-second
TOA request against a 2 s deadline and a 0.3 s client: a fast machine finished first, a loaded one hit the
deadline before noticing the departure.)"""

from __future__ import annotations

import json
import socket
import threading
import time

import uvicorn
from fastapi.testclient import TestClient

from raytrace.solver.budget import Budget
from service.app import create_app
from service.routes import ranging as route
from tests.conftest import HANG_GUARD_S, free_port

# one path near the latest delay the waveform can hold (13 us at 20 GS/s): about 0.26 M samples per trial;
# 190 trials run in chunks, each followed by a check of the budget
SLOW_TOA = {"profile": {"paths": [{"delay_s": 13e-6 - 40e-9, "gain": {"re": 1e-3, "im": 0.0}}]},
            "method": "gcc", "trials": 190}


class SteppedClock(Budget):
    """A budget whose clock reads one second more at every check."""

    checks = 0

    def charge(self, ray_segments: int = 0) -> None:
        self.checks += 1
        super().charge(ray_segments)

    def elapsed_s(self) -> float:
        return float(self.checks)


class HeldUntilCancelled(Budget):
    """A budget whose every check waits until the budget is cancelled (the work, held on purpose, cannot end
    before its client leaves), then raises as a cancelled budget does."""

    checks = 0

    def charge(self, ray_segments: int = 0) -> None:
        self.checks += 1
        self._cancelled.wait(HANG_GUARD_S)
        super().charge(ray_segments)


def _replace_budget(monkeypatch, kind: type[Budget]) -> list[Budget]:
    made: list[Budget] = []

    def make(*args, **kwargs):
        made.append(kind(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(route, "Budget", make)
    return made


def test_ranging_stops_at_its_deadline(make_settings, monkeypatch):
    made = _replace_budget(monkeypatch, SteppedClock)
    settings = make_settings(load_builtins=False, request_deadline_s=2.0, max_ranging_samples=50_000_000)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        r = client.post("/v1/ranging/toa", json=SLOW_TOA)
    assert r.status_code == 504 and r.json()["detail"][0]["type"] == "deadline_exceeded", r.text[:300]
    assert made[0].checks == 3  # the check that read 3 "seconds" (> 2) stopped it, long before its last chunk


def test_ranging_is_cancelled_when_its_client_leaves(make_settings, monkeypatch):
    made = _replace_budget(monkeypatch, HeldUntilCancelled)
    app = create_app(make_settings(load_builtins=False, max_ranging_samples=50_000_000))
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        _until(lambda: server.started, "the server's start")
        body = json.dumps(SLOW_TOA).encode()
        with socket.create_connection(("127.0.0.1", port), timeout=HANG_GUARD_S) as client:
            client.sendall(b"POST /v1/ranging/toa HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                           + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
            _until(lambda: made and made[0].checks == 1, "the estimator's first check")  # the work is running
        # the client has left (its connection closed) while the estimator waits at its check
        gate, metrics = app.state.capsule.gate, app.state.capsule.metrics
        _until(lambda: gate.admitted == 0, "the computation to stop")
        assert made[0]._cancelled.is_set() and made[0].checks == 1  # stopped at that check, as cancelled
        assert metrics.budget_exceeded.labels("cancelled")._value.get() == 1.0
        assert metrics.budget_exceeded.labels("deadline")._value.get() == 0.0
    finally:
        server.should_exit = True
        thread.join(HANG_GUARD_S)


def _until(predicate, what: str) -> None:
    deadline = time.monotonic() + HANG_GUARD_S  # a hang guard, not a verdict
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"hung waiting for {what}")
        time.sleep(0.01)
