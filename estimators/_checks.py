"""Small validators shared by the estimators (all raise EstimatorInputError)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from .errors import EstimatorInputError

MAX_TRIALS = 10_000

Check = Callable[[], None] | None
"""The stop protocol of long estimator loops: a callable that takes no argument, called
between chunks of work (every few hundred milliseconds at most), that returns to go on
and raises (any exception, which propagates unchanged) to stop the computation -- e.g. a
deadline passed or the caller went away. ``None``: never stop."""


def checkpoint(check: Check) -> None:
    """Call ``check`` if one was given (see :data:`Check`)."""
    if check is not None:
        check()


def finite_float(value: Any, field: str, *, positive: bool = False, nonnegative: bool = False) -> float:
    """Return ``value`` as a finite float, or raise naming ``field``."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise EstimatorInputError(f"must be a number, got {value!r}", field) from None
    if not math.isfinite(out):
        raise EstimatorInputError(f"must be finite, got {out!r}", field)
    if positive and out <= 0.0:
        raise EstimatorInputError(f"must be > 0, got {out!r}", field)
    if nonnegative and out < 0.0:
        raise EstimatorInputError(f"must be >= 0, got {out!r}", field)
    return out


def trials_count(value: Any, field: str = "trials") -> int:
    """Monte Carlo trial count: an integer in [1, MAX_TRIALS]."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise EstimatorInputError(f"must be an integer, got {value!r}", field)
    if not 1 <= int(value) <= MAX_TRIALS:
        raise EstimatorInputError(f"must be between 1 and {MAX_TRIALS}, got {int(value)}", field)
    return int(value)


def relative_permittivity(value: Any, field: str = "relative_permittivity") -> float:
    """Velocity assumption eps_r: finite and >= 1 (no medium is faster than vacuum)."""
    eps = finite_float(value, field)
    if eps < 1.0:
        raise EstimatorInputError(f"must be >= 1 (v = c / sqrt(eps_r) cannot exceed c), got {eps!r}", field)
    return eps


SNR_RANGE_DB = (-50.0, 200.0)
"""What a request may ask for as ``snr_db``."""
LINK_SNR_FLOOR_DB = -300.0
"""Lowest SNR a link budget may produce (a sensor in deep shadow): the noise is then 1e30 times
the signal, still finite in float64; below, the estimate would be noise alone either way."""


def snr_db(value: Any, field: str = "snr_db", floor_db: float = SNR_RANGE_DB[0]) -> float | None:
    """SNR in dB, or None for noiseless; bounded to a physically meaningful range."""
    if value is None:
        return None
    snr = finite_float(value, field)
    if not floor_db <= snr <= SNR_RANGE_DB[1]:
        raise EstimatorInputError(f"must lie in [{floor_db:g}, {SNR_RANGE_DB[1]:g}] dB, got {snr!r}", field)
    return snr


def generator(seed: Any, field: str = "seed") -> np.random.Generator:
    """numpy Generator from an int seed (>= 0) or an existing Generator."""
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise EstimatorInputError(f"must be a non-negative integer or a numpy Generator, got {seed!r}", field)
    return np.random.default_rng(int(seed))
