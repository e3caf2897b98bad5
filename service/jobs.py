"""The service's jobs: one durable queue on disk and one runner for every kind of job.

A machine runs one heavy job at a time, whatever it is: a sweep (:mod:`service.sweep_jobs`,
``<data_dir>/sweeps/sw-<16 hex>/``) or a full-wave cross-check (:mod:`service.fullwave_jobs`,
``<data_dir>/fullwave/fw-<16 hex>/``). Each kind keeps its jobs as directories whose
``state.json`` says ``queued``, ``running``, ``done``, ``failed`` or ``cancelled``, so the queue
*is* the disk: a restarted service finds its jobs there and goes on (a job that was ``running``
when the process died is run again; each kind resumes from what it finished: a sweep's stored
tasks, a full-wave job's finished gprMax runs).

One *runner* thread per data directory executes the jobs of every kind in submission order
(oldest ``created_at`` first). It holds an exclusive ``flock`` on ``<data_dir>/.jobs-runner.lock``,
so with several uvicorn workers only one of them runs jobs while every one accepts, reports and
cancels them. The runner only coordinates: the work runs in child processes (a sweep's worker
pool or Dask, gprMax) or in the runner's own thread (a full-wave job's trace), never on the event
loop. Cancellation is a ``cancel.requested`` file in the job's directory that the runner watches
(so any worker process can ask for it); the kind's ``execute`` gets it as an event and stops its
children.

Admission is per kind (``sweep_max_queue``, ``fullwave_max_queue``: jobs queued or running;
beyond, 503 + Retry-After); every job is validated before its 202, and its cost goes through the
service's one rule (:mod:`service.admission`): a kind implements :meth:`JobKind.estimate` and queues
with :meth:`JobKind.create`, which admits the cost (422 naming the field) before anything is written.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import re
import secrets
import shutil
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

from service.admission import Cost, admit
from service.errors import Conflict, NotFound, ServerSaturated
from service.security import check_owner
from service.settings import Settings
from service.workers import WORKERS_DIR, clear, reap

log = logging.getLogger("capsule_rt.jobs")

CANCEL_FILE = "cancel.requested"
#: The job's owner: the id of the API key that submitted it (service.security.owner_id), or null.
OWNER_FILE = "owner.json"
ACTIVE = ("queued", "running")
#: How often the runner looks for new jobs and cancellation requests [s].
POLL_S = 0.5
LOCK_FILE = ".jobs-runner.lock"


class JobKind:
    """One kind of job: where its directories live and how one is run (module docstring).

    A subclass sets ``kind``, ``prefix``, ``noun``, ``list_path``, ``id_loc`` and implements
    :meth:`exists`, :meth:`read_state`, :meth:`write_state`, :meth:`created_at`,
    :meth:`status`, :meth:`execute` and :meth:`estimate`; it submits through :meth:`create`."""

    kind = ""
    prefix = ""
    noun = "job"
    list_path = ""
    id_loc: list[str] = ["path", "job_id"]

    def __init__(self, runner: "JobRunner", settings: Settings, root: Path, max_queue: int) -> None:
        self.runner = runner
        self.settings = settings
        self.root = Path(root)
        self.max_queue = max_queue
        self.retry_after_s = settings.retry_after_s
        self._id_re = re.compile(rf"^{re.escape(self.prefix)}[0-9a-f]{{16}}$")
        runner.register(self)

    # ------------------------------------------------------------ the kind's own
    def exists(self, d: Path) -> bool:
        raise NotImplementedError

    def read_state(self, d: Path) -> dict[str, Any]:
        raise NotImplementedError

    def write_state(self, d: Path, state: dict[str, Any]) -> None:
        raise NotImplementedError

    def created_at(self, d: Path) -> float:
        raise NotImplementedError

    def status(self, job_id: str) -> dict[str, Any]:
        raise NotImplementedError

    def execute(self, job_id: str, cancel: threading.Event) -> str:
        """Run the job until it ends or ``cancel`` is set; its final state (recorded in its state)."""
        raise NotImplementedError

    def estimate(self, validated: Any) -> Cost:
        """What one job costs, from its validated request, before it is queued: its work products
        against their caps and the memory one of its computations holds (service.admission,
        docs/service.md "Bounded before work"). Every kind implements it; :meth:`create` admits it."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what the kind keeps between jobs (the runner is stopping)."""

    # ------------------------------------------------------------ shared
    def is_id(self, value: str) -> bool:
        return isinstance(value, str) and self._id_re.fullmatch(value) is not None

    def new_id(self) -> str:
        return self.prefix + secrets.token_hex(8)

    def job_dir(self, job_id: str) -> Path:
        """The job's directory, or :class:`NotFound` naming the path parameter."""
        if not self.is_id(job_id):
            raise NotFound(f"unknown {self.noun} {job_id!r}", loc=self.id_loc)
        d = self.root / job_id
        if not self.exists(d):
            raise NotFound(f"unknown {self.noun} {job_id!r} (GET {self.list_path} lists them)", loc=self.id_loc)
        return d

    def job_ids(self) -> list[str]:
        if not self.root.is_dir():
            return []
        return [d.name for d in self.root.iterdir() if self.is_id(d.name) and self.exists(d)]

    def active(self) -> int:
        return sum(1 for j in self.job_ids() if self.read_state(self.root / j).get("state") in ACTIVE)

    def create(self, cost: Cost, build: Callable[[Path], None], owner: str | None) -> str:
        """Queue a new job: ``cost`` through the one rule (422 naming its dominant field), then, under the
        queue's admission (503 beyond ``max_queue``), ``build(tmp)`` writes the job's files into a
        temporary directory that one rename makes the job (never half-written), with ``owner`` (the
        submitting key's id, :func:`service.security.owner_id`; None without keys). Its id."""
        admit(cost, self.settings)
        with self.admission():
            job_id = self.new_id()
            tmp = self.root / f".tmp-{job_id}"
            try:
                tmp.mkdir(parents=True)
                build(tmp)
                (tmp / OWNER_FILE).write_text(json.dumps({"owner": owner}))
                os.replace(tmp, self.root / job_id)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        return job_id

    @contextmanager
    def admission(self) -> Iterator[None]:
        """Hold the queue's lock while a job is created; 503 + Retry-After when ``max_queue`` are active."""
        with self.runner.submit_lock:
            if self.active() >= self.max_queue:
                raise ServerSaturated(
                    f"{self.max_queue} {self.noun}s are already queued or running ({self.kind}_max_queue); "
                    f"retry after {self.retry_after_s} s", loc=["server"],
                    headers={"Retry-After": str(self.retry_after_s)})
            yield

    def redact(self, text: str | None, job_dir: Path | None = None) -> str | None:
        """``text`` (a log, a message) without the server's file system: the job's own directory becomes
        ``.`` relative to the file asked for (``job_dir``: its run directory), the data directory
        ``<data_dir>``. Absolute paths tell a client where and as whom the server runs."""
        if not text:
            return text
        pairs = []
        if job_dir is not None:
            pairs += [(str(job_dir.resolve()), "."), (str(job_dir.absolute()), ".")]
        data = Path(self.settings.data_dir)
        pairs += [(str(data.resolve()), "<data_dir>"), (str(data.absolute()), "<data_dir>")]
        for path, replacement in sorted(set(pairs), key=lambda p: -len(p[0])):  # the longest first
            text = text.replace(path, replacement)
        return text

    def owner(self, job_id: str) -> str | None:
        """The id of the key that submitted the job (None: submitted without keys, or before owners were kept)."""
        try:
            return json.loads((self.job_dir(job_id) / OWNER_FILE).read_text()).get("owner")
        except (FileNotFoundError, ValueError, AttributeError):
            return None

    def cancel(self, job_id: str, requester: str | None = None) -> dict[str, Any]:
        """Cancel a queued or running job; delete a finished one (and all its files). With API keys in use
        (``requester``: the request's key id), only the key that submitted the job may (403 otherwise)."""
        d = self.job_dir(job_id)
        check_owner(self.owner(job_id), requester, f"{self.noun} {job_id}")
        state = self.read_state(d)
        if state.get("state") in ACTIVE:
            (d / CANCEL_FILE).touch()
            if state.get("state") == "queued":
                with self.runner.submit_lock:
                    if self.read_state(d).get("state") == "queued" and not self.runner.is_current(self, job_id):
                        self.write_state(d, {**state, "state": "cancelled", "finished_at": time.time()})
            out = self.status(job_id)
            out["deleted"] = False
            return out
        out = self.status(job_id)
        trash = self.root / f".trash-{job_id}-{secrets.token_hex(4)}"
        try:
            os.replace(d, trash)
        except FileNotFoundError:
            raise Conflict(f"{self.noun} {job_id} is being deleted", loc=self.id_loc) from None
        shutil.rmtree(trash, ignore_errors=True)
        out["deleted"] = True
        return out


