"""The small persistent thread pool of vision/'s GIL-free kernels (the MI histograms, the mucosa).

As the tracer does (``THREADS = min(2, cpus)``): work is cut into THREADS parts handed to
workers that run compiled ``nogil`` code; no numba ``prange``, whose OpenMP workers spin while
they wait, which on a shared 2-core machine costs more than it gains.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

THREADS = min(2, os.cpu_count() or 1)
_POOL: ThreadPoolExecutor | None = None
_LOCK = threading.Lock()


def pool() -> ThreadPoolExecutor:
    """The process's pool of THREADS workers (made on first use)."""
    global _POOL
    with _LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=THREADS, thread_name_prefix="vision")
        return _POOL
