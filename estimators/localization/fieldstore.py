"""The travel-time fields of many sensors on one grid: built in parallel, kept in memory and on
disk (docs/localization.md, "Travel-time fields", "Speed").

    fields_for_sensors(grid_key, sensors_m, index_grid, *, cache_dir=None, workers=None, check=None)
        -> TravelTimeFields

``grid_key`` names the index grid without building it: the caller's content hash of what the
grid depends on (for a phantom: its geometry and materials, the frequency, the delay kind and
the cell size; ``evaluation.fields``). ``index_grid()`` builds the grid -- ``(index, origin_m,
spacing_m)`` -- and is called only when some sensor's field is in neither cache, so a restarted
server whose disk cache holds the fields skips the voxelization too.

Caches, per field key ``(grid_key, sensor position to 1 nm, order, source radius, format)``:

* **memory**: the in-process LRU of :mod:`.traveltime` (``CACHE_MAX_BYTES``);
* **disk** (``cache_dir``; none when None): one ``.npz`` per field in ``cache_dir``, written to a
  temporary file in the same directory and renamed over the final name (``os.replace``: readers
  see the whole file or none, also across processes), bounded to ``max_bytes`` by deleting the
  least recently used files (a hit refreshes its mtime). A file that does not load (truncated,
  another format) is a miss and is rewritten.

Misses are solved in ``workers`` processes (scikit-fmm holds the GIL, so threads would run one at
a time): a spawned process pool, one task per sensor, each sending back its field; the budget's
``check`` runs as each finishes and may stop the rest. One miss, one worker, a process that may
not have children (a daemonic pool worker), or a plain script without a ``__main__`` guard
(:func:`spawn_safe`) solve in the caller; so do the rest if a worker dies. The numbers do not depend on where
a field was solved (the same code on the same arrays).
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EstimatorInputError
from . import traveltime as tt

__all__ = ["DISK_CACHE_MAX_BYTES", "FORMAT", "clear_disk_cache", "disk_cache_bytes", "field_key",
           "fields_for_sensors"]

#: Bump when a stored field's meaning changes (solver, source model, error statement).
FORMAT = 1
#: Default bound of the disk cache [bytes] (the torso at 4 mm: 6.1 MB per field, ~330 fields).
DISK_CACHE_MAX_BYTES = 2 * 2**30
_SUFFIX = ".npz"
#: A temporary file older than this was left by a writer that died [s]; eviction removes it.
_STALE_TMP_S = 3600.0
_SCALARS = ("spacing_m", "max_index", "source_index", "source_radius_m", "discretisation_error_s", "order")


def field_key(grid_key: str, sensor_m: np.ndarray, order: int, source_radius_cells: float) -> str:
    """The cache key of one sensor's field on the grid ``grid_key`` (module docstring)."""
    s = np.round(np.asarray(sensor_m, float) * 1e9).astype(np.int64)  # 1 nm: below any cell
    text = f"{FORMAT}|{grid_key}|{s.tolist()}|{int(order)}|{float(source_radius_cells)!r}"
    return hashlib.blake2b(text.encode(), digest_size=20).hexdigest()


