"""Run a sweep into a directory: plan it, run its missing tasks on an engine, store each as it ends.

:func:`run_sweep` is what the CLI (``capsule-rt sweep``) and the service's jobs call::

    summary = run_sweep(spec, "out/", workers=2)              # local pool of 2 processes
    summary = run_sweep(spec, "out/", cluster="tcp://h:8786")  # an existing Dask scheduler
    summary = run_sweep(spec, "out/", resume=True)            # after a crash: only what is missing

A directory holds one sweep (:mod:`sweeps.store`). Starting a sweep in a directory that
already holds one is refused unless ``resume`` is set, and resuming needs the same spec
(its sha256): the plan stored at the first start is reused, the tasks that already have a
part are skipped. Progress goes to ``state.json`` and to ``on_progress(state)`` after
every task. The final state is ``done`` (every task stored, no failure), ``failed``
(failures are listed with their reasons; the rows of every other link are stored),
or ``cancelled``.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import pyarrow as pa

from raytrace.body.library import get_phantom
from raytrace.body.phantom import Phantom
from raytrace.errors import InputError
from sweeps.engines import SerialEngine, make_engine
from sweeps.plan import Plan, make_plan
from sweeps.spec import LIMITS, Limits, SweepSpec, SweepSpecError
from sweeps.store import SweepDir
from sweeps.table import LOCALIZATION_SCHEMA, results_schema, table_from_columns
from sweeps.task import PhantomFiles, PhantomSource, TaskInput, run_task

__all__ = ["MAX_LISTED_FAILURES", "SweepExistsError", "SweepSummary", "open_sweep", "prepare", "run_sweep"]

#: Failures kept in state.json (their total count is always there).
MAX_LISTED_FAILURES = 100


class SweepExistsError(InputError):
    """The output directory already holds a sweep (resume it or choose another directory)."""


@dataclass(frozen=True)
class SweepSummary:
    root: Path
    state: dict
    results: pa.Table
    localization: pa.Table | None


def prepare(spec: SweepSpec, root: str | Path, *, phantom: Phantom | None = None,
            source: PhantomSource | None = None, limits: Limits = LIMITS,
            resume: bool = False) -> tuple[SweepDir, Plan]:
    """Create the sweep directory (plan checked against the phantom), or open it to resume."""
    store = SweepDir(root)
    if store.exists():
        record = store.record()
        if not resume:
            raise SweepExistsError(f"{store.root} already holds a sweep ({record['spec'].get('name') or 'unnamed'}); "
                                   "resume it or choose another output directory", field="out")
        if record["spec_sha256"] != spec.sha256:
            raise SweepSpecError(f"differs from the spec of the sweep stored in {store.root}; a sweep is resumed "
                                 "with its own spec", field="spec")
        store.clean()
        return store, Plan.from_dict(record["plan"])
    source = source or PhantomSource(spec["phantom"])
    if phantom is None:
        phantom = get_phantom(source.id)
    plan = make_plan(spec, phantom, source.id, limits)
    store.create({"spec": spec.to_dict(), "spec_sha256": spec.sha256, "plan": plan.to_dict(),
                  "phantom": {"id": source.id, "glb_path": source.glb_path, "manifest_path": source.manifest_path},
                  "created_at": time.time()})
    store.write_state({"state": "queued", "done": 0, "total": plan.total_traces, "failures": [],
                       "failure_count": 0, "elapsed_s": 0.0, "eta_s": None})
    return store, plan


def open_sweep(root: str | Path) -> tuple[SweepDir, SweepSpec, Plan, PhantomSource]:
    store = SweepDir(root)
    record = store.record()
    return store, SweepSpec(record["spec"]), Plan.from_dict(record["plan"]), PhantomSource(**record["phantom"])


def _task_plan(plan: dict, positions: range) -> dict:
    keys = ("positions_m", "labels", "s_m", "media", "polarizations")
    sub = {k: plan[k][positions.start:positions.stop] for k in keys}
    return {**plan, **sub, "position_indices": list(positions)}


def run_sweep(spec: SweepSpec, root: str | Path, *, phantom: Phantom | None = None,
              source: PhantomSource | None = None, workers: int | None = None, cluster: str | None = None,
              engine: Any = None, resume: bool = False, on_progress: Callable[[dict], None] | None = None,
              cancel: threading.Event | None = None, budget: dict | None = None,
              limits: Limits = LIMITS, tracer_threads: int | None = None) -> SweepSummary:
    """Run (or resume) ``spec`` into ``root`` (module docstring); returns the final state and tables."""
    store, plan = prepare(spec, root, phantom=phantom, source=source, limits=limits, resume=resume)
    record = store.record()
    source = PhantomSource(**record["phantom"])
    return execute(store, SweepSpec(record["spec"]), plan, source, workers=workers, cluster=cluster, engine=engine,
                   on_progress=on_progress, cancel=cancel, budget=budget, tracer_threads=tracer_threads)


def execute(store: SweepDir, spec: SweepSpec, plan: Plan, source: PhantomSource, *, workers: int | None = None,
            cluster: str | None = None, engine: Any = None, on_progress: Callable[[dict], None] | None = None,
            cancel: threading.Event | None = None, budget: dict | None = None,
            tracer_threads: int | None = None) -> SweepSummary:
    """Run the tasks of a prepared sweep that have no part yet (or whose part recorded failures).

    ``tracer_threads``: the tracer's threads per trace; by default 1 on a pool or a cluster (one
    task per worker process: the workers are the parallelism, and a worker's task does not
    compete with its neighbours for the cores) and every CPU in this process (``workers=0``).
    An uploaded phantom's files are shipped to a cluster's workers with the tasks
    (:class:`sweeps.task.PhantomFiles`), not read there."""
    schema = results_schema(spec.methods)
    loc_schema = LOCALIZATION_SCHEMA if spec["localization"] else None
    previous = store.read_state()
    completed = store.completed()
    todo = [t for t in range(plan.n_tasks) if t not in completed or completed[t]]
    for stale in ("results.parquet", "localization.parquet"):
        if todo:
            (store.root / stale).unlink(missing_ok=True)
    per_task = {t: len(plan.task_positions(t)) * len(plan.frequencies_hz) for t in range(plan.n_tasks)}
    failures: dict[int, list[dict]] = {t: f for t, f in completed.items() if t not in todo}
    done_before = sum(per_task[t] for t in failures)
    own_engine = engine is None
    engine = engine or make_engine(workers, cluster)
    started = time.monotonic()
    elapsed_before = float(previous.get("elapsed_s") or 0.0)
    state: dict[str, Any] = {
        "state": "running", "done": done_before, "total": plan.total_traces, "tasks_total": plan.n_tasks,
        "tasks_done": len(failures), "engine": engine.name, "elapsed_s": elapsed_before, "eta_s": None,
        "failures": [], "failure_count": 0, "started_at": previous.get("started_at") or time.time(),
        "finished_at": None, "error": None,
    }
    task_errors: dict[int, dict] = {}

    def publish() -> None:
        listed = [f for t in sorted(failures) for f in failures[t]] + list(task_errors.values())
        state["failures"] = listed[:MAX_LISTED_FAILURES]
        state["failure_count"] = len(listed)
        run_s = time.monotonic() - started
        state["elapsed_s"] = elapsed_before + run_s
        done_now = state["done"] - done_before
        remaining = state["total"] - state["done"]
        state["eta_s"] = (run_s / done_now * remaining) if done_now > 0 and state["state"] == "running" else (
            0.0 if remaining == 0 else None)
        store.write_state(state)
        if on_progress is not None:
            on_progress(dict(state))

    publish()
    record = plan.to_dict()
    if tracer_threads is None and not isinstance(engine, SerialEngine):
        tracer_threads = 1
    inputs = [TaskInput(task=t, spec=spec.to_dict(), plan=_task_plan(record, plan.task_positions(t)),
                        phantom=source, budget=dict(budget or {}), tracer_threads=tracer_threads) for t in todo]
    shared = {"phantom_files": PhantomFiles.read(source)} if engine.remote and source.glb_path and todo else None
    try:
        for i, out in engine.run(run_task, inputs, cancel, shared):
            t = todo[i]
            if isinstance(out, BaseException):
                task_errors[t] = {"task": t, "positions": [plan.labels[p] for p in plan.task_positions(t)],
                                  "reason": f"{type(out).__name__}: {getattr(out, 'reason', None) or out}",
                                  "type": type(out).__name__}
            else:
                table = table_from_columns(out.rows, schema)
                loc = table_from_columns(out.localization, loc_schema) if loc_schema is not None else None
                store.write_part(t, table, out.failures, loc)
                failures[t] = out.failures
                task_errors.pop(t, None)
                state["done"] += per_task[t]
                state["tasks_done"] += 1
            publish()
    except BaseException as exc:
        state["state"] = "failed"
        state["error"] = f"{type(exc).__name__}: {exc}"
        state["finished_at"] = time.time()
        publish()
        raise
    finally:
        if own_engine:
            engine.close()
    cancelled = cancel is not None and cancel.is_set()
    complete = state["tasks_done"] == plan.n_tasks
    if complete:
        store.finalize(schema, loc_schema, plan.n_tasks)
    state["state"] = ("cancelled" if cancelled and not complete
                      else "failed" if task_errors or any(failures.values()) or not complete else "done")
    state["finished_at"] = time.time()
    publish()
    return SweepSummary(store.root, dict(state), store.results(schema, plan.n_tasks),
                        store.localization(loc_schema, plan.n_tasks) if loc_schema is not None else None)
