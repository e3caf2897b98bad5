"""Sensor-layout design speed (reported, never asserted; docs/design.md, "Cost").

    python -m bench.design [--candidates-spacing-m 0.0115] [--positions 35] [--coverage DIR]

* Coverage: one capsule position of the default torso traced to every skin candidate in one trace,
  plus its seven travel-time fields, in CPU seconds (process time: every thread of this process),
  against the reference measured in the same run: single-receiver channel requests to a few of the
  same candidates (what a coverage without reuse would cost per candidate). The whole tract's
  estimate is the per-position time x positions / cores.
* Layout: the search (greedy + swaps, 4 restarts) of 8 sensors over the candidates of a coverage
  directory (``--coverage``), or over a synthetic problem of the same size (random gradients and
  SNRs) when none is given, in CPU seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

import raytrace as rt
from design.candidates import CandidateSpec, skin_candidates
from design.coverage import Plan, PositionTask, channel_spec, link_arrays, load, normalise_spec, position_columns
from design.criterion import Problem
from design.optimize import Constraints, search
from design.positions import resolve_positions
from raytrace.body.torso import default_torso
from sweeps.task import PhantomSource


def coverage_cost(spacing_m: float, positions: int, singles: int = 4) -> dict:
    phantom = default_torso()
    spec = normalise_spec({"positions": {"along_tract": {"ds_m": 0.02}}, "candidates": {"spacing_m": spacing_m}})
    cands = skin_candidates(phantom, CandidateSpec(spacing_m=spacing_m))
    pos = resolve_positions(phantom, spec["positions"])
    p = len(pos) // 2
    plan = Plan("torso", pos, cands, len(cands))
    task = PositionTask(p, spec, plan.to_dict(), PhantomSource("torso"))
    rt.trace_channel(channel_spec(spec, "torso", pos.positions_m[p], cands.positions_m[:1]), phantom)  # warm
    c0, t0 = time.process_time(), time.perf_counter()
    position_columns(task, phantom)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    picks = np.linspace(0, len(cands) - 13, singles).astype(int)
    c0 = time.process_time()
    for c in picks:
        rt.trace_channel(channel_spec(spec, "torso", pos.positions_m[p], cands.positions_m[c:c + 1]), phantom)
    single = (time.process_time() - c0) / singles
    cores = len(os.sched_getaffinity(0))
    return {"candidates": len(cands), "positions_of_the_tract": len(pos), "position_cpu_s": cpu,
            "position_wall_s": wall, "per_candidate_cpu_ms": 1e3 * cpu / len(cands),
            "single_request_cpu_ms": 1e3 * single, "reuse_gain": single * len(cands) / cpu,
            "tract_estimate_min": cpu * positions / cores / 60.0, "cores": cores}


def layout_cost(coverage: str | None, candidates: int, positions: int, sensors: int = 8) -> dict:
    if coverage:
        from design.layout import normalise_layout, problem_of

        record, plan, table = load(coverage)
        arrays = link_arrays(table, len(plan.positions), len(plan.candidates))
        problem = problem_of(normalise_layout({"sensors": sensors}), record["spec"], plan, arrays, 0.67)
        site = np.array([bool(s) for s in plan.candidates.site])
        cons = Constraints(~site, plan.candidates.positions_m)
    else:
        rng = np.random.default_rng(0)
        g = rng.normal(size=(positions, candidates, 3))
        g *= 2.6e-8 / np.linalg.norm(g, axis=2, keepdims=True)
        usable = rng.random((positions, candidates)) > 0.2
        sigma = 1e-12 * 10 ** (rng.random((positions, candidates)))
        problem = Problem(np.where(usable[:, :, None], g / sigma[:, :, None], 0.0), usable, "p90", 4, 0.67)
        cons = Constraints(np.ones(candidates, bool), rng.normal(size=(candidates, 3)))
    c0 = time.process_time()
    result = search(problem, cons, sensors, restarts=4, seed=0, exact_limit=0)
    return {"positions": problem.positions, "candidates": int(cons.allowed.sum()), "sensors": sensors,
            "search_cpu_s": time.process_time() - c0, "evaluations": result.evaluations, "swaps": result.swaps}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates-spacing-m", type=float, default=0.0115)
    ap.add_argument("--positions", type=int, default=35)
    ap.add_argument("--coverage", default=None)
    args = ap.parse_args()
    with open("/proc/loadavg") as fh:
        load_avg = fh.read().split()[:3]
    out = {"load_average": load_avg, "coverage": coverage_cost(args.candidates_spacing_m, args.positions)}
    out["layout"] = layout_cost(args.coverage, out["coverage"]["candidates"], args.positions)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
