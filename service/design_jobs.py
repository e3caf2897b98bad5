"""Sensor-layout design jobs on the service's one job queue (:mod:`service.jobs`; docs/design.md, "Over HTTP").

Two kinds:

* coverage (``cv-`` + 16 hex, ``<data_dir>/design/coverage/<id>/``): a :class:`design.coverage.CoverageDir`;
  its positions run on a pool of worker processes (``sweep_workers``, kept warm between jobs), each
  storing its part as it ends, so a restarted job resumes with the positions still missing;
* layout (``ly-`` + 16 hex, ``<data_dir>/design/layout/<id>/``): ``job.json`` (the request), ``state.json``,
  ``progress.json`` (the running stage, written by the worker) and, when done, ``result.json`` and
  ``report.md``; the search and the evaluation run in one worker process.

Everything is checked before the 202: the spec against the phantom (positions, candidates), the
coverage's links against ``design_max_links``, each trace against the channel endpoint's work and
memory rules, the layout against its coverage (done, the constraints leave enough candidates) and
the search's work bound.
"""

from __future__ import annotations

import builtins
import json
import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from design import coverage as cov
from design.layout import MAX_SEARCH_WORK, constraints_of, normalise_layout, report_markdown, run_layout, search_work  # noqa: F401 (validation before the 202)
from raytrace.errors import CapsuleRTError
from service.admission import Cost, Work
from service.errors import Conflict, NotFound
from service.jobs import CANCEL_FILE, JobKind, JobRunner
from service.registry import Registry
from service.settings import Settings
from service.storage import is_upload_id
from service.workers import WORKERS_DIR, register
from sweeps.engines import make_engine
from sweeps.store import atomic_write
from sweeps.task import PhantomSource, phantom_for

log = logging.getLogger("capsule_rt.jobs")


def _source(registry: Registry, phantom_id: str) -> PhantomSource:
    if is_upload_id(phantom_id):
        d = registry.store.root / phantom_id
        return PhantomSource(phantom_id, str(d / "mesh.glb"), str(d / "manifest.json"))
    return PhantomSource(phantom_id)


def limits_for(settings: Settings) -> cov.Limits:
    return cov.Limits(max_links=settings.design_max_links, max_rays=settings.max_rays,
                      max_interactions=settings.max_interactions, max_ray_segments=settings.max_ray_segments,
                      max_trace_bytes=settings.compute_memory_share_bytes)


