"""How the engine's kernels are compiled: the one module that touches numba's internals.

Two decorators, :func:`kernel` and :func:`helper`, compile every function of
:mod:`raytrace.engine.kernels` and :mod:`raytrace.engine.embree`: in nopython mode, without the
GIL (``nogil``), with numpy's float semantics (``error_model="numpy"``: a division by zero
gives inf / nan, as in the numpy reference, never an exception), cached on disk.
:func:`helper` also turns numba's reference counting off (``_nrt=False``, a private option,
as numba's own hot helpers in ``numba/cpython/unicode.py`` use it): a per-ray helper only
borrows the arrays its caller holds and allocates none; with the runtime on, each call did an
atomic incref and decref of every array argument on entry and exit, which the optimiser
cannot remove across a call that is not inlined: ~40 % of Newton's time.

The on-disk cache is keyed on the engine's sources (:data:`ENGINE_SOURCES_SHA256`, a hash of
every ``.py`` file of this package), not on the kernel file alone as numba keys it: a kernel
carries its own copy of every compiled callee it calls (``embree.intersect`` in
``kernels.follow``), so a change to any engine module must recompile every kernel. numba
alone would load the stale machine code of ``kernels.py`` after an edit of ``embree.py``.

Both uses of numba internals (``_nrt``, the cache's source stamp) live here, and
``pyproject.toml`` pins numba to the minor release they were tested with
(tests/raytrace/test_engine_guards.py checks both still work).

``NUMBA_DISABLE_JIT=1``: the decorators return the Python functions unchanged, and
:mod:`raytrace.engine.embree` calls Embree through ctypes instead of the compiled call; the
kernels then run as (slow) Python, for debugging with pdb or coverage (docs/tracer.md,
"The kernel boundary").
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from numba import njit
from numba.core import caching
from numba.core import config as _numba_config

#: True when numba's JIT is off (``NUMBA_DISABLE_JIT=1``): kernels run as Python.
JIT_DISABLED: bool = bool(_numba_config.DISABLE_JIT)

_ENGINE_DIR = Path(__file__).resolve().parent


def engine_sources_sha256(directory: Path = _ENGINE_DIR) -> str:
    """SHA-256 over the names and contents of every ``.py`` file of the engine package, in
    name order: the key of the kernels' on-disk cache."""
    digest = hashlib.sha256()
    for path in sorted(Path(directory).glob("*.py")):
        digest.update(path.name.encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()


#: The engine's source hash at import (module doc).
ENGINE_SOURCES_SHA256: str = engine_sources_sha256()


class _EngineCache(caching.FunctionCache):
    """numba's cache of one function, located where numba would put it (beside the source,
    in ``NUMBA_CACHE_DIR`` or in the user's cache directory), whose index is stamped with
    the engine's source hash instead of the one file's: an index written for other engine
    sources is discarded and the function recompiled."""

    def __init__(self, py_func):
        super().__init__(py_func)
        self._cache_file = caching.IndexDataCacheFile(
            cache_path=self._cache_path, filename_base=self._impl.filename_base,
            source_stamp=("raytrace.engine", ENGINE_SOURCES_SHA256))


def _compiled(options: dict):
    def decorate(fn):
        if JIT_DISABLED:
            return fn
        dispatcher = njit(nogil=True, error_model="numpy", **options)(fn)
        dispatcher._cache = _EngineCache(fn)  # what njit(cache=True) does, with the engine's stamp
        return dispatcher

    return decorate


#: A compiled kernel: called from Python or from another kernel; may allocate.
kernel = _compiled({})
#: A compiled per-ray helper called only from kernels: borrows its arrays, allocates none
#: (numba's reference counting off, module doc).
helper = _compiled({"_nrt": False})
