"""Sensor-layout design speed (reported, never asserted; docs/design.md, "Cost").

    python -m bench.design [--candidates-spacing-m 0.0115] [--positions 35] [--coverage DIR]

* Coverage: one capsule position of the default torso traced to every skin candidate in one trace,
  plus its ranging column and seven travel-time fields, in CPU seconds (process time: every thread
  of this process), split into its parts (shares of the position, each timed in this run), against
  the reference measured in the same run: single-receiver channel requests to a few of the same
  candidates (what a coverage without reuse would cost per candidate). The whole tract's estimate is
  the per-position time x positions / cores.
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
    """One position's coverage CPU, split into its parts, each timed in this run: the trace to every
    candidate, the ranging column (noiseless GCC per link), the seven travel-time fields, the Parquet
    part; the reference is single-receiver requests to a few of the same candidates. Also the same
    trace under ``TracerConfig(zoom_levels=12)`` (an input for the tracer's owners: the direct-path
    zoom's share of the trace, and whether its last 12 levels change any row)."""
    import dataclasses

    import pyarrow as pa

    from design.coverage import SCHEMA, ranging_delay_s, waveform_of
    from design.model import link_model
    from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
    from evaluation.fields import index_grid
    from sweeps.store import parquet_bytes

    phantom = default_torso()
    spec = normalise_spec({"positions": {"along_tract": {"ds_m": 0.02}}, "candidates": {"spacing_m": spacing_m}})
    cands = skin_candidates(phantom, CandidateSpec(spacing_m=spacing_m))
    pos = resolve_positions(phantom, spec["positions"])
    p = len(pos) // 2
    x = pos.positions_m[p]
    plan = Plan("torso", pos, cands, len(cands))
    task = PositionTask(p, spec, plan.to_dict(), PhantomSource("torso"))
    rt.trace_channel(channel_spec(spec, "torso", x, cands.positions_m[:1]), phantom)  # warm the kernels
    index_grid(phantom, spec["frequency_hz"], spec["cell_size_m"], "phase")  # once per worker process: not counted

    def cpu(fn):
        c0 = time.process_time()
        out = fn()
        return time.process_time() - c0, out

    full = channel_spec(spec, "torso", x, cands.positions_m)
    t_trace, result = cpu(lambda: rt.trace_channel(full, phantom))
    v = velocity_m_per_s(DEFAULT_RELATIVE_PERMITTIVITY)
    wf = waveform_of(spec)
    t_ranging, _ = cpu(lambda: [ranging_delay_s(q.paths, spec["frequency_hz"], wf, v) for q in result.profiles
                                if q.paths])
    t_fields, _ = cpu(lambda: link_model(phantom, x[None, :], cands.positions_m, spec["frequency_hz"],
                                         spec["cell_size_m"]))
    c0, t0 = time.process_time(), time.perf_counter()
    columns = position_columns(task, phantom)
    t_position, wall = time.process_time() - c0, time.perf_counter() - t0
    t_write, _ = cpu(lambda: parquet_bytes(pa.table(columns, schema=SCHEMA)))
    picks = np.linspace(0, len(cands) - 13, singles).astype(int)
    c0 = time.process_time()
    for c in picks:
        rt.trace_channel(channel_spec(spec, "torso", x, cands.positions_m[c:c + 1]), phantom)
    single = (time.process_time() - c0) / singles
    cfg = dataclasses.replace(rt.TracerConfig(), zoom_levels=12)
    t_zoom12, fewer = cpu(lambda: rt.trace_channel(full, phantom, config=cfg))
    same = all(len(a.paths) == len(b.paths) and all(pa_.delay_s == pb.delay_s for pa_, pb in zip(a.paths, b.paths))
               for a, b in zip(result.profiles, fewer.profiles))
    cores = len(os.sched_getaffinity(0))
    return {"candidates": len(cands), "positions_of_the_tract": len(pos), "position_cpu_s": t_position,
            "position_wall_s": wall, "per_candidate_cpu_ms": 1e3 * t_position / len(cands),
            "share_trace": t_trace / t_position, "share_ranging": t_ranging / t_position,
            "share_fields": t_fields / t_position, "share_parquet": t_write / t_position,
            "single_request_cpu_ms": 1e3 * single, "reuse_gain": single * len(cands) / t_position,
            "trace_zoom_levels_12_over_default": t_zoom12 / t_trace, "zoom_levels_12_same_delays": same,
            "tract_estimate_min": t_position * positions / cores / 60.0, "cores": cores}


def layout_cost(coverage: str | None, candidates: int, positions: int, sensors: int = 8) -> dict:
    if coverage:
        from design.layout import normalise_layout, problem_of

        record, plan, table = load(coverage)
        arrays = link_arrays(table, len(plan.positions), len(plan.candidates))
        from design.layout import stated_grid_error_s

        problem = problem_of(normalise_layout({"sensors": sensors}), record["spec"], plan, arrays, 0.67,
                             stated_grid_error_s(default_torso(), record["spec"]))
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
