"""The particle tracker of POST /v1/track honours its deadline and a client that left (issue 34, item 7:
it went on for 30 s after either). No wall clock decides anything here: the deadline is tested with an
injected clock (a budget whose clock advances one second per look), the departure by cancelling the
budget at a known step."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from raytrace.errors import BudgetExceededError
from raytrace.solver.budget import Budget
from service.app import create_app
from service.operations.tracking import run_track
from service.routes import tracking as route
from service.schemas.tracking import TrackRequest

COV = [[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-4]]
STEPS = 400


def _body(steps: int = STEPS) -> dict:
    return {"tracker": "particle", "config": {"particles": 200, "seed": 1},
            "observations": [{"t_s": 0.5 * k, "rf": {"position_m": [0.0, 0.02, 0.1], "covariance_m2": COV}}
                             for k in range(steps)]}


class SteppedClock(Budget):
    """A budget whose clock reads one second more at every check (injected: no wall time)."""

    checks = 0

    def charge(self, ray_segments: int = 0) -> None:
        self.checks += 1
        super().charge(ray_segments)

    def elapsed_s(self) -> float:
        return float(self.checks)


def test_a_particle_track_past_its_deadline_answers_504(make_settings, monkeypatch):
    budgets: list[SteppedClock] = []

    def make(*args, **kwargs):
        budgets.append(SteppedClock(*args, **kwargs))
        return budgets[-1]

    monkeypatch.setattr(route, "Budget", make)
    with TestClient(create_app(make_settings(request_deadline_s=50.0)), raise_server_exceptions=False) as client:
        r = client.post("/v1/track", json=_body())
    assert r.status_code == 504 and r.json()["detail"][0]["type"] == "deadline_exceeded", r.text[:300]
    # it stopped at the first check past 50 "seconds": the route's own, then 50 steps of 400
    assert budgets[0].checks == 51


class LeavesAt(Budget):
    """A budget whose client leaves (the gate cancels it) at its ``k``-th check."""

    k = 0
    checks = 0

    def charge(self, ray_segments: int = 0) -> None:
        self.checks += 1
        if self.checks == self.k:
            self.cancel()
        super().charge(ray_segments)


def test_a_particle_track_stops_when_its_client_leaves(make_settings):
    from service.registry import Registry
    from service.storage import PhantomStore

    registry = Registry(store=PhantomStore(make_settings().data_dir))
    registry.load_builtins(True)
    budget = LeavesAt()
    budget.k = 31
    req = TrackRequest.model_validate(_body())
    with pytest.raises(BudgetExceededError) as info:
        run_track(req, registry, budget, make_settings())
    assert info.value.kind == "cancelled"
    assert budget.checks == 31  # the route's own check before the track, then 30 steps of 400
