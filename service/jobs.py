"""Sweep jobs of the service: a durable queue under ``<data_dir>/sweeps/``, run one at a time.

Each job is a sweep directory (:mod:`sweeps.store`) named by its id (``sw-`` + 16 hex),
so the queue *is* the disk: a submitted job is a directory whose ``state.json`` says
``queued``; a restarted service finds its jobs there and goes on (a job that was
``running`` when the process died is resumed: only its missing tasks run again).

One *runner* thread per data directory executes the jobs in submission order. It holds
an exclusive ``flock`` on ``sweeps/.runner.lock``, so with several uvicorn workers only
one of them runs jobs while every one accepts, reports and cancels them. The runner only
coordinates: the tasks run in worker processes (a local ``spawn`` pool of
``sweep_workers`` processes, or the Dask scheduler at ``sweep_cluster``), never on the
event loop nor in the server's threads. Cancellation is a ``cancel.requested`` file the
runner watches (so any worker process can ask for it).

Admission: at most ``sweep_max_queue`` jobs queued or running; beyond, 503 +
Retry-After. Every job is validated (spec and plan, against the phantom) before its 202.
"""

from __future__ import annotations

import fcntl
import logging
import os
import re
import secrets
import shutil
import threading
import time
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from service.errors import Conflict, NotFound, ServerSaturated
from service.registry import Registry
from service.settings import Settings
from service.storage import is_upload_id
from sweeps.engines import make_engine
from sweeps.run import execute, open_sweep, prepare
from sweeps.spec import LIMITS, Limits, SweepSpec
from sweeps.store import SweepDir
from sweeps.table import LOCALIZATION_SCHEMA, results_schema, to_csv_bytes, to_json_bytes
from sweeps.task import PhantomSource

log = logging.getLogger("capsule_rt.jobs")

SWEEP_ID_RE = re.compile(r"^sw-[0-9a-f]{16}$")
CANCEL_FILE = "cancel.requested"
ACTIVE = ("queued", "running")
#: How often the runner looks for new jobs and cancellation requests [s].
POLL_S = 0.5


def is_sweep_id(value: str) -> bool:
    return isinstance(value, str) and SWEEP_ID_RE.fullmatch(value) is not None


def limits_for(settings: Settings) -> Limits:
    """The sweep limits of this server: the request limits of its settings."""
    return Limits(max_positions=LIMITS.max_positions, max_receivers=settings.max_receivers,
                  max_traces=settings.sweep_max_traces, max_rays=settings.max_rays,
                  max_interactions=settings.max_interactions, max_band_points=settings.max_band_points,
                  max_trials=settings.max_trials, max_ray_segments=settings.max_ray_segments,
                  max_trace_bytes=settings.compute_memory_share_bytes)


