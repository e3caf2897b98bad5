"""Full-wave cross-check jobs (``fw-`` + 16 hex) on the service's one job queue (:mod:`service.jobs`).

A job is a directory under ``<data_dir>/fullwave/``::

    job.json          the request as given, the ChannelSpec it became, the FDTD options, the runs' sizes
    state.json        state, progress (run, stage, gprMax's time steps), elapsed and remaining time, error
    run/              fullwave.run.compare's directory: model_<cell>.in (written at submission), .h5, .log,
                      .wall_s (a finished run), report.json and report.md (when the job is done)

Everything is checked before the 202 (docs/validation.md, "Over HTTP"): the channel request as
POST /v1/channel checks it (phantom lookup, uploads included, and the tracer's footprint: the job
traces it too), the FDTD options, the models' work (cells x time steps over its runs, from
:func:`fullwave.model.model_size`) against ``fullwave_max_cell_updates``, and each model itself
(:func:`fullwave.model.build_model`: an antenna in the absorbing layer is refused naming
``margin_m``). ``export_only`` jobs are finished at submission (inputs and a report without FDTD
numbers); the others need gprMax on the server (501 otherwise).

The runner executes :func:`fullwave.run.compare` in its own thread with ``reuse``: gprMax runs in a
child process (killed on cancellation, at shutdown and at the job's wall-time bound
``fullwave_max_wall_s``), so a job interrupted by a restart runs again from the first cell size
whose gprMax run had not finished.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

from fullwave.model import FdtdOptions, build_model, model_size
from fullwave.run import compare, export, gprmax_available, input_stem
from raytrace.errors import BudgetExceededError, CapsuleRTError
from raytrace.spec import ChannelSpec
from service.admission import Cost, Work, admit
from service.errors import Conflict, NotFound, NotInstalled, Unprocessable
from service.jobs import CANCEL_FILE, JobKind, JobRunner
from service.operations.channel import to_spec
from service.registry import Registry
from service.schemas.channel import ChannelRequest
from service.schemas.fullwave import CHANNEL_FIELDS
from service.settings import Settings
from sweeps.store import atomic_write

log = logging.getLogger("capsule_rt.jobs")

JOB_FILE = "job.json"
STATE_FILE = "state.json"
RUN_DIR = "run"
#: gprMax's throughput on 2 idle cores of the reference machine [cell updates / s] (docs/validation.md):
#: only to say in a refusal roughly how long a model would take.
UPDATES_PER_S = 2.6e7
#: Media types of the downloadable files, by suffix.
MEDIA = {".in": "text/plain; charset=utf-8", ".h5": "application/x-hdf5", ".log": "text/plain; charset=utf-8",
         ".json": "application/json", ".md": "text/markdown; charset=utf-8"}
#: How often the running job's state file is rewritten with gprMax's progress, at most [s].
PUBLISH_S = 1.0


def _threads(settings: Settings) -> int:
    if settings.fullwave_threads is not None:
        return settings.fullwave_threads
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _stop_orphan(pid: int | None, run_dir: Path) -> None:
    """Kill the gprMax process group an earlier start of the job left running (the service was killed
    while gprMax ran: it is in a session of its own, so it outlives its parent and would write the
    same output as the new run). Only a process that is gprMax and works in the job's own ``run_dir``
    (Linux ``/proc``), so a recycled pid is left alone."""
    if not pid:
        return
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        cwd = os.readlink(f"/proc/{pid}/cwd")
    except OSError:
        return
    if b"gprMax" in argv and cwd == str(run_dir):
        log.warning("killing the gprMax an earlier start left running", extra={"pid": pid})
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


class FullwaveJobs(JobKind):
    kind = "fullwave"
    prefix = "fw-"
    noun = "full-wave job"
    list_path = "/v1/fullwave"
    id_loc = ["path", "job_id"]

    def __init__(self, settings: Settings, registry: Registry, runner: JobRunner) -> None:
        super().__init__(runner, settings, Path(settings.data_dir) / "fullwave", settings.fullwave_max_queue)
        self.registry = registry

    # ------------------------------------------------------------ the queue's hooks
    def exists(self, d: Path) -> bool:
        return (d / JOB_FILE).is_file()

    def read_state(self, d: Path) -> dict[str, Any]:
        try:
            return json.loads((d / STATE_FILE).read_text())
        except FileNotFoundError:
            return {}

    def write_state(self, d: Path, state: dict[str, Any]) -> None:
        state = {**state, "updated_at": time.time()}
        atomic_write(d / STATE_FILE, json.dumps(state, sort_keys=True, allow_nan=False).encode())

    def created_at(self, d: Path) -> float:
        return self._job(d).get("created_at") or 0

    @staticmethod
    def _job(d: Path) -> dict[str, Any]:
        return json.loads((d / JOB_FILE).read_text())

    # ------------------------------------------------------------ submission
    def _validate(self, req: Any) -> tuple[ChannelSpec, Any, FdtdOptions, list[float], list[dict]]:
        """The request's spec, phantom, options, cell sizes and models' sizes; a 4xx naming the field."""
        channel = ChannelRequest.model_construct(**{k: getattr(req, k) for k in CHANNEL_FIELDS}, outputs=None)
        spec, phantom = to_spec(channel, self.registry, self.settings)
        options = FdtdOptions(cell_m=req.cell_m, margin_m=req.margin_m, pml_cells=req.pml_cells)
        factor = req.coarse_factor or None
        sizes = [req.cell_m] + ([req.cell_m * factor] if factor else [])
        if factor is not None and factor == 1.0:
            raise Unprocessable("a coarse_factor of 1 repeats the first run; give 0 (one run) or another factor",
                                loc=["body", "coarse_factor"])
        if factor is not None and not 1e-4 <= sizes[1] <= 0.02:
            raise Unprocessable(f"the second run's cells would be {sizes[1]:.4g} m, outside [1e-4, 0.02] m",
                                loc=["body", "coarse_factor"])
        runs = []
        for h in sizes:
            size = model_size(spec, phantom, FdtdOptions(cell_m=h, margin_m=options.margin_m,
                                                        pml_cells=options.pml_cells))
            runs.append({"cell_m": h, "input": f"{input_stem(h)}.in", "cells": list(size.cells),
                         "iterations": size.iterations, "cell_updates": size.cell_updates,
                         "_bytes": size.memory_bytes})
        admit(self.estimate(runs), self.settings)
        for k, r in enumerate(runs):  # the models themselves: antennas outside the PML, the phantom's voxels
            opts = FdtdOptions(cell_m=r["cell_m"], margin_m=options.margin_m, pml_cells=options.pml_cells)
            try:
                model = build_model(spec, phantom, opts)
            except CapsuleRTError as exc:  # the voxel grid's: its bounds are the margin's, its spacing the cell's
                field = "margin_m" if exc.field == "bounds_m" else "coarse_factor" if k else "cell_m"
                raise Unprocessable(f"{r['cell_m'] * 1e3:g} mm cells: {exc.reason}", loc=["body", field]) from None
            except ValueError as exc:
                raise Unprocessable(str(exc), loc=["body", "margin_m"]) from None
            r.pop("_bytes", None)
            r.update(cells=list(model.cells), iterations=model.iterations,
                     cell_updates=model.iterations * model.cells[0] * model.cells[1] * model.cells[2],
                     _model=model)
        return spec, phantom, options, sizes, runs

    def estimate(self, runs: list[dict]) -> Cost:
        """A job's cost (its models' sizes, :func:`fullwave.model.model_size`): the cells x time steps of
        all its gprMax runs against ``fullwave_max_cell_updates`` (``cell_m``, or ``coarse_factor`` when the
        second run is the bigger one), and the grid gprMax holds (one run at a time: the largest) against one
        computation's memory share. The trace it also runs was admitted with its channel request."""
        loc = lambda k: ("coarse_factor",) if k else ("cell_m",)  # noqa: E731
        total = sum(r["cell_updates"] for r in runs)
        field = 1 if len(runs) == 2 and runs[1]["cell_updates"] > runs[0]["cell_updates"] else 0
        sizes_text = " + ".join(f"{r['cell_m'] * 1e3:g} mm: {'x'.join(map(str, r['cells']))} cells x "
                                f"{r['iterations']} steps" for r in runs)
        cap = self.settings.fullwave_max_cell_updates
        biggest = max(range(len(runs)), key=lambda k: runs[k]["_bytes"])
        return Cost(
            work=(Work(loc(field), total, cap, "cell updates", "fullwave_max_cell_updates",
                       f"the FDTD work ({sizes_text})", f"about {cap / UPDATES_PER_S / 60:.0f} min of gprMax on 2 "
                       "cores; larger cell_m, a smaller margin_m, or coarse_factor 0 (one run)"),),
            memory=((loc(biggest), runs[biggest]["_bytes"]),),
            what=f"the FDTD grid at {runs[biggest]['cell_m'] * 1e3:g} mm ({'x'.join(map(str, runs[biggest]['cells']))} "
                 "cells; gprMax holds it whole)", knobs="larger cells or a smaller margin_m")

    def submit(self, req: Any, owner: str | None = None) -> dict[str, Any]:
        """Validate a :class:`~service.schemas.fullwave.FullwaveRequest`, store the job (``queued``, or
        ``done`` for ``export_only``) owned by ``owner`` (the submitting key's id); its status. Runs in a
        worker thread."""
        spec, phantom, options, sizes, runs = self._validate(req)
        if not req.export_only and not gprmax_available():
            raise NotInstalled("gprMax is not installed on this server (pip install 'capsule-rt[fullwave]'); "
                               "export_only: true writes the gprMax inputs to run elsewhere",
                               loc=["body", "export_only"])
        record = {
            "request": req.model_dump(mode="json", exclude_none=True), "spec": spec.to_dict(),
            "phantom": spec.phantom, "options": {"cell_m": options.cell_m, "margin_m": options.margin_m,
                                                 "pml_cells": options.pml_cells},
            "coarse_factor": req.coarse_factor or None, "export_only": req.export_only,
            "runs": [{k: v for k, v in r.items() if k != "_model"} for r in runs], "created_at": time.time(),
        }

        def build(tmp: Path) -> None:
            (tmp / RUN_DIR).mkdir()
            for r in runs:  # the inputs are there at once, to download while the job waits
                export(r["_model"], tmp / RUN_DIR, input_stem(r["cell_m"]))
            state = {"state": "queued", "runs_done": 0, "elapsed_s": 0.0}
            if req.export_only:
                compare(spec, phantom, options, tmp / RUN_DIR, coarse_factor=record["coarse_factor"], run=False)
                state.update(state="done", finished_at=time.time())
            atomic_write(tmp / JOB_FILE, json.dumps(record, sort_keys=True, allow_nan=False).encode())
            self.write_state(tmp, state)

        job_id = self.create(Cost(), build, owner)  # its cost was admitted by _validate, before the models were built
        log.info("fullwave queued", extra={"fullwave": job_id, "phantom": spec.phantom,
                                           "cell_updates": sum(r["cell_updates"] for r in runs)})
        return self.status(job_id)

    # ------------------------------------------------------------ API
    def status(self, job_id: str) -> dict[str, Any]:
        d = self.job_dir(job_id)
        job, state = self._job(d), self.read_state(d)
        runs = job["runs"]
        work = [r["cell_updates"] for r in runs]
        done_work = state.get("work_done", 0.0)
        out = {
            "id": job_id, "phantom": job["phantom"], "state": state.get("state", "queued"),
            "export_only": job["export_only"], "runs": runs, "runs_done": state.get("runs_done", 0),
            "runs_total": len(runs), "run": state.get("run"), "stage": state.get("stage"),
            "iteration": state.get("iteration", 0), "iterations": state.get("iterations", 0),
            "progress": min(1.0, done_work / sum(work)) if sum(work) else 0.0,
            "elapsed_s": float(state.get("elapsed_s") or 0.0), "eta_s": state.get("eta_s"),
            "error": self.redact(state.get("error"), d / RUN_DIR), "files": self._files(d),
            "created_at": job.get("created_at"),
            "started_at": state.get("started_at"), "finished_at": state.get("finished_at"),
            "cancel_requested": (d / CANCEL_FILE).exists(),
        }
        if out["state"] == "done" and not job["export_only"]:
            out["progress"] = 1.0
        if out["state"] != "running":
            out.update(run=None, stage=None)
        elif state.get("updated_at"):  # elapsed up to now, not to the last write
            out["elapsed_s"] += max(0.0, time.time() - state["updated_at"])
        return out

    @staticmethod
    def _files(d: Path) -> list[str]:
        run = d / RUN_DIR
        if not run.is_dir():
            return []
        names = []
        for p in sorted(run.iterdir()):
            if p.suffix in (".in", ".log") or p.name in ("report.json", "report.md"):
                names.append(p.name)
            elif p.suffix == ".h5" and p.with_suffix(".wall_s").exists():  # a finished run's output only
                names.append(p.name)
        return names

    def list(self) -> list[dict[str, Any]]:
        out = []
        for job_id in self.job_ids():
            s = self.status(job_id)
            out.append({k: s[k] for k in ("id", "phantom", "state", "runs_done", "runs_total", "created_at")})
        return sorted(out, key=lambda s: s["created_at"] or 0)

    def report(self, job_id: str, fmt: str) -> bytes:
        d = self.job_dir(job_id)
        path = d / RUN_DIR / f"report.{fmt}"
        if not path.is_file():
            state = self.read_state(d).get("state", "queued")
            raise Conflict(f"the report is written when the job is done; it is {state}", loc=self.id_loc)
        return path.read_bytes()

    def file(self, job_id: str, name: str) -> tuple[Path | bytes, str]:
        """A file of the job's own run directory that :meth:`_files` lists (the route's pattern has
        already refused any other name), and its media type. Text files (gprMax's log and input, the
        report) come as bytes with the server's paths redacted (:meth:`redact`: gprMax writes the
        absolute paths of its input and output); the HDF5 output as its path."""
        d = self.job_dir(job_id)
        if name not in self._files(d):
            raise NotFound(f"{name!r} is not (yet) a file of {job_id}; its status lists them",
                           loc=["path", "name"])
        path = d / RUN_DIR / name
        media = MEDIA.get(path.suffix, "application/octet-stream")
        if path.suffix == ".h5":
            return path, media
        return (self.redact(path.read_text(errors="replace"), d / RUN_DIR) or "").encode(), media

    # ------------------------------------------------------------ runner
    def execute(self, job_id: str, cancel: threading.Event) -> str:
        d = self.root / job_id
        job, previous = self._job(d), self.read_state(d)
        work = [r["cell_updates"] for r in job["runs"]]
        elapsed_before = float(previous.get("elapsed_s") or 0.0)
        started = time.monotonic()
        deadline = started + max(0.0, self.settings.fullwave_max_wall_s - elapsed_before)
        state: dict[str, Any] = {
            "state": "running", "runs_done": 0, "run": None, "stage": None, "iteration": 0, "iterations": 0,
            "work_done": 0.0, "elapsed_s": elapsed_before, "eta_s": None, "error": None,
            "started_at": previous.get("started_at") or time.time(), "finished_at": None,
        }
        progress = {"baseline": None, "published": 0.0}

        def publish(force: bool = False) -> None:
            now = time.monotonic()
            if not force and now - progress["published"] < PUBLISH_S:
                return
            progress["published"] = now
            run_s = now - started
            state["elapsed_s"] = elapsed_before + run_s
            base = progress["baseline"]
            if base is not None and state["work_done"] > base and state["state"] == "running":
                state["eta_s"] = run_s * (sum(work) - state["work_done"]) / (state["work_done"] - base)
            self.write_state(d, state)

        def on_progress(event: dict) -> None:
            k, stage = event["run"], event["stage"]
            before = float(sum(work[:k]))
            if stage == "reused":  # a finished run of an earlier start: not this start's rate
                state["work_done"] = before + work[k]
                if progress["baseline"] is not None:
                    progress["baseline"] += work[k]
            elif stage == "gprmax":
                if progress["baseline"] is None:
                    progress["baseline"] = before
                n = event["iterations"] or 1
                state.update(iteration=event["iteration"], iterations=event["iterations"])
                state["work_done"] = before + work[k] * min(1.0, event["iteration"] / n)
            else:
                state["work_done"] = before + work[k]
            state.update(run=k, stage=stage if stage in ("gprmax", "tracer") else None,
                         runs_done=k + (1 if stage == "done" else 0))
            publish(force=stage != "gprmax" or event["iteration"] == 0)  # a new stage at once; steps throttled

        def started_gprmax(pid: int) -> None:
            state["gprmax_pid"] = pid
            publish(force=True)

        _stop_orphan(previous.get("gprmax_pid"), d / RUN_DIR)
        publish(force=True)
        try:
            spec = ChannelSpec.from_dict(job["spec"])
            try:
                phantom = self.registry.get(spec.phantom, field_loc=["body", "phantom"])
            except CapsuleRTError as exc:
                raise RuntimeError(f"phantom {spec.phantom!r} is no longer available: {exc}") from None
            except NotFound as exc:
                raise RuntimeError(f"phantom {spec.phantom!r} is no longer available: {exc.reason}") from None
            compare(spec, phantom, FdtdOptions(**job["options"]), d / RUN_DIR, coarse_factor=job["coarse_factor"],
                    run=True, threads=_threads(self.settings), reuse=True, cancel=cancel, deadline=deadline,
                    on_progress=on_progress, on_start=started_gprmax)
        except BudgetExceededError as exc:
            if exc.kind == "cancelled":
                state["state"] = "cancelled"  # the runner makes it "queued" again when the service is stopping
            else:
                state.update(state="failed", error=f"the job ran past this server's wall-time bound of "
                             f"{self.settings.fullwave_max_wall_s:g} s (fullwave_max_wall_s) and was stopped: "
                             f"{exc.reason}")
        except Exception as exc:
            log.exception("fullwave failed", extra={"fullwave": job_id})
            state.update(state="failed", error=f"{type(exc).__name__}: {exc}")
        else:
            state.update(state="done", runs_done=len(work), work_done=float(sum(work)), eta_s=0.0)
        state.update(finished_at=time.time(), run=None, stage=None, gprmax_pid=None)
        if state["state"] != "done":
            state["eta_s"] = None
        publish(force=True)
        return state["state"]