class DesignEngine:
    """One process pool for both design kinds, started at the first job and kept warm."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.engine = None

    def get(self):
        if self.engine is None:
            # the workers record themselves for the next start to reap if this server is killed (service.workers)
            self.engine = make_engine(self.settings.sweep_workers, initializer=register,
                                      initargs=(str(Path(self.settings.data_dir) / WORKERS_DIR),))
        return self.engine

    def close(self) -> None:
        if self.engine is not None:
            self.engine.close()
            self.engine = None


class CoverageJobs(JobKind):
    kind = "coverage"
    prefix = "cv-"
    noun = "coverage job"
    list_path = "/v1/design/coverage"
    id_loc = ["path", "job_id"]

    def __init__(self, settings: Settings, registry: Registry, runner: JobRunner, engine: DesignEngine) -> None:
        super().__init__(runner, settings, Path(settings.data_dir) / "design" / "coverage", settings.design_max_queue)
        self.registry, self.engine = registry, engine
        self.limits = limits_for(settings)

    def exists(self, d: Path) -> bool:
        return cov.CoverageDir(d).exists()

    def read_state(self, d: Path) -> dict[str, Any]:
        return cov.CoverageDir(d).read_state()

    def write_state(self, d: Path, state: dict[str, Any]) -> None:
        cov.CoverageDir(d).write_state(state)

    def created_at(self, d: Path) -> float:
        return cov.CoverageDir(d).record().get("created_at") or 0

    def close(self) -> None:
        self.engine.close()

    def submit(self, data: dict, owner: str | None = None) -> dict[str, Any]:
        """Normalise and plan the spec (every check before any work); store the job ``queued`` (owned by
        ``owner``, the submitting key's id)."""
        spec = cov.normalise_spec(data, self.limits)
        phantom = self.registry.get(spec["phantom"], field_loc=["body", "phantom"])
        source = _source(self.registry, spec["phantom"])
        plan = cov.make_plan(spec, phantom, self.limits, self.settings.tracer_config())

        def build(tmp: Path) -> None:
            store = cov.CoverageDir(tmp)
            store.create({"spec": spec, "plan": plan.to_dict(), "source": source.__dict__,
                          "created_at": time.time(), "links": plan.links})
            store.write_state({"state": "queued", "done": 0, "total": len(plan.positions), "elapsed_s": 0.0})

        job_id = self.create(self.estimate(plan), build, owner)
        log.info("coverage queued", extra={"coverage": job_id, "links": plan.links})
        return self.status(job_id)

    def estimate(self, plan: cov.Plan) -> Cost:
        """A coverage's cost (service.admission): its links (capsule positions x candidates) against
        ``design_max_links``; each trace's work and memory were bounded by the plan with the channel
        endpoint's rules (design.coverage.make_plan, the same footprint model and caps)."""
        where = ("positions",) if len(plan.positions) > len(plan.candidates) else ("candidates", "spacing_m")
        return Cost(work=(Work(where, plan.links, self.settings.design_max_links, "links", "design_max_links",
                               f"{len(plan.positions)} capsule positions x {len(plan.candidates)} candidates",
                               "fewer positions (a larger ds_m) or a larger candidate spacing"),))

    def status(self, job_id: str) -> dict[str, Any]:
        store = cov.CoverageDir(self.job_dir(job_id))
        record, state = store.record(), store.read_state()
        plan = record["plan"]
        out = {"id": job_id, "phantom": record["spec"]["phantom"], "state": state.get("state", "queued"),
               "done": state.get("done", 0), "total": state.get("total", 0),
               "positions": len(plan["positions"]["labels"]), "candidates": len(plan["candidates"]["site"]),
               "links": record["links"], "receivers_per_trace": plan["receivers_per_trace"],
               "elapsed_s": float(state.get("elapsed_s") or 0.0), "eta_s": state.get("eta_s"),
               "error": state.get("error"), "failures": state.get("failures", []),
               "created_at": record.get("created_at"), "started_at": state.get("started_at"),
               "finished_at": state.get("finished_at"), "cancel_requested": (store.root / CANCEL_FILE).exists()}
        if out["state"] == "running" and state.get("updated_at"):
            out["elapsed_s"] += max(0.0, time.time() - state["updated_at"])
        return out

    def list(self) -> builtins.list[dict[str, Any]]:
        return sorted((self.status(j) for j in self.job_ids()), key=lambda s: s["created_at"] or 0)

    def table(self, job_id: str):
        return cov.CoverageDir(self.job_dir(job_id)).table()

    def done_dir(self, job_id: str, loc: builtins.list) -> Path:
        """A done coverage's directory, or 404 / 409 naming ``loc``."""
        if not self.is_id(job_id) or not self.exists(self.root / job_id):
            raise NotFound(f"unknown coverage job {job_id!r} (GET /v1/design/coverage lists them)", loc=loc)
        d = self.root / job_id
        state = self.read_state(d).get("state", "queued")
        if state != "done":
            raise Conflict(f"coverage {job_id} is {state}; a layout needs a done coverage", loc=loc)
        return d

    def execute(self, job_id: str, cancel: threading.Event) -> str:
        budget = {"deadline_s": self.settings.request_deadline_s, "max_ray_segments": self.settings.max_ray_segments,
                  "max_bytes": self.settings.compute_memory_share_bytes}
        state = cov.execute(self.root / job_id, engine=self.engine.get(), cancel=cancel, budget=budget,
                            config=self.settings.tracer_config())
        return state["state"]


JOB = "job.json"
STATE = "state.json"
PROGRESS = "progress.json"
RESULT = "result.json"
REPORT = "report.md"


def layout_task(args: tuple[str, str, dict]) -> dict:
    """Run one layout in a worker process: (job dir, coverage dir, layout spec) -> result."""
    job_dir, coverage_dir, layout = args
    record, plan, table = cov.load(coverage_dir)
    phantom = phantom_for(PhantomSource(**record["source"]))

    def check(stage: str) -> None:
        atomic_write(Path(job_dir) / PROGRESS, json.dumps({"stage": stage, "at": time.time()}).encode())

    result = run_layout(layout, record, plan, table, phantom, check=check)
    return result


class LayoutJobs(JobKind):
    kind = "layout"
    prefix = "ly-"
    noun = "layout job"
    list_path = "/v1/design/layout"
    id_loc = ["path", "job_id"]

    def __init__(self, settings: Settings, registry: Registry, runner: JobRunner, engine: DesignEngine,
                 coverage: CoverageJobs) -> None:
        super().__init__(runner, settings, Path(settings.data_dir) / "design" / "layout", settings.design_max_queue)
        self.registry, self.engine, self.coverage = registry, engine, coverage

    def exists(self, d: Path) -> bool:
        return (d / JOB).is_file()

    def read_state(self, d: Path) -> dict[str, Any]:
        try:
            return json.loads((d / STATE).read_text())
        except FileNotFoundError:
            return {}

    def write_state(self, d: Path, state: dict[str, Any]) -> None:
        atomic_write(d / STATE, json.dumps({**state, "updated_at": time.time()}, allow_nan=False).encode())

    def created_at(self, d: Path) -> float:
        return json.loads((d / JOB).read_text()).get("created_at") or 0

    def submit(self, data: dict, owner: str | None = None) -> dict[str, Any]:
        """Check the layout against its coverage (done; constraints; the search's work bound); queue it (owned
        by ``owner``, the submitting key's id)."""
        data = dict(data)
        coverage_id = data.pop("coverage", None)
        layout = normalise_layout(data, max_rays=self.settings.max_rays,
                                  max_interactions=self.settings.max_interactions)
        d = self.coverage.done_dir(coverage_id, ["body", "coverage"])
        record = cov.CoverageDir(d).record()
        plan = cov.Plan.from_dict(record["plan"])
        is_site = np.array([bool(s) for s in plan.candidates.site])
        cons, _ = constraints_of(layout, plan.candidates.positions_m, is_site)
        work = search_work(layout, len(plan.positions), int(cons.allowed.sum()))

        def build(tmp: Path) -> None:
            atomic_write(tmp / JOB, json.dumps({"layout": layout, "coverage": coverage_id,
                                                "created_at": time.time()}, allow_nan=False).encode())
            self.write_state(tmp, {"state": "queued", "elapsed_s": 0.0})

        job_id = self.create(self.estimate(work), build, owner)
        return self.status(job_id)

    def estimate(self, work: float) -> Cost:
        """A layout's cost (service.admission): the search's candidate scorings x positions
        (design.layout.search_work) against its bound."""
        return Cost(work=(Work(("search", "restarts"), work, MAX_SEARCH_WORK, "candidate scorings x positions",
                               "MAX_SEARCH_WORK", "the search", "fewer search.restarts or search.max_passes"),))

    def status(self, job_id: str) -> dict[str, Any]:
        d = self.job_dir(job_id)
        job, state = json.loads((d / JOB).read_text()), self.read_state(d)
        out = {"id": job_id, "coverage": job["coverage"], "state": state.get("state", "queued"),
               "stage": None, "elapsed_s": float(state.get("elapsed_s") or 0.0), "eta_s": None,
               "error": state.get("error"), "created_at": job.get("created_at"),
               "started_at": state.get("started_at"), "finished_at": state.get("finished_at"),
               "cancel_requested": (d / CANCEL_FILE).exists(), "result": None}
        if out["state"] == "running":
            try:
                out["stage"] = json.loads((d / PROGRESS).read_text())["stage"]
            except (FileNotFoundError, ValueError, KeyError):
                out["stage"] = "starting"
            if state.get("updated_at"):
                out["elapsed_s"] += max(0.0, time.time() - state["updated_at"])
        if out["state"] == "done" and (d / RESULT).is_file():
            out["result"] = json.loads((d / RESULT).read_text())
        return out

    def list(self) -> builtins.list[dict[str, Any]]:
        return sorted((self.status(j) for j in self.job_ids()), key=lambda s: s["created_at"] or 0)

    def report(self, job_id: str, fmt: str) -> bytes:
        d = self.job_dir(job_id)
        path = d / (RESULT if fmt == "json" else REPORT)
        if not path.is_file():
            raise Conflict(f"the report is written when the job is done; it is {self.read_state(d).get('state')}",
                           loc=self.id_loc)
        return path.read_bytes()

    def execute(self, job_id: str, cancel: threading.Event) -> str:
        d = self.root / job_id
        job = json.loads((d / JOB).read_text())
        started = time.monotonic()
        state = {"state": "running", "elapsed_s": 0.0, "started_at": time.time(), "finished_at": None, "error": None}
        self.write_state(d, state)
        cdir = self.coverage.root / job["coverage"]
        try:
            if not cov.CoverageDir(cdir).exists():
                raise RuntimeError(f"coverage {job['coverage']} was deleted")
            outputs = list(self.engine.get().run(layout_task, [(str(d), str(cdir), job["layout"])], cancel))
            if cancel.is_set() or not outputs:
                state["state"] = "cancelled"
            else:
                result = outputs[0][1]
                if isinstance(result, BaseException):
                    raise result
                atomic_write(d / RESULT, json.dumps(result, allow_nan=False).encode())
                atomic_write(d / REPORT, report_markdown(result, job["layout"]).encode())
                state["state"] = "done"
        except CapsuleRTError as exc:
            state.update(state="failed", error=exc.reason)
        except Exception as exc:
            log.exception("layout failed", extra={"layout": job_id})
            state.update(state="failed", error=f"{type(exc).__name__}: {exc}")
        state.update(elapsed_s=time.monotonic() - started, finished_at=time.time())
        self.write_state(d, state)
        return str(state["state"])