class SweepJobs:
    def __init__(self, settings: Settings, registry: Registry) -> None:
        self.settings = settings
        self.registry = registry
        self.root = Path(settings.data_dir) / "sweeps"
        self.limits = limits_for(settings)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock_fd: int | None = None
        self._current: tuple[str, threading.Event] | None = None
        self._submit_lock = threading.Lock()
        self._engine = None

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        self._thread = threading.Thread(target=self._run, name="sweep-runner", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 20.0) -> None:
        """Stop the runner; a running job is interrupted (its workers killed) and left ``queued`` to resume."""
        self._stop.set()
        if self._current is not None:
            self._current[1].set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._engine is not None:
            self._engine.close()
            self._engine = None
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    # ------------------------------------------------------------ API
    def _dir(self, sweep_id: str) -> SweepDir:
        if not is_sweep_id(sweep_id):
            raise NotFound(f"unknown sweep {sweep_id!r}", loc=["path", "sweep_id"])
        store = SweepDir(self.root / sweep_id)
        if not store.exists():
            raise NotFound(f"unknown sweep {sweep_id!r} (GET /v1/sweeps lists them)", loc=["path", "sweep_id"])
        return store

    def _active(self) -> int:
        n = 0
        if self.root.is_dir():
            for d in self.root.iterdir():
                if is_sweep_id(d.name) and SweepDir(d).read_state().get("state") in ACTIVE:
                    n += 1
        return n

    def submit(self, data: Any) -> dict[str, Any]:
        """Validate and plan a spec, store the job ``queued``; its status. Runs in a worker thread."""
        spec = SweepSpec.from_dict(data, self.limits)
        phantom_id = spec["phantom"]
        phantom = self.registry.get(phantom_id, field_loc=["body", "phantom"])
        source = PhantomSource(phantom_id)
        if is_upload_id(phantom_id):
            d = self.registry.store.root / phantom_id
            source = PhantomSource(phantom_id, str(d / "mesh.glb"), str(d / "manifest.json"))
        with self._submit_lock:
            if self._active() >= self.settings.sweep_max_queue:
                raise ServerSaturated(
                    f"{self.settings.sweep_max_queue} sweeps are already queued or running (sweep_max_queue); "
                    f"retry after {self.settings.retry_after_s} s", loc=["server"],
                    headers={"Retry-After": str(self.settings.retry_after_s)})
            sweep_id = "sw-" + secrets.token_hex(8)
            tmp = self.root / f".tmp-{sweep_id}"
            try:
                prepare(spec, tmp, phantom=phantom, source=source, limits=self.limits)
                os.replace(tmp, self.root / sweep_id)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        log.info("sweep queued", extra={"sweep": sweep_id, "phantom": phantom_id})
        return self.status(sweep_id)

    def status(self, sweep_id: str) -> dict[str, Any]:
        store = self._dir(sweep_id)
        record = store.record()
        state = store.read_state()
        out = {
            "id": sweep_id, "name": record["spec"].get("name", ""), "phantom": record["spec"]["phantom"],
            "state": state.get("state", "queued"), "done": state.get("done", 0),
            "total": state.get("total", 0), "tasks_done": state.get("tasks_done", 0),
            "tasks_total": state.get("tasks_total") or -(-len(record["plan"]["labels"])
                                                         // record["plan"]["chunk_positions"]),
            "elapsed_s": float(state.get("elapsed_s") or 0.0), "eta_s": state.get("eta_s"),
            "failures": state.get("failures", []), "failure_count": state.get("failure_count", 0),
            "engine": state.get("engine"), "error": state.get("error"), "created_at": record.get("created_at"),
            "started_at": state.get("started_at"), "finished_at": state.get("finished_at"),
            "cancel_requested": (store.root / CANCEL_FILE).exists(),
        }
        if out["state"] == "running" and state.get("updated_at"):  # elapsed up to now, not to the last task
            out["elapsed_s"] += max(0.0, time.time() - state["updated_at"])
        return out

    def list(self) -> list[dict[str, Any]]:
        out = []
        if self.root.is_dir():
            for d in sorted(self.root.iterdir()):
                if is_sweep_id(d.name) and SweepDir(d).exists():
                    s = self.status(d.name)
                    out.append({k: s[k] for k in ("id", "name", "phantom", "state", "done", "total", "created_at")})
        return sorted(out, key=lambda s: s["created_at"] or 0)

    def results(self, sweep_id: str, fmt: str, table: str = "results") -> tuple[bytes, dict[str, Any]]:
        """The stored rows (partial while running) as ``fmt`` bytes, and the status."""
        store = self._dir(sweep_id)
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

    def cancel(self, sweep_id: str) -> dict[str, Any]:
        """Cancel a queued or running job; delete a finished one (and its results)."""
        store = self._dir(sweep_id)
        state = store.read_state()
        if state.get("state") in ACTIVE:
            (store.root / CANCEL_FILE).touch()
            if state.get("state") == "queued":
                with self._submit_lock:
                    if store.read_state().get("state") == "queued" and not self._is_current(sweep_id):
                        store.write_state({**state, "state": "cancelled", "finished_at": time.time()})
            out = self.status(sweep_id)
            out["deleted"] = False
            return out
        out = self.status(sweep_id)
        trash = self.root / f".trash-{sweep_id}-{secrets.token_hex(4)}"
        try:
            os.replace(store.root, trash)
        except FileNotFoundError:
            raise Conflict(f"sweep {sweep_id} is being deleted", loc=["path", "sweep_id"]) from None
        shutil.rmtree(trash, ignore_errors=True)
        out["deleted"] = True
        return out

    def _is_current(self, sweep_id: str) -> bool:
        return self._current is not None and self._current[0] == sweep_id

    # ------------------------------------------------------------ runner
    def _take_lock(self) -> bool:
        if self._lock_fd is not None:
            return True
        fd = os.open(self.root / ".runner.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        self._lock_fd = fd
        for entry in self.root.iterdir():  # leftovers of submissions and deletions a crash interrupted
            if entry.name.startswith((".tmp-", ".trash-")):
                shutil.rmtree(entry, ignore_errors=True)
        return True

    def _next(self) -> str | None:
        jobs = []
        for d in self.root.iterdir():
            if is_sweep_id(d.name) and SweepDir(d).exists():
                state = SweepDir(d).read_state().get("state")
                if state in ACTIVE:  # "running" here: its runner died with it; resume it
                    jobs.append((SweepDir(d).record().get("created_at") or 0, d.name))
        return min(jobs)[1] if jobs else None

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                if not self._take_lock():
                    self._stop.wait(POLL_S * 4)
                    continue
                sweep_id = self._next()
                if sweep_id is None:
                    self._stop.wait(POLL_S)
                    continue
                self._execute(sweep_id)
            except Exception:  # a broken job must not stop the runner
                log.exception("sweep runner error")
                self._stop.wait(POLL_S)

    def _execute(self, sweep_id: str) -> None:
        store, spec, plan, source = open_sweep(self.root / sweep_id)
        cancel = threading.Event()
        with self._submit_lock:
            if (store.root / CANCEL_FILE).exists():
                store.write_state({**store.read_state(), "state": "cancelled", "finished_at": time.time()})
                return
            self._current = (sweep_id, cancel)
        done = threading.Event()

        def watch() -> None:
            while not done.wait(POLL_S):
                if (store.root / CANCEL_FILE).exists():
                    cancel.set()
                    return

        watcher = threading.Thread(target=watch, name=f"sweep-watch-{sweep_id}", daemon=True)
        watcher.start()
        log.info("sweep started", extra={"sweep": sweep_id, "traces": plan.total_traces})
        budget = {"deadline_s": self.settings.request_deadline_s, "max_ray_segments": self.settings.max_ray_segments,
                  "max_bytes": self.settings.compute_memory_share_bytes}
        try:
            if self._engine is None:  # one pool (or Dask client) for the runner's life: workers stay warm
                self._engine = make_engine(self.settings.sweep_workers, self.settings.sweep_cluster)
            summary = execute(store, spec, plan, source, engine=self._engine, cancel=cancel, budget=budget)
            final = summary.state["state"]
        except Exception as exc:  # execute has recorded the failure in state.json
            log.exception("sweep failed", extra={"sweep": sweep_id})
            final = f"failed: {exc}"
        finally:
            done.set()
            self._current = None
        if self._stop.is_set() and not (store.root / CANCEL_FILE).exists():
            # the service is shutting down, not the user cancelling: resume at the next start
            store.write_state({**store.read_state(), "state": "queued", "finished_at": None})
            final = "interrupted (will resume)"
        log.info("sweep ended", extra={"sweep": sweep_id, "state": final})
