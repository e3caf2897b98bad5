"""Issue 25, item 1: a channel request's memory and work are estimated before any work, refused with a
422 naming the field when they cannot fit, and counted while the trace runs (docs/service.md, "Memory
and work model of a channel request")."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import threading
from dataclasses import replace

import pytest

from raytrace.errors import BudgetExceededError
from raytrace.scenarios import get_scenario
from raytrace.solver.budget import Budget
from raytrace.solver.footprint import estimate
from raytrace.solver.tracer import trace_channel
from raytrace.spec import Band
from tests.conftest import HANG_GUARD_S
from tests.service.test_api import assert_field

TORSO = get_scenario("torso-stomach").spec


def test_the_estimate_grows_with_every_knob_it_names():
    """Each knob the model reads raises the estimate where it binds (the dynamic range where it, not
    max_interactions, limits the ray tree's depth), and the estimate is deterministic."""
    small = {"rays": 20_000, "max_interactions": 6, "dynamic_range_db": 60.0}
    base = estimate(replace(TORSO, **small))
    for knob in ({"rays": 40_000}, {"max_interactions": 8}, {"dynamic_range_db": 160.0},
                 {"receivers": tuple(replace(r, name=f"{r.name}_{k}") for k in (0, 1) for r in TORSO.receivers)}):
        bigger = estimate(replace(TORSO, **{**small, **knob}))
        assert bigger.peak_bytes > base.peak_bytes, knob
    assert estimate(replace(TORSO, **small)) == base
    banded = estimate(replace(TORSO, **small, band=Band(start_hz=380e6, stop_hz=420e6, points=201)))
    assert banded.band_bytes > 0 == base.band_bytes and banded.largest_field() == "band.points"


def test_the_audits_request_is_refused_before_any_work(make_settings):
    """1e6 rays x 10 interactions x 12 sensors (within every per-field limit) ran 7-8 s to a 503 "work
    budget exceeded"; now a 422 naming rays, and no segment traced (the metrics say so)."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    settings = make_settings(max_rays=1_000_000)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        body = {"scenario": "torso-stomach", "rays": 1_000_000, "max_interactions": 10}
        r = client.post("/v1/channel", json=body)
        assert_field(r, 422, "body", "rays")
        assert "work budget" in r.json()["detail"][0]["msg"]
        body = {"scenario": "torso-stomach", "rays": 100_000, "max_interactions": 10, "dynamic_range_db": 300,
                "band": {"start_hz": 380e6, "stop_hz": 420e6, "points": 201}}
        r = client.post("/v1/channel", json=body)
        assert_field(r, 422, "body", "band", "points")
        assert "MiB" in r.json()["detail"][0]["msg"]
        metrics = client.get("/metrics").text
        segments = [line for line in metrics.splitlines() if line.startswith("capsule_rt_ray_segments_traced_total")]
        assert segments and all(float(line.split()[-1]) == 0.0 for line in segments), segments


def test_a_trace_past_its_memory_budget_stops_cleanly():
    """The safety net when the estimate is wrong: the tracer counts what it allocates."""
    spec = replace(TORSO, rays=20_000, max_interactions=8, dynamic_range_db=160.0)
    budget = Budget(max_bytes=2 * 2**20)
    with pytest.raises(BudgetExceededError) as info:
        trace_channel(spec, budget=budget)
    assert info.value.kind == "memory" and "memory budget exceeded" in info.value.reason
    counted = Budget()
    trace_channel(replace(spec, rays=2000), budget=counted)
    assert counted.peak_bytes > 0


#: The worker: an app with a memory ceiling, measured by its own peak RSS (VmHWM, reset through
#: /proc/self/clear_refs before each request).
WORKER = textwrap.dedent("""
    import json, os, sys
    from fastapi.testclient import TestClient
    from service.app import create_app
    from service.settings import Settings

    def hwm_bytes(key="VmHWM"):
        for line in open("/proc/self/status"):
            if line.startswith(key):
                return int(line.split()[1]) * 1024

    settings = Settings(data_dir=sys.argv[1], log_level="warning", max_concurrency=1, tracer_threads=2,
                        max_compute_memory_bytes=int(sys.argv[2]))
    out = []
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        for body in json.loads(sys.argv[3]):
            client.get("/healthz")
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")  # VmHWM := VmRSS
            base = hwm_bytes("VmRSS")
            r = client.post("/v1/channel", json=body)
            out.append({"status": r.status_code, "peak_above_base": hwm_bytes() - base, "body": r.json()})
    print(json.dumps(out))
""")


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's /proc peak-RSS reset")
def test_the_largest_allowed_request_fits_the_ceiling_or_is_refused_first(tmp_path):
    """Acceptance (issue 25): with a 1 GiB ceiling, the largest request every per-field limit allows is
    refused before any tracing (its worker's peak RSS barely moves), and the largest one the estimate
    admits (12 sensors, 10 interactions, 300 dB: the most rays under the ceiling) completes under it."""
    ceiling = 2**30
    largest = {"scenario": "torso-stomach", "rays": 1_000_000, "max_interactions": 10, "dynamic_range_db": 300,
               "receivers": [{"site": s} for s in ("belt_0", "belt_1")] * 32,
               "band": {"start_hz": 380e6, "stop_hz": 420e6, "points": 201}}
    lo, hi = 1000, 1_000_000  # the most rays whose estimate fits (bisection on the same estimate the server uses)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        fits = estimate(replace(TORSO, rays=mid, max_interactions=10, dynamic_range_db=300.0)).peak_bytes <= ceiling
        lo, hi = (mid, hi) if fits else (lo, mid)
    admitted = {"scenario": "torso-stomach", "rays": lo, "max_interactions": 10, "dynamic_range_db": 300}
    run = subprocess.run([sys.executable, "-c", WORKER, str(tmp_path / "data"), str(ceiling),
                          json.dumps([largest, admitted])], capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert run.returncode == 0, run.stderr[-3000:]
    refused, done = json.loads(run.stdout.strip().splitlines()[-1])
    assert refused["status"] == 422, refused
    # before any tracing: a trace's arrays alone are hundreds of MB; a refusal allocates next to nothing
    assert refused["peak_above_base"] < 64 * 2**20, refused["peak_above_base"]
    assert done["status"] == 200, str(done["body"])[:500]
    assert done["body"]["stats"]["rays_launched"] == lo
    assert 0 < done["peak_above_base"] <= ceiling, (lo, done["peak_above_base"])


def test_channel_bodies_are_decoded_off_the_loop_while_healthz_answers(api, monkeypatch):
    """While a channel body is being decoded (held in its worker thread until /healthz has answered),
    the event loop serves /healthz: ordering, not timing."""
    import service.bodies as bodies

    healthz_done = threading.Event()
    decode_saw = []
    real = bodies.decode

    def slow_decode(model, body):
        decode_saw.append(healthz_done.wait(timeout=HANG_GUARD_S))  # on the loop this would block /healthz: a deadlock
        return real(model, body)

    monkeypatch.setattr(bodies, "decode", slow_decode)
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("r", api.post(
        "/v1/channel", json={"scenario": "half-space", "rays": 2000})))
    worker.start()
    while not decode_saw and worker.is_alive() and not healthz_done.is_set():
        if api.get("/healthz").status_code == 200:
            healthz_done.set()
    worker.join(timeout=HANG_GUARD_S)
    assert healthz_done.is_set() and decode_saw == [True]
    assert result["r"].status_code == 200, result["r"].text
