"""Run heavy work (tracing, Monte Carlo) off the event loop, with admission control.

At most ``max_concurrency`` computations run at once (worker threads bounded
by an :class:`anyio.CapacityLimiter`; embreex and numpy release the GIL), at
most ``max_queue`` more wait for a slot, and anything beyond is refused at
once with 503 + Retry-After instead of queueing without bound. Each
computation gets a :class:`raytrace.solver.budget.Budget` (deadline and work cap)
that the tracer checks inside its loops, so a thread that runs too long
stops itself; the budget is also cancelled when the server shuts down.
"""

from __future__ import annotations

import threading
import time
from typing import Awaitable, Callable, TypeVar

import anyio
import anyio.to_thread

from raytrace.errors import BudgetExceededError
from raytrace.solver.budget import Budget
from service.errors import ServerSaturated
from service.metrics import Metrics

T = TypeVar("T")

#: How often a running computation checks whether its client is still there [s].
DISCONNECT_POLL_S = 0.25


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

    async def run(
        self,
        fn: Callable[[Budget], T],
        budget: Budget,
        disconnected: Callable[[], Awaitable[bool]] | None = None,
    ) -> T:
        """Run ``fn(budget)`` in a worker thread, or raise :class:`ServerSaturated` at once.

        ``disconnected`` (e.g. ``request.is_disconnected``) is polled while the
        thread runs; when the client has gone the budget is cancelled, so the
        computation stops at its next budget check instead of running on."""
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

        async def watch() -> None:
            while True:
                await anyio.sleep(DISCONNECT_POLL_S)
                if await disconnected():
                    budget.cancel()
                    return

        try:
            if disconnected is None:
                return await anyio.to_thread.run_sync(work, limiter=self.limiter)
            outcome: dict[str, object] = {}
            async with anyio.create_task_group() as tg:
                tg.start_soon(watch)
                try:
                    outcome["value"] = await anyio.to_thread.run_sync(work, limiter=self.limiter)
                except Exception as exc:  # re-raised below, outside the task group (no ExceptionGroup)
                    outcome["error"] = exc
                finally:
                    tg.cancel_scope.cancel()
            if "error" in outcome:
                raise outcome["error"]  # type: ignore[misc]
            return outcome["value"]  # type: ignore[return-value]
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