def fields_for_sensors(grid_key: str, sensors_m: Any, index_grid: Callable[[], tuple], *,
                       cache_dir: str | Path | None = None, max_bytes: int = DISK_CACHE_MAX_BYTES,
                       workers: int | None = None, check: Callable[[], None] | None = None, order: int = 2,
                       source_radius_cells: float = tt.SOURCE_RADIUS_CELLS,
                       field: str = "sensors") -> tt.TravelTimeFields:
    """Every sensor's field (module docstring), stacked. ``workers`` None: the CPUs this process
    may use that the load average leaves idle, plus one (one: solved here). Errors:
    EstimatorInputError naming ``{field}[i].position_m`` for a sensor outside the grid or its
    propagation domain, or the grid's field for a bad grid."""
    try:
        sensors = np.asarray(sensors_m, dtype=float).reshape(-1, 3)
    except (TypeError, ValueError):
        raise EstimatorInputError("must be an (N, 3) array of positions [m]", field) from None
    if not len(sensors):
        raise EstimatorInputError("give at least one sensor", field)
    keys = [field_key(grid_key, s, order, source_radius_cells) for s in sensors]
    stacked = tt.stack_get(tuple(keys))
    if stacked is not None:
        return stacked
    disk = None if cache_dir is None else Path(cache_dir)
    out: list[tt.TravelTimeField | None] = [None] * len(sensors)
    missing: list[int] = []
    for i, key in enumerate(keys):
        hit = tt.memory_get(key)
        if hit is None and disk is not None:
            hit = _load(disk / (key + _SUFFIX))
            if hit is not None:
                tt.memory_put(key, hit)
        if hit is None:
            missing.append(i)
        out[i] = hit
    if missing:
        if check is not None:
            check()
        count = _worker_count(workers, len(missing))
        pool = None if count == 1 else _start_pool(count)  # its processes start while the grid is built
        finished = False
        try:
            n, origin, h = tt.check_index_grid(*index_grid())
            for i in missing:  # every sensor checked before any work
                tt.check_sensor(sensors[i], origin, h, n.shape, f"{field}[{i}].position_m")
            solved = (_serial if pool is None else _parallel)(pool, n, origin, h, sensors, missing, order,
                                                              source_radius_cells, check, field)
            for i, f in solved:
                tt.memory_put(keys[i], f)
                if disk is not None:
                    _store(disk, keys[i] + _SUFFIX, f, max_bytes)
                out[i] = f
            finished = True
        finally:
            if pool is not None:
                # done: the idle workers exit at once and are reaped here; stopped (a budget, an
                # error): queued solves are cancelled and nobody waits for the running ones
                pool.shutdown(wait=finished, cancel_futures=True)
    complete = [f for f in out if f is not None]
    assert len(complete) == len(out), "every sensor's field was loaded or solved"
    stacked = tt.TravelTimeFields(complete)
    tt.stack_put(tuple(keys), stacked)
    return stacked


# ------------------------------------------------------------------------ solving
def _solve_one(n, origin, h, sensor, order, radius_cells):
    """Pool task: ('ok', field) or ('error', reason) (exceptions with a field do not pickle whole)."""
    try:
        return "ok", tt.solve(n, origin, h, sensor, order, radius_cells)
    except EstimatorInputError as exc:
        return "error", exc.reason


def _ready() -> bool:
    """Pool warm-up task: the worker has started and imported the solver."""
    return True


def _worker_count(workers: int | None, tasks: int) -> int:
    if workers is None:
        if not spawn_safe():
            return 1
        try:
            cpus = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cpus = os.cpu_count() or 1
        # the idle CPUs (by the 1-minute load average): on a busy machine spawned solvers only add
        # their interpreters' start to the same CPU time (measured: bench/localization.py)
        workers = max(1, min(cpus, int(round(cpus - os.getloadavg()[0])) + 1))
    if multiprocessing.current_process().daemon:  # a pool's worker may not start processes
        return 1
    return max(1, min(int(workers), tasks))


def spawn_safe() -> bool:
    """Whether spawned workers can start from this process: a spawned interpreter imports the
    parent's ``__main__`` again. A module run with ``-m``, an entry point (``capsule-rt``, pytest,
    uvicorn) or an interactive session is imported by name or not at all; a plain script is run
    again, which is harmless only behind ``if __name__ == "__main__"`` -- a script that never
    mentions ``__main__`` gets the serial path (``workers=None``) rather than its own body run
    once per worker."""
    main = sys.modules.get("__main__")
    if main is None or getattr(main, "__spec__", None) is not None:
        return True
    path = getattr(main, "__file__", None)
    if path is None:
        return True
    try:
        return "__main__" in Path(path).read_text(errors="replace")
    except OSError:
        return False


