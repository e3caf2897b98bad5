"""Run heavy work (tracing, Monte Carlo) off the event loop, with admission control.

At most ``max_concurrency`` computations run at once (worker threads bounded
by an :class:`anyio.CapacityLimiter`; embreex and numpy release the GIL), at
most ``max_queue`` more wait for a slot, and anything beyond is refused at
once with 503 + Retry-After instead of queueing without bound. Each
computation gets a :class:`raytrace.budget.Budget` (deadline and work cap)
that the tracer checks inside its loops, so a thread that runs too long
stops itself; the budget is also cancelled when the server shuts down.
"""

from __future__ import annotations

import threading
import time
from typing import Callable, TypeVar

import anyio
import anyio.to_thread

from raytrace.budget import Budget
from raytrace.errors import BudgetExceededError
from service.errors import ServerSaturated
from service.metrics import Metrics

T = TypeVar("T")


class ComputeGate:
    def __init__(self, max_concurrency: int, max_queue: int, retry_after_s: int, metrics: Metrics) -> None:
        self.max_concurrency = max_concurrency
        self.max_queue = max_queue
        self.retry_after_s = retry_after_s
        self.metrics = metrics
        self._limiter: anyio.CapacityLimiter | None = None
        self._admitted = 0
        self._running = 0
        self._lock = threading.Lock()
        self._budgets: dict[int, Budget] = {}

    @property
    def limiter(self) -> anyio.CapacityLimiter:
        if self._limiter is None:  # created lazily inside the running event loop
            self._limiter = anyio.CapacityLimiter(self.max_concurrency)
        return self._limiter

    @property
    def admitted(self) -> int:
        return self._admitted

    def cancel_all(self) -> None:
        with self._lock:
            for b in list(self._budgets.values()):
                b.cancel()

    async def run(self, fn: Callable[[Budget], T], budget: Budget) -> T:
        """Run ``fn(budget)`` in a worker thread, or raise :class:`ServerSaturated` at once."""
        with self._lock:
            if self._admitted >= self.max_concurrency + self.max_queue:
                self.metrics.rejected.inc()
                raise ServerSaturated(
                    f"server saturated: {self._admitted} heavy computations in progress "
                    f"(limit {self.max_concurrency} running + {self.max_queue} queued); retry after "
                    f"{self.retry_after_s} s",
                    loc=["server"],
                    headers={"Retry-After": str(self.retry_after_s)},
                )
            self._admitted += 1
            self._budgets[id(budget)] = budget
            self._update_gauges()

        def work() -> T:
            with self._lock:
                self._running += 1
                self._update_gauges()
            # The deadline counts from the moment the thread starts, not from admission.
            budget.started = time.monotonic()
            try:
                return fn(budget)
            finally:
                with self._lock:
                    self._running -= 1
                    self._update_gauges()

        try:
            return await anyio.to_thread.run_sync(work, limiter=self.limiter)
        except BudgetExceededError as exc:
            self.metrics.budget_exceeded.labels(exc.kind).inc()
            raise
        finally:
            with self._lock:
                self._admitted -= 1
                self._budgets.pop(id(budget), None)
                self._update_gauges()

    def _update_gauges(self) -> None:
        self.metrics.in_flight.set(self._running)
        self.metrics.waiting.set(max(self._admitted - self._running, 0))
