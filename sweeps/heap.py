"""The C heap a sweep task runs with, in a worker whose allocator was tuned from its environment.

Dask's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536``
(``distributed.nanny.pre-spawn-environ``) so that freed memory goes back to the system and
its memory monitor sees less "unmanaged" memory. In glibc, setting any heap parameter
explicitly also switches off the *dynamic* mmap threshold (``mallopt(3)``, M_MMAP_THRESHOLD:
"dynamic adjustment ... is disabled if any of M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD
or M_MMAP_MAX is set"), so every allocation above 128 KiB becomes a fresh ``mmap`` whose
pages are faulted in and zeroed again. The tracer makes many such temporaries (a float64
array over 20 000 rays is 160 KB): a sweep task ran ~25 % slower on a Dask worker than in a
plain process for this reason alone (``docs/sweeps.md``, "Performance").

:func:`task_heap` gives the task the heap a default glibc process converges to (mmap
threshold 32 MiB, trim threshold twice that: the dynamic scheme's ceilings on 64-bit) while it
runs, then puts the worker's own policy back and returns the freed memory to the system
(``malloc_trim(0)``), which is what the worker's setting asked for. It does nothing unless
the environment set a heap parameter (the dynamic threshold is then already off), nor off
glibc. Process-wide, so concurrent tasks of one worker share one setting: the first task in
sets it, the last one out restores it.
"""

from __future__ import annotations

import ctypes
import os
import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["HEAP_ENV", "MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "task_heap"]

#: The environment variables by which glibc takes heap parameters at start-up.
HEAP_ENV = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")
#: glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit: the largest mmap threshold the dynamic scheme reaches.
MMAP_THRESHOLD_BYTES = 32 * 2**20
#: The trim threshold the dynamic scheme pairs with it (twice the mmap threshold).
TRIM_THRESHOLD_BYTES = 2 * MMAP_THRESHOLD_BYTES
#: glibc's defaults, for parameters the environment did not set.
_DEFAULT_MMAP_THRESHOLD = 128 * 1024
_DEFAULT_TRIM_THRESHOLD = 128 * 1024
_M_TRIM_THRESHOLD = -1  # <malloc.h>
_M_MMAP_THRESHOLD = -3

_lock = threading.Lock()
_depth = 0


def _libc():
    """The process's own C library (``CDLL(None)``: no search, no subprocess), if it is glibc."""
    try:
        libc = ctypes.CDLL(None)
    except OSError:  # pragma: no cover - no dynamic symbols to load
        return None
    if not (hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim")):
        return None  # not glibc (musl has neither)
    return libc


_LIBC = _libc()


def _env_bytes(name: str, default: int) -> int:
    try:
        return int(os.environ[name])
    except (KeyError, ValueError):
        return default


def tuned_by_environment() -> bool:
    """Whether this process's heap parameters came from its environment (dynamic threshold off)."""
    return _LIBC is not None and any(name in os.environ for name in HEAP_ENV)


@contextmanager
def task_heap() -> Iterator[bool]:
    """Run the block with glibc's default large-allocation behaviour (module docstring); yields
    whether anything was changed."""
    global _depth
    if not tuned_by_environment():
        yield False
        return
    with _lock:
        _depth += 1
        if _depth == 1:
            _LIBC.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
            _LIBC.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    try:
        yield True
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _LIBC.mallopt(_M_MMAP_THRESHOLD, _env_bytes("MALLOC_MMAP_THRESHOLD_", _DEFAULT_MMAP_THRESHOLD))
                _LIBC.mallopt(_M_TRIM_THRESHOLD, _env_bytes("MALLOC_TRIM_THRESHOLD_", _DEFAULT_TRIM_THRESHOLD))
                _LIBC.malloc_trim(0)
