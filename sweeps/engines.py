"""Where a sweep's tasks run: in this process, a local process pool, or a Dask cluster.

Each engine's :meth:`run` takes a function and task inputs and yields ``(index, output)``
pairs as tasks finish (``output`` is the task's return value or the exception it raised),
stopping early when ``cancel`` is set. The function and its inputs are the same whatever
the engine, and so are the outputs (``docs/sweeps.md``, "Engines"). ``shared`` (keyword
arguments every task gets, e.g. an uploaded phantom's files) is sent once per run: a Dask
engine scatters it to every worker once (its workers may be other machines that do not see
this one's files: ``remote``), the local engines pass it along.

* :class:`SerialEngine` (``workers=0``): a plain loop in this process (tests, benchmarks'
  reference, debugging).
* :class:`ProcessEngine` (the default): a ``concurrent.futures`` pool of ``workers``
  processes started with ``spawn`` (no fork of a threaded parent). A worker that dies
  (killed, out of memory) breaks the pool; the engine starts a new pool and resubmits the
  unfinished tasks, up to :data:`MAX_POOL_RESTARTS` times.
* :class:`DaskEngine` (``--cluster ADDRESS``): an existing ``dask.distributed`` scheduler;
  Dask itself reschedules the tasks of a worker that dies (``distributed.scheduler.allowed-failures``).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import secrets
import threading
import time
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

__all__ = ["DaskEngine", "MAX_POOL_RESTARTS", "ProcessEngine", "SerialEngine", "default_workers", "make_engine"]

#: How many times a local pool is restarted after a worker died, per sweep run.
MAX_POOL_RESTARTS = 3
#: How often a waiting engine checks for cancellation [s].
POLL_S = 0.2

Result = tuple[int, Any]


def default_workers() -> int:
    """Worker processes of the default pool: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class SerialEngine:
    name = "serial"
    remote = False

    def close(self) -> None:
        pass

    def run(self, fn: Callable, inputs: Sequence, cancel: threading.Event | None = None,
            shared: dict | None = None) -> Iterator[Result]:
        for i, item in enumerate(inputs):
            if cancel is not None and cancel.is_set():
                return
            try:
                yield i, fn(item, **(shared or {}))
            except Exception as exc:  # noqa: BLE001 - reported as the task's failure
                yield i, exc


class ProcessEngine:
    """A pool of ``workers`` spawned processes, kept between runs (each worker keeps its phantoms
    and compiled kernels) until :meth:`close`; rebuilt after a worker died or a run was cancelled.
    ``initializer(*initargs)`` runs first in every worker (the service's: service.workers.register)."""

    remote = False

    def __init__(self, workers: int, initializer: Callable | None = None, initargs: tuple = ()) -> None:
        self.workers = int(workers)
        self.name = f"local:{self.workers}"
        self.restarts = 0
        self.initializer, self.initargs = initializer, tuple(initargs)
        self._pool: cf.ProcessPoolExecutor | None = None

    @property
    def pids(self) -> list[int]:
        """pids of the current pool's workers (for operators and tests)."""
        return [p.pid for p in (getattr(self._pool, "_processes", None) or {}).values()]

    def _get_pool(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            self._pool = cf.ProcessPoolExecutor(max_workers=self.workers,
                                                mp_context=multiprocessing.get_context("spawn"),
                                                initializer=self.initializer, initargs=self.initargs)
        return self._pool

    def _kill(self) -> None:
        if self._pool is not None:
            _terminate(self._pool)
            self._pool = None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def run(self, fn: Callable, inputs: Sequence, cancel: threading.Event | None = None,
            shared: dict | None = None) -> Iterator[Result]:
        pending = dict(enumerate(inputs))
        restarts = 0
        while pending:
            pool = self._get_pool()
            futures = {pool.submit(fn, item, **(shared or {})): i for i, item in pending.items()}
            broken = False
            try:
                not_done = set(futures)
                while not_done:
                    if cancel is not None and cancel.is_set():
                        self._kill()
                        return
                    done, not_done = cf.wait(not_done, timeout=POLL_S, return_when=cf.FIRST_COMPLETED)
                    for fut in done:
                        i = futures[fut]
                        exc = fut.exception()
                        if isinstance(exc, BrokenProcessPool):
                            broken = True
                            continue
                        pending.pop(i)
                        yield i, (exc if exc is not None else fut.result())
                    if broken:
                        break
            finally:
                if broken or pending:  # a dead worker, a cancel, or the consumer stopped early
                    self._kill()
            if broken:
                restarts += 1
                self.restarts += 1
                if restarts > MAX_POOL_RESTARTS:
                    for i in list(pending):
                        pending.pop(i)
                        yield i, RuntimeError(f"a worker process died and the pool was restarted "
                                              f"{MAX_POOL_RESTARTS} times; giving up on this task")
                    return


def _terminate(pool: cf.ProcessPoolExecutor) -> None:
    """Stop a pool now: cancel what waits, kill what runs (a running task cannot be interrupted otherwise)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.kill()
    for p in processes:
        p.join(timeout=5)


class DaskEngine:
    """The tasks on a ``dask.distributed`` scheduler at ``address`` (``tcp://host:8786``): its workers
    may be processes on other machines, started as on a cluster (``dask scheduler``, ``dask worker``;
    docs/sweeps.md, "Across machines")."""

    remote = True

    def __init__(self, address: str, *, client: Any = None) -> None:
        self.address = address
        self.name = f"dask:{address}"
        self._client = client

    def client(self):
        if self._client is None:
            from distributed import Client

            self._client = Client(self.address, timeout="30s", set_as_default=False)
        return self._client

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def run(self, fn: Callable, inputs: Sequence, cancel: threading.Event | None = None,
            shared: dict | None = None) -> Iterator[Result]:
        client = self.client()
        run_id = secrets.token_hex(4)  # fresh keys: a resubmitted task is never a cached old result
        # shared values go to every worker once (a worker that joins later fetches them from a peer
        # when its first task needs them); each task gets them as futures, resolved on its worker
        scattered = {name: client.scatter(value, broadcast=True, hash=False) for name, value in (shared or {}).items()}
        futures = [client.submit(fn, item, **scattered, key=f"capsule-rt-sweep-{run_id}-{i}", pure=False)
                   for i, item in enumerate(inputs)]
        pending = dict(enumerate(futures))
        try:
            while pending:
                if cancel is not None and cancel.is_set():
                    return
                finished = [i for i, f in pending.items() if f.done()]
                if not finished:
                    time.sleep(POLL_S / 4)
                    continue
                for i in finished:
                    fut = pending.pop(i)
                    if fut.status == "error":
                        yield i, fut.exception()
                    elif fut.status == "cancelled":
                        yield i, RuntimeError("the task was cancelled on the cluster")
                    else:
                        yield i, fut.result()
        finally:
            unfinished = [f for f in pending.values() if not f.done()]
            if unfinished:
                client.cancel(unfinished)
            for value in scattered.values():
                value.release()


def make_engine(workers: int | None = None, cluster: str | None = None, initializer: Callable | None = None,
                initargs: tuple = ()):
    """The engine of a sweep: Dask when ``cluster`` is an address, else the local pool of ``workers``
    processes (default :func:`default_workers`; each runs ``initializer(*initargs)`` first), or this
    process for ``workers=0``."""
    if cluster:
        return DaskEngine(cluster)
    n = default_workers() if workers is None else int(workers)
    if n < 0:
        raise ValueError("workers must be >= 0")
    return SerialEngine() if n == 0 else ProcessEngine(n, initializer, initargs)
