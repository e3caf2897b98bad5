"""The job runner's worker processes: each in a process group of its own, recorded on disk, and reaped by
the next runner of the data directory when the server that started them was killed (SIGKILL, OOM killer).

A local sweep pool's workers (``sweeps.engines.ProcessEngine``, spawned) run :func:`register` first: the
worker makes itself the leader of a new process group (so it and anything it starts go together, and a
terminal's Ctrl-C to the server's group does not kill it mid-task) and writes ``<pid>`` into
``<data_dir>/.jobs-workers/`` with its start time (``/proc/<pid>/stat``, field 22). Normally the pool is
shut down with the runner. When the server dies without that, the workers outlive it (each holds the
others' end of the pool's queues, so none ever sees EOF) until the next runner of the data directory,
which holds its lock (:class:`service.jobs.JobRunner`), calls :func:`reap`: every recorded worker that
still runs with the recorded start time (not a recycled pid) is killed with its group, and the records
are cleared. The multiprocessing resource tracker the dead server started exits by itself once no worker
holds its pipe. This module imports nothing heavy: it runs first in every spawned worker.
"""

from __future__ import annotations

import logging
import os
import signal
from pathlib import Path

log = logging.getLogger("capsule_rt.jobs")

WORKERS_DIR = ".jobs-workers"


def start_time(pid: int) -> int | None:
    """The process's start time [clock ticks after boot] (None: no such process, or not Linux)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(text[text.rindex(")") + 2:].split()[19])


def register(directory: str) -> None:
    """A worker's initializer: lead a process group of its own and record itself in ``directory``."""
    os.setpgid(0, 0)
    pid = os.getpid()
    started = start_time(pid)
    if started is None:  # pragma: no cover - not Linux: nothing to reap by later
        return
    path = Path(directory)
    path.mkdir(parents=True, exist_ok=True)
    tmp = path / f".{pid}.tmp"
    tmp.write_text(str(started))
    os.replace(tmp, path / str(pid))


def reap(directory: Path) -> list[int]:
    """Kill (with their process groups) the recorded workers still running, and clear every record; the
    pids killed. Call it only while holding the runner's lock: the records are then a dead runner's."""
    killed: list[int] = []
    if not directory.is_dir():
        return killed
    for record in directory.iterdir():
        try:
            pid, recorded = int(record.name), int(record.read_text())
        except ValueError:  # a partial write (.<pid>.tmp) or a stranger: only cleared
            record.unlink(missing_ok=True)
            continue
        if start_time(pid) == recorded:
            try:
                os.killpg(pid, signal.SIGKILL)  # the worker leads its group: it and its children
                killed.append(pid)
            except ProcessLookupError:
                pass
        record.unlink(missing_ok=True)
    if killed:
        log.warning("killed the worker processes a killed server left running", extra={"pids": killed})
    return killed


def clear(directory: Path) -> None:
    """Forget every record (the pool was shut down cleanly)."""
    if directory.is_dir():
        for record in directory.iterdir():
            record.unlink(missing_ok=True)
