"""Work, memory and wall-time budget of one computation, checked inside the loops.

A timeout wrapped around a worker thread does not stop the thread; the tracer
calls :meth:`Budget.charge` once per bounce / batch instead, so a request that
runs out of time or work stops itself with :class:`BudgetExceededError`.
The service may also :meth:`cancel` it (e.g. the client went away).

Memory is counted the same way: the tracer :meth:`Budget.hold` s the bytes of the
arrays that grow with the request (the shooting's event logs, live rays and reception
candidates, the paths' band gains) as it allocates them and :meth:`Budget.release` s
them when it frees them; past ``max_bytes`` held at once the computation stops
(kind ``"memory"``). This is the safety net behind the estimate made before the work
(:mod:`raytrace.solver.footprint`, docs/service.md "Memory and work model of a channel request").
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from raytrace.errors import BudgetExceededError


@dataclass
class Budget:
    """``deadline_s``: wall time allowed from creation [s]; ``max_ray_segments``:
    cap on ray segments traced (one segment = one ray cast); ``max_bytes``: cap on the
    bytes the computation holds at once (:meth:`hold`). ``None`` = unlimited."""

    deadline_s: float | None = None
    max_ray_segments: int | None = None
    max_bytes: int | None = None
    started: float = field(default_factory=time.monotonic)
    ray_segments: int = 0
    #: bytes held now and at most so far (:meth:`hold`, :meth:`release`)
    bytes_held: int = 0
    peak_bytes: int = 0
    _cancelled: threading.Event = field(default_factory=threading.Event, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def cancel(self) -> None:
        self._cancelled.set()

    def elapsed_s(self) -> float:
        return time.monotonic() - self.started

    def hold(self, nbytes: int) -> None:
        """Account for ``nbytes`` newly allocated (negative: freed) and raise
        :class:`BudgetExceededError` (kind ``"memory"``) when more than ``max_bytes`` are held."""
        with self._lock:
            self.bytes_held += int(nbytes)
            self.peak_bytes = max(self.peak_bytes, self.bytes_held)
            held = self.bytes_held
        if nbytes > 0 and self.max_bytes is not None and held > self.max_bytes:
            raise BudgetExceededError(
                f"memory budget exceeded: the computation holds {held / 2**20:.0f} MiB, cap "
                f"{self.max_bytes / 2**20:.0f} MiB (the estimate made before it started was too low for this "
                "phantom); lower rays, max_interactions, dynamic_range_db or receivers",
                kind="memory",
            )

    def release(self, nbytes: int) -> None:
        """Account for ``nbytes`` freed (:meth:`hold`)."""
        self.hold(-int(nbytes))

    def charge(self, ray_segments: int = 0) -> None:
        """Account for work done and raise if a limit is passed (thread-safe: the tracer
        shoots launch batches concurrently)."""
        with self._lock:
            self.ray_segments += int(ray_segments)
        if self._cancelled.is_set():
            raise BudgetExceededError("the computation was cancelled", kind="cancelled")
        if self.max_ray_segments is not None and self.ray_segments > self.max_ray_segments:
            raise BudgetExceededError(
                f"work budget exceeded: {self.ray_segments} ray segments traced, cap "
                f"{self.max_ray_segments}; lower rays, max_interactions or receivers",
                kind="work",
            )
        if self.deadline_s is not None and self.elapsed_s() > self.deadline_s:
            raise BudgetExceededError(
                f"deadline exceeded: {self.elapsed_s():.2f} s > {self.deadline_s:.2f} s; "
                "lower rays, max_interactions or receivers",
                kind="deadline",
            )
