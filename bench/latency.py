"""Channel request latency on the default torso: in-process and over HTTP.

In-process: ``trace_channel`` called directly (the service's work without
HTTP/JSON). Over HTTP: a real ``capsule-rt serve`` subprocess on 127.0.0.1;
cold start = process start until ``/readyz`` answers 200; cold request = the
first channel request; then p50/p95 over repeated requests.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import httpx
import numpy as np

from bench import scenes
from bench.common import ROOT, percentiles, timed


def in_process(repeat: int, rays: int, interactions: int) -> dict:
    """Wall and CPU time (every thread) of the one-receiver and the all-sensor request, their
    repeats interleaved (one, all, one, all, ...) so that the machine's drift hits both alike."""
    phantom = scenes.torso()
    tx = scenes.transmitter(phantom)
    rx_all = scenes.receivers(phantom)
    t0 = time.perf_counter()
    scenes.trace(phantom, tx, rx_all, 402e6, rays=rays, max_interactions=interactions)
    cold = time.perf_counter() - t0
    walls = {"one": [], "all": []}
    cpus = {"one": [], "all": []}
    for _ in range(repeat):
        for key, rx in (("one", rx_all[:1]), ("all", rx_all)):
            w0, c0 = time.perf_counter(), time.process_time()
            scenes.trace(phantom, tx, rx, 402e6, rays=rays, max_interactions=interactions)
            walls[key].append(time.perf_counter() - w0)
            cpus[key].append(time.process_time() - c0)
    out = {"cold_first_trace_s": cold, "receivers": len(rx_all)}
    for key, name in (("one", "one_receiver"), ("all", "all_sensor_sites")):
        out[name] = {**percentiles(np.array(walls[key])), "cpu_p50_s": float(np.median(cpus[key])),
                     "cpu_min_s": float(np.min(cpus[key]))}
    return out


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def over_http(repeat: int, rays: int, interactions: int) -> dict:
    phantom = scenes.torso()
    capsule = scenes.capsule_site(phantom)
    sensors = scenes.sensor_sites(phantom)
    port = _free_port()
    env = dict(os.environ, CAPSULE_RT_PORT=str(port), CAPSULE_RT_HOST="127.0.0.1")
    exe = os.path.join(os.path.dirname(sys.executable), "capsule-rt")
    t0 = time.perf_counter()
    proc = subprocess.Popen([exe, "serve", "--host", "127.0.0.1", "--port", str(port)], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        with httpx.Client(base_url=base, timeout=120.0) as client:
            while True:
                try:
                    if client.get("/readyz").status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                if proc.poll() is not None or time.perf_counter() - t0 > 120:
                    raise RuntimeError("server did not become ready")
                time.sleep(0.05)
            cold_start = time.perf_counter() - t0

            def request(receivers):
                body = {"phantom": "torso", "frequency_hz": 402e6, "transmitter": {"site": capsule},
                        "receivers": [{"site": s} for s in receivers], "rays": rays,
                        "max_interactions": interactions}
                r = client.post("/v1/channel", json=body)
                r.raise_for_status()

            t1 = time.perf_counter()
            request(sensors)
            cold_request = time.perf_counter() - t1
            one = timed(lambda: request(sensors[:1]), repeat)
            every = timed(lambda: request(sensors), repeat)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return {"cold_start_s": cold_start, "cold_first_request_s": cold_request,
            "one_receiver": percentiles(one), "all_sensor_sites": percentiles(every)}
