"""One-dimensional maximisation: the Fibonacci search (thesis Section 3.2.3) and golden section.

Both shrink a bracket [lo, hi] holding the maximum of a unimodal function, keeping one interior
point (and its value) per step so that each step costs ONE evaluation.

* Fibonacci (Kiefer 1953, "Sequential minimax search for a maximum"): with F_0 = F_1 = 1,
  F_k = F_{k-1} + F_{k-2}, choose the smallest N with F_N >= (hi - lo) / tol; the probes of the
  bracket of "Fibonacci length" F_m sit at F_{m-2} / F_m and F_{m-1} / F_m of it, the kept probe
  lands exactly on a probe position of the next bracket, and after N - 2 steps the bracket is
  (hi - lo) * 2 / F_N long (the two last probes coincide at its middle; one more probe
  ``eps`` beside it halves it: (hi - lo) / F_N). For a given number of evaluations it is the
  optimal (minimax) bracketing search.
* golden section: the limit of the same with the constant ratio 1 / phi = 0.618..., run until
  the bracket is shorter than ``tol``: ~ 1.4 % more evaluations for the same final bracket.

Erratum of the thesis: its listing (A.2) named "Fibonacci search" is a golden-section search
(ratio 0.618) with stopping width 0.01 where its text asks for 0.005; both are here, correctly.

A multimodal function (the mutual information far from its peak) needs a bracket around the
right maximum first: :mod:`vision.motion` finds it on a grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from .errors import VisionInputError

SEARCHES = ("fibonacci", "golden")
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class SearchResult:
    """Where the search ended: ``x`` (the best probe), ``value`` f(x), the final bracket
    [lo, hi], ``iterations`` (bracket reductions) and ``evaluations`` of f."""

    x: float
    value: float
    lo: float
    hi: float
    iterations: int
    evaluations: int


def fibonacci_numbers(limit: float) -> list[int]:
    """F_0 = F_1 = 1, ... up to the first F_N >= ``limit``."""
    fib = [1, 1]
    while fib[-1] < limit:
        fib.append(fib[-1] + fib[-2])
    return fib


def _check(lo: float, hi: float, tol: float) -> None:
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise VisionInputError(f"bracket must be finite with lo < hi, got [{lo}, {hi}]", "bracket")
    if not (math.isfinite(tol) and tol > 0.0):
        raise VisionInputError(f"must be a finite number > 0, got {tol!r}", "tolerance")


def fibonacci_search(f: Callable[[float], float], lo: float, hi: float, tol: float) -> SearchResult:
    """Maximise a unimodal ``f`` on [lo, hi] by Kiefer's Fibonacci search (module doc) to a final
    bracket no longer than ``tol``."""
    _check(lo, hi, tol)
    length = hi - lo
    fib = fibonacci_numbers(length / tol)
    m = len(fib) - 1  # the bracket has Fibonacci length F_m
    if m < 3:  # already within tolerance: probe the middle
        x = 0.5 * (lo + hi)
        return SearchResult(x, float(f(x)), lo, hi, 0, 1)
    a, b = lo, hi
    x1 = a + fib[m - 2] / fib[m] * (b - a)
    x2 = a + fib[m - 1] / fib[m] * (b - a)
    f1, f2 = float(f(x1)), float(f(x2))
    evaluations, iterations = 2, 0
    while m > 3:
        iterations += 1
        if f1 < f2:  # the maximum is right of x1
            a, x1, f1 = x1, x2, f2
            m -= 1
            x2 = a + fib[m - 1] / fib[m] * (b - a)
            f2 = float(f(x2))
        else:
            b, x2, f2 = x2, x1, f1
            m -= 1
            x1 = a + fib[m - 2] / fib[m] * (b - a)
            f1 = float(f(x1))
        evaluations += 1
    # F_3 = 3: probes at 1/3 and 2/3; one reduction leaves a bracket of length 2 (in units of
    # (hi - lo) / F_N) with the kept probe at its middle; the last probe goes just beside it.
    iterations += 1
    if f1 < f2:
        a, keep, fkeep = x1, x2, f2
    else:
        b, keep, fkeep = x2, x1, f1
    eps = 1e-3 * (b - a)
    probe = keep + eps
    fprobe = float(f(probe))
    evaluations += 1
    if fprobe > fkeep:
        a = keep
        return SearchResult(probe, fprobe, a, b, iterations, evaluations)
    b = probe
    return SearchResult(keep, fkeep, a, b, iterations, evaluations)


def golden_section_search(f: Callable[[float], float], lo: float, hi: float, tol: float) -> SearchResult:
    """Maximise a unimodal ``f`` on [lo, hi] by golden-section search until the bracket is
    shorter than ``tol`` (module doc)."""
    _check(lo, hi, tol)
    a, b = lo, hi
    x1, x2 = b - _INV_PHI * (b - a), a + _INV_PHI * (b - a)
    f1, f2 = float(f(x1)), float(f(x2))
    evaluations, iterations = 2, 0
    while b - a > tol:
        iterations += 1
        if f1 < f2:
            a, x1, f1 = x1, x2, f2
            x2 = a + _INV_PHI * (b - a)
            f2 = float(f(x2))
        else:
            b, x2, f2 = x2, x1, f1
            x1 = b - _INV_PHI * (b - a)
            f1 = float(f(x1))
        evaluations += 1
    if f1 >= f2:
        return SearchResult(x1, f1, a, b, iterations, evaluations)
    return SearchResult(x2, f2, a, b, iterations, evaluations)


def maximise(f: Callable[[float], float], lo: float, hi: float, tol: float, method: str = "fibonacci") -> SearchResult:
    """:func:`fibonacci_search` or :func:`golden_section_search` by name."""
    if method == "fibonacci":
        return fibonacci_search(f, lo, hi, tol)
    if method == "golden":
        return golden_section_search(f, lo, hi, tol)
    raise VisionInputError(f"must be one of {', '.join(SEARCHES)}, got {method!r}", "search")
