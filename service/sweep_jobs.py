"""Sweep jobs (``sw-`` + 16 hex) on the service's one job queue (:mod:`service.jobs`).

Each job is a sweep directory (:mod:`sweeps.store`) under ``<data_dir>/sweeps/`` named by its id.
A job that was ``running`` when the process died is resumed: only its missing tasks run again.
The tasks run in worker processes (a local ``spawn`` pool of ``sweep_workers`` processes kept warm
between jobs, or the Dask scheduler at ``sweep_cluster``), never on the event loop nor in the
server's threads. Every job is validated (spec and plan, against the phantom) before its 202.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from raytrace.spec import Antenna
from service import costs
from service.admission import Cost
from service.errors import NotFound
from service.jobs import CANCEL_FILE, JobKind, JobRunner
from service.registry import Registry
from service.settings import Settings
from service.storage import is_upload_id
from service.workers import register
from sweeps.engines import make_engine
from sweeps.run import execute, open_sweep, prepare
from sweeps.spec import LIMITS, Limits, SweepSpec
from sweeps.store import SweepDir
from sweeps.table import LOCALIZATION_SCHEMA, results_schema, to_csv_bytes, to_json_bytes
from sweeps.task import PhantomSource

log = logging.getLogger("capsule_rt.jobs")


def limits_for(settings: Settings) -> Limits:
    """The sweep limits of this server: the request limits of its settings (a trace's work and memory
    caps too, which :meth:`SweepJobs.estimate` admits through the service's one rule before the plan
    would check them: the same footprint model and caps, so the plan never refuses what was admitted)."""
    return Limits(max_positions=LIMITS.max_positions, max_receivers=settings.max_receivers,
                  max_traces=settings.sweep_max_traces, max_rays=settings.max_rays,
                  max_interactions=settings.max_interactions, max_band_points=settings.max_band_points,
                  max_trials=settings.max_trials, max_ray_segments=settings.max_ray_segments,
                  max_trace_bytes=settings.compute_memory_share_bytes)


#: A trace's footprint fields (service.costs.channel) as the sweep spec's.
_TRACE_FIELDS = {"rays": ("channel", "rays"), "max_interactions": ("channel", "max_interactions"),
                 "band.points": ("channel", "band", "points"), "receivers": ("receivers",)}


class SweepJobs(JobKind):
    kind = "sweep"
    prefix = "sw-"
    noun = "sweep"
    list_path = "/v1/sweeps"
    id_loc = ["path", "sweep_id"]

    def __init__(self, settings: Settings, registry: Registry, runner: JobRunner) -> None:
        super().__init__(runner, settings, Path(settings.data_dir) / "sweeps", settings.sweep_max_queue)
        self.registry = registry
        self.limits = limits_for(settings)
        self._engine = None

    # ------------------------------------------------------------ the queue's hooks
    def exists(self, d: Path) -> bool:
        return SweepDir(d).exists()

    def read_state(self, d: Path) -> dict[str, Any]:
        return SweepDir(d).read_state()

    def write_state(self, d: Path, state: dict[str, Any]) -> None:
        SweepDir(d).write_state(state)

    def created_at(self, d: Path) -> float:
        return SweepDir(d).record().get("created_at") or 0

    def close(self) -> None:
        if self._engine is not None:
            self._engine.close()
            self._engine = None

    # ------------------------------------------------------------ API
    def submit(self, data: Any, owner: str | None = None) -> dict[str, Any]:
        """Validate and plan a spec, store the job ``queued`` (owned by ``owner``, the submitting key's id);
        its status. Runs in a worker thread."""
        spec = SweepSpec.from_dict(data, self.limits)
        phantom_id = spec["phantom"]
        phantom = self.registry.get(phantom_id, field_loc=["body", "phantom"])
        source = PhantomSource(phantom_id)
        if is_upload_id(phantom_id):
            d = self.registry.store.root / phantom_id
            source = PhantomSource(phantom_id, str(d / "mesh.glb"), str(d / "manifest.json"))

        def build(tmp: Path) -> None:
            prepare(spec, tmp, phantom=phantom, source=source, limits=self.limits)

        sweep_id = self.create(self.estimate((spec, phantom)), build, owner)
        log.info("sweep queued", extra={"sweep": sweep_id, "phantom": phantom_id})
        return self.status(sweep_id)

    def estimate(self, validated: tuple[SweepSpec, Any]) -> Cost:
        """A sweep's cost: each trace (one at a time per worker) against the work budget and one
        computation's memory share, as a channel request's (:func:`service.costs.channel`, fields renamed
        to the spec's). The number of traces is the spec's own limit (``sweep_max_traces``)."""
        spec, phantom = validated
        if spec["receivers"] == "sensors":
            receivers = tuple(Antenna(site=n, name=n) for n, s in phantom.sites.items() if s.kind == "sensor")
        else:
            receivers = tuple(Antenna.from_dict(r) for r in spec["receivers"])
        tx = Antenna(position_m=np.zeros(3))  # the footprint depends on the knobs and the counts only
        per_frequency = [costs.channel(spec.channel_spec(tx, receivers or (tx,), f, spec["phantom"]), self.settings,
                                       _TRACE_FIELDS) for f in spec["frequencies_hz"]]
        return max(per_frequency, key=lambda c: c.memory_bytes)

    def status(self, sweep_id: str) -> dict[str, Any]:
        store = SweepDir(self.job_dir(sweep_id))
        record = store.record()
        state = store.read_state()
        out = {
            "id": sweep_id, "name": record["spec"].get("name", ""), "phantom": record["spec"]["phantom"],
            "state": state.get("state", "queued"), "done": state.get("done", 0),
            "total": state.get("total", 0), "tasks_done": state.get("tasks_done", 0),
            "tasks_total": state.get("tasks_total") or -(-len(record["plan"]["labels"])
                                                         // record["plan"]["chunk_positions"]),
            "elapsed_s": float(state.get("elapsed_s") or 0.0), "eta_s": state.get("eta_s"),
            "failures": [{**f, "reason": self.redact(f.get("reason"), store.root)} for f in state.get("failures", [])],
            "failure_count": state.get("failure_count", 0), "engine": state.get("engine"),
            "error": self.redact(state.get("error"), store.root), "created_at": record.get("created_at"),
            "started_at": state.get("started_at"), "finished_at": state.get("finished_at"),
            "cancel_requested": (store.root / CANCEL_FILE).exists(),
        }
        if out["state"] == "running" and state.get("updated_at"):  # elapsed up to now, not to the last task
            out["elapsed_s"] += max(0.0, time.time() - state["updated_at"])
        return out

    def list(self) -> list[dict[str, Any]]:
        out = []
        for job_id in sorted(self.job_ids()):
            s = self.status(job_id)
            out.append({k: s[k] for k in ("id", "name", "phantom", "state", "done", "total", "created_at")})
        return sorted(out, key=lambda s: s["created_at"] or 0)

    def results(self, sweep_id: str, fmt: str, table: str = "results") -> tuple[bytes, dict[str, Any]]:
        """The stored rows (partial while running) as ``fmt`` bytes, and the status."""
        store = SweepDir(self.job_dir(sweep_id))
        _, spec, plan, _ = open_sweep(store.root)
        if table == "localization":
            if not spec["localization"]:
                raise NotFound("this sweep has no localization methods", loc=["query", "table"])
            data = store.localization(LOCALIZATION_SCHEMA, plan.n_tasks)
        else:
            data = store.results(results_schema(spec.methods), plan.n_tasks)
        if fmt == "csv":
            body = to_csv_bytes(data)
        elif fmt == "json":
            body = to_json_bytes(data)
        else:
            sink = pa.BufferOutputStream()
            pq.write_table(data, sink, compression="zstd")
            body = sink.getvalue().to_pybytes()
        return body, self.status(sweep_id)

    # ------------------------------------------------------------ runner
    def execute(self, sweep_id: str, cancel: threading.Event) -> str:
        store, spec, plan, source = open_sweep(self.root / sweep_id)
        log.info("sweep planned", extra={"sweep": sweep_id, "traces": plan.total_traces})
        budget = {"deadline_s": self.settings.request_deadline_s, "max_ray_segments": self.settings.max_ray_segments,
                  "max_bytes": self.settings.compute_memory_share_bytes}
        if self._engine is None:  # one pool (or Dask client) for the runner's life: workers stay warm
            # each local worker leads a process group of its own and records itself, so that the next
            # runner of this data directory reaps the pool of a server that was killed (service.workers)
            self._engine = make_engine(self.settings.sweep_workers, self.settings.sweep_cluster,
                                       initializer=register, initargs=(str(self.runner.workers_dir),))
        summary = execute(store, spec, plan, source, engine=self._engine, cancel=cancel, budget=budget)
        return summary.state["state"]
