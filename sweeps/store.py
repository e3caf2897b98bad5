"""A sweep on disk: its spec, plan, state and one Parquet part per finished task (``docs/sweeps.md``, "Files").

Layout of a sweep directory::

    sweep.json                      spec (normalised), its sha256, the plan, the phantom source
    state.json                      state, progress, failures (rewritten as tasks finish)
    parts/task-000012.parquet       the rows of task 12 (its trace failures in the schema metadata)
    parts/task-000012.loc.parquet   its localization rows (when the spec asks for them)
    results.parquet                 every part, in task order (written when the sweep ends)
    localization.parquet            likewise

Every file is written to a temporary name in the same directory, flushed and fsynced,
then renamed over its final name (``os.replace``, atomic on POSIX) and the directory
fsynced: a killed sweep leaves whole parts or none, never a partial row. A task's part is
its completion record: a resumed sweep recomputes exactly the tasks without one (and the
tasks whose part recorded trace failures); recomputing a task replaces its part, so no
row is ever stored twice. A task's localization part is written before its main part.
"""

from __future__ import annotations

import json
import os
import secrets
import time
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

__all__ = ["SweepDir", "atomic_write"]

SWEEP_FILE = "sweep.json"
STATE_FILE = "state.json"
PARTS = "parts"
RESULTS = "results.parquet"
LOCALIZATION = "localization.parquet"
_FAILURES_KEY = b"capsule_rt.failures"


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` all-or-nothing (temporary file, fsync, rename, fsync the directory)."""
    path = Path(path)
    tmp = path.parent / f".tmp-{path.name}-{secrets.token_hex(4)}"
    try:
        with open(tmp, "xb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def parquet_bytes(table: pa.Table, metadata: dict[bytes, bytes] | None = None) -> bytes:
    if metadata:
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), **metadata})
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    return sink.getvalue().to_pybytes()


class SweepDir:
    """One sweep's directory (module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.parts = self.root / PARTS

    # ------------------------------------------------------------ sweep.json
    def exists(self) -> bool:
        return (self.root / SWEEP_FILE).is_file()

    def create(self, record: dict[str, Any]) -> None:
        self.parts.mkdir(parents=True, exist_ok=True)
        atomic_write(self.root / SWEEP_FILE, json.dumps(record, sort_keys=True).encode())

    def record(self) -> dict[str, Any]:
        return json.loads((self.root / SWEEP_FILE).read_text())

    def clean(self) -> None:
        """Remove temporary files an interrupted write left behind."""
        for d in (self.root, self.parts):
            if d.is_dir():
                for entry in d.iterdir():
                    if entry.name.startswith(".tmp-"):
                        entry.unlink(missing_ok=True)

    # ------------------------------------------------------------ state.json
    def read_state(self) -> dict[str, Any]:
        try:
            return json.loads((self.root / STATE_FILE).read_text())
        except FileNotFoundError:
            return {}

    def write_state(self, state: dict[str, Any]) -> None:
        state = {**state, "updated_at": time.time()}
        atomic_write(self.root / STATE_FILE, json.dumps(state, sort_keys=True, allow_nan=False).encode())

    # ------------------------------------------------------------ parts
    def part_path(self, task: int) -> Path:
        return self.parts / f"task-{task:06d}.parquet"

    def loc_part_path(self, task: int) -> Path:
        return self.parts / f"task-{task:06d}.loc.parquet"

    def write_part(self, task: int, table: pa.Table, failures: list[dict], loc_table: pa.Table | None = None) -> None:
        self.parts.mkdir(parents=True, exist_ok=True)
        if loc_table is not None:
            atomic_write(self.loc_part_path(task), parquet_bytes(loc_table))
        meta = {_FAILURES_KEY: json.dumps(failures, sort_keys=True).encode()}
        atomic_write(self.part_path(task), parquet_bytes(table, meta))

    def completed(self) -> dict[int, list[dict]]:
        """Tasks with a part on disk, and the trace failures each recorded."""
        out: dict[int, list[dict]] = {}
        if not self.parts.is_dir():
            return out
        for entry in self.parts.iterdir():
            name = entry.name
            if name.startswith("task-") and name.endswith(".parquet") and not name.endswith(".loc.parquet"):
                meta = pq.read_schema(entry).metadata or {}
                out[int(name[5:11])] = json.loads(meta.get(_FAILURES_KEY, b"[]"))
        return out

    def _concat(self, paths: list[Path], schema: pa.Schema) -> pa.Table:
        tables = [pq.read_table(p).replace_schema_metadata(None) for p in paths if p.is_file()]
        if not tables:
            return schema.empty_table()
        return pa.concat_tables(tables)

    def results(self, schema: pa.Schema, n_tasks: int) -> pa.Table:
        """Every finished task's rows, in task order (partial while the sweep runs)."""
        if (self.root / RESULTS).is_file():
            return pq.read_table(self.root / RESULTS)
        return self._concat([self.part_path(t) for t in range(n_tasks)], schema)

    def localization(self, schema: pa.Schema, n_tasks: int) -> pa.Table:
        if (self.root / LOCALIZATION).is_file():
            return pq.read_table(self.root / LOCALIZATION)
        done = self.completed()
        return self._concat([self.loc_part_path(t) for t in range(n_tasks) if t in done], schema)

    def finalize(self, schema: pa.Schema, loc_schema: pa.Schema | None, n_tasks: int) -> None:
        """Merge the parts into ``results.parquet`` (and ``localization.parquet``)."""
        table = self._concat([self.part_path(t) for t in range(n_tasks)], schema)
        if loc_schema is not None:
            loc = self._concat([self.loc_part_path(t) for t in range(n_tasks)], loc_schema)
            atomic_write(self.root / LOCALIZATION, parquet_bytes(loc))
        atomic_write(self.root / RESULTS, parquet_bytes(table))
