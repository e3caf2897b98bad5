"""Where a sweep's tasks run: in this process, a local process pool, or a Dask cluster.

Each engine's :meth:`run` takes a function and task inputs and yields ``(index, output)``
pairs as tasks finish (``output`` is the task's return value or the exception it raised),
stopping early when ``cancel`` is set. The function and its inputs are the same whatever
the engine, and so are the outputs (``docs/sweeps.md``, "Engines").

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

    def run(self, fn: Callable, inputs: Sequence, cancel: threading.Event | None = None) -> Iterator[Result]:
        for i, item in enumerate(inputs):
            if cancel is not None and cancel.is_set():
                return
            try:
                yield i, fn(item)
            except Exception as exc:  # noqa: BLE001 - reported as the task's failure
                yield i, exc


class ProcessEngine:
    def __init__(self, workers: int) -> None:
        self.workers = int(workers)
        self.name = f"local:{self.workers}"
        self.restarts = 0
        #: pids of the current pool's workers (for operators and tests)
        self.pids: list[int] = []

    def run(self, fn: Callable, inputs: Sequence, cancel: threading.Event | None = None) -> Iterator[Result]:
        pending = dict(enumerate(inputs))
        context = multiprocessing.get_context("spawn")
        while pending:
            pool = cf.ProcessPoolExecutor(max_workers=min(self.workers, len(pending)), mp_context=context)
            futures = {pool.submit(fn, item): i for i, item in pending.items()}
            broken = False
            try:
                not_done = set(futures)
                while not_done:
                    if cancel is not None and cancel.is_set():
                        _terminate(pool)
                        return
                    done, not_done = cf.wait(not_done, timeout=POLL_S, return_when=cf.FIRST_COMPLETED)
                    self.pids = [p.pid for p in (getattr(pool, "_processes", None) or {}).values()]
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
                if broken or pending:
                    _terminate(pool)
                else:
                    pool.shutdown(wait=True)
            if broken:
                self.restarts += 1
                if self.restarts > MAX_POOL_RESTARTS:
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

    def run(self, fn: Callable, inputs: Sequence, cancel: threading.Event | None = None) -> Iterator[Result]:
        from distributed import as_completed

        client = self.client()
        run_id = secrets.token_hex(4)  # fresh keys: a resubmitted task is never a cached old result
        futures = [client.submit(fn, item, key=f"capsule-rt-sweep-{run_id}-{i}", pure=False)
                   for i, item in enumerate(inputs)]
        index = {f.key: i for i, f in enumerate(futures)}
        ac = as_completed(futures)
        try:
            while not ac.is_empty():
                if cancel is not None and cancel.is_set():
                    client.cancel(futures)
                    return
                batch = ac.next_batch(block=False)
                if not batch:
                    time.sleep(POLL_S / 4)
                    continue
                for fut in batch:
                    if fut.status == "error":
                        yield index[fut.key], fut.exception()
                    elif fut.status == "cancelled":
                        yield index[fut.key], RuntimeError("the task was cancelled on the cluster")
                    else:
                        yield index[fut.key], fut.result()
        finally:
            client.cancel([f for f in futures if not f.done()])


def make_engine(workers: int | None = None, cluster: str | None = None):
    """The engine of a sweep: Dask when ``cluster`` is an address, else the local pool of ``workers``
    processes (default :func:`default_workers`), or this process for ``workers=0``."""
    if cluster:
        return DaskEngine(cluster)
    n = default_workers() if workers is None else int(workers)
    if n < 0:
        raise ValueError("workers must be >= 0")
    return SerialEngine() if n == 0 else ProcessEngine(n)