class JobRunner:
    """The one runner of a data directory's jobs, of every kind (module docstring)."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)
        #: Where the kinds' worker processes record themselves (service.workers).
        self.workers_dir = self.data_dir / WORKERS_DIR
        self.kinds: list[JobKind] = []
        self.submit_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock_fd: int | None = None
        self._current: tuple[JobKind, str, threading.Event] | None = None

    def register(self, kind: JobKind) -> None:
        """Add a kind to the queue; one that does not say what its jobs cost is refused (service.admission)."""
        if type(kind).estimate is JobKind.estimate:
            raise TypeError(f"job kind {type(kind).__name__} must implement estimate() (docs/service.md, "
                            "'Bounded before work')")
        self.kinds.append(kind)

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start the runner thread; when this process gets the data directory's lock at once, it first reaps
        what a killed runner left (its workers, its partial submissions), before the service says ready."""
        for kind in self.kinds:
            kind.root.mkdir(parents=True, exist_ok=True)
        self._take_lock()
        self._thread = threading.Thread(target=self._run, name="job-runner", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 20.0) -> None:
        """Stop the runner; a running job is interrupted (its children killed) and left ``queued`` to resume."""
        self._stop.set()
        current = self._current
        if current is not None:
            current[2].set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        for kind in self.kinds:
            kind.close()
        clear(self.workers_dir)  # every pool shut down cleanly: nothing for the next start to reap
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def is_current(self, kind: JobKind, job_id: str) -> bool:
        current = self._current
        return current is not None and current[0] is kind and current[1] == job_id

    # ------------------------------------------------------------ runner
    def _take_lock(self) -> bool:
        if self._lock_fd is not None:
            return True
        self.data_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.data_dir / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        self._lock_fd = fd
        reap(self.workers_dir)  # the worker processes of a runner that was killed (service.workers)
        for kind in self.kinds:  # leftovers of submissions and deletions a crash interrupted
            if kind.root.is_dir():
                for entry in kind.root.iterdir():
                    if entry.name.startswith((".tmp-", ".trash-")):
                        shutil.rmtree(entry, ignore_errors=True)
        return True

    def _next(self) -> tuple[JobKind, str] | None:
        jobs = []
        for k, kind in enumerate(self.kinds):
            for job_id in kind.job_ids():
                d = kind.root / job_id
                if kind.read_state(d).get("state") in ACTIVE:  # "running" here: its runner died with it
                    jobs.append((kind.created_at(d), k, job_id))
        if not jobs:
            return None
        _, k, job_id = min(jobs)
        return self.kinds[k], job_id

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                if not self._take_lock():
                    self._stop.wait(POLL_S * 4)
                    continue
                job = self._next()
                if job is None:
                    self._stop.wait(POLL_S)
                    continue
                self._execute(*job)
            except Exception:  # a broken job must not stop the runner
                log.exception("job runner error")
                self._stop.wait(POLL_S)

    def _execute(self, kind: JobKind, job_id: str) -> None:
        d = kind.root / job_id
        cancel = threading.Event()
        with self.submit_lock:
            if (d / CANCEL_FILE).exists():
                kind.write_state(d, {**kind.read_state(d), "state": "cancelled", "finished_at": time.time()})
                return
            self._current = (kind, job_id, cancel)
        done = threading.Event()

        def watch() -> None:
            while not done.wait(POLL_S):
                if (d / CANCEL_FILE).exists():
                    cancel.set()
                    return

        watcher = threading.Thread(target=watch, name=f"job-watch-{job_id}", daemon=True)
        watcher.start()
        log.info(f"{kind.kind} started", extra={kind.kind: job_id})
        try:
            final = kind.execute(job_id, cancel)
        except Exception as exc:  # the kind has recorded the failure in its state
            log.exception(f"{kind.kind} failed", extra={kind.kind: job_id})
            final = f"failed: {exc}"
        finally:
            done.set()
            self._current = None
        if self._stop.is_set() and not (d / CANCEL_FILE).exists():
            # the service is shutting down, not the user cancelling: resume at the next start
            kind.write_state(d, {**kind.read_state(d), "state": "queued", "finished_at": None})
            final = "interrupted (will resume)"
        log.info(f"{kind.kind} ended", extra={kind.kind: job_id, "state": final})