def _start_pool(count: int) -> ProcessPoolExecutor:
    """A spawned pool whose ``count`` processes are started now (one warm-up task each): a
    spawned interpreter takes ~1 s to import numpy, scipy and scikit-fmm, which then overlaps
    the voxelization of the grid in the caller."""
    pool = ProcessPoolExecutor(max_workers=count, mp_context=multiprocessing.get_context("spawn"))
    for _ in range(count):
        pool.submit(_ready)
    return pool


def _serial(pool, n, origin, h, sensors, missing, order, radius_cells, check, field):
    for i in missing:
        if check is not None:
            check()
        yield i, _named(_solve_one(n, origin, h, sensors[i], order, radius_cells), field, i)


def _parallel(pool, n, origin, h, sensors, missing, order, radius_cells, check, field):
    pending = {pool.submit(_solve_one, n, origin, h, sensors[i], order, radius_cells): i for i in missing}
    while pending:
        done, _ = wait(pending, return_when=FIRST_COMPLETED)
        for future in done:
            i = pending.pop(future)
            try:
                result = future.result()
            except BrokenProcessPool:  # a worker died (killed, out of memory): solve the rest here
                rest = [i, *pending.values()]
                pending.clear()
                yield from _serial(None, n, origin, h, sensors, rest, order, radius_cells, check, field)
                return
            yield i, _named(result, field, i)
        if check is not None and pending:
            check()


def _named(result, field: str, i: int) -> tt.TravelTimeField:
    status, value = result
    if status == "error":
        raise EstimatorInputError(value, f"{field}[{i}].position_m")
    return value


# ------------------------------------------------------------------------ disk
def _load(path: Path) -> tt.TravelTimeField | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["format"]) != FORMAT:
                return None
            scalars: dict[str, Any] = {k: (int(z[k]) if k == "order" else float(z[k])) for k in _SCALARS}
            field = tt.TravelTimeField(
                sensor_position_m=z["sensor_position_m"], origin_m=z["origin_m"], time_s=z["time_s"],
                domain=z["domain"], **scalars)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError):
        return None
    try:
        os.utime(path)  # recently used: evicted last
    except OSError:
        pass
    return field


def _store(disk: Path, name: str, field: tt.TravelTimeField, max_bytes: int) -> None:
    """Atomic write (temporary file + rename), then the size bound. A full or read-only disk
    only loses the cache entry: the field itself is already in hand."""
    try:
        disk.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=disk, prefix=".tmp-", suffix=_SUFFIX)
        try:
            with os.fdopen(fd, "wb") as fh:
                arrays: dict[str, Any] = {k: np.asarray(getattr(field, k)) for k in _SCALARS}
                np.savez(fh, format=np.int64(FORMAT), sensor_position_m=field.sensor_position_m,
                         origin_m=field.origin_m, time_s=field.time_s, domain=field.domain, **arrays)
            os.replace(tmp, disk / name)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        _evict(disk, max_bytes)
    except OSError:
        return


def disk_cache_bytes(cache_dir: str | Path) -> int:
    """Bytes of the stored fields in ``cache_dir``."""
    return sum(size for _, size, _ in _entries(Path(cache_dir)))


def _entries(disk: Path):
    out = []
    for p in disk.glob("[!.]*" + _SUFFIX):
        try:
            st = p.stat()
        except OSError:
            continue
        out.append((p, st.st_size, st.st_mtime))
    return out


def _evict(disk: Path, max_bytes: int) -> None:
    now = time.time()
    for tmp in disk.glob(".tmp-*"):
        try:
            if now - tmp.stat().st_mtime > _STALE_TMP_S:
                tmp.unlink(missing_ok=True)
        except OSError:
            pass
    entries = sorted(_entries(disk), key=lambda e: e[2])  # oldest first
    total = sum(size for _, size, _ in entries)
    for path, size, _ in entries:
        if total <= max_bytes:
            break
        path.unlink(missing_ok=True)
        total -= size


def clear_disk_cache(cache_dir: str | Path) -> None:
    """Delete every stored field of ``cache_dir`` (tests, benches)."""
    for path, _, _ in _entries(Path(cache_dir)):
        path.unlink(missing_ok=True)

