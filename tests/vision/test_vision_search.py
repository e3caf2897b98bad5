"""Fibonacci and golden-section maximisation (thesis Section 3.2.3) against closed forms and scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from vision.errors import VisionInputError
from vision.search import fibonacci_numbers, fibonacci_search, golden_section_search, maximise


def _counted(f):
    calls = []

    def g(x):
        calls.append(x)
        return f(x)

    return g, calls


@pytest.mark.parametrize("peak", [-0.731, 0.0, 0.123456, 1.9])
def test_fibonacci_brackets_the_peak_in_kiefers_number_of_evaluations(peak) -> None:
    """Kiefer's search with N evaluations shrinks [lo, hi] to (hi - lo) / F_N (+ the last
    probe's 1e-3 offset), F_N the first Fibonacci number >= (hi - lo) / tol: for [-2, 2] and tol
    1e-3, F_N = 4181 (N = 18, F_0 = F_1 = 1), so exactly 18 evaluations; the peak of a parabola
    lies in the final bracket."""
    f, calls = _counted(lambda x: -((x - peak) ** 2))
    res = fibonacci_search(f, -2.0, 2.0, 1e-3)
    fib = fibonacci_numbers(4.0 / 1e-3)
    assert fib[-1] == 4181 and len(fib) - 1 == 18
    assert res.evaluations == len(calls) == 18
    assert res.hi - res.lo <= 4.0 / 4181 * 1.01
    assert res.lo <= peak <= res.hi
    assert abs(res.x - peak) <= 1e-3


def test_golden_section_stops_below_tolerance_in_the_predicted_evaluations() -> None:
    """The bracket shrinks by 1/phi per evaluation after the first two: 2 + ceil(ln(tol / L) /
    ln(1 / phi)) evaluations."""
    f, calls = _counted(lambda x: math.exp(-((x - 0.3) ** 2)))
    res = golden_section_search(f, -2.0, 2.0, 1e-3)
    inv_phi = (math.sqrt(5) - 1) / 2
    assert res.evaluations == len(calls) == 2 + math.ceil(math.log(1e-3 / 4.0) / math.log(inv_phi))
    assert res.hi - res.lo <= 1e-3 and abs(res.x - 0.3) <= 1e-3


def test_fibonacci_needs_no_more_evaluations_than_golden_section() -> None:
    f = lambda x: -abs(x - 0.4)  # noqa: E731 - unimodal, not smooth
    for tol in (1e-1, 1e-2, 1e-3, 1e-5):
        fib, gold = fibonacci_search(f, 0.0, 1.0, tol), golden_section_search(f, 0.0, 1.0, tol)
        assert fib.evaluations <= gold.evaluations
        assert abs(fib.x - 0.4) <= tol and abs(gold.x - 0.4) <= tol


@pytest.mark.parametrize("method", ["fibonacci", "golden"])
def test_agrees_with_scipys_bounded_brent(method) -> None:
    """An asymmetric unimodal function, x exp(-x) on [0, 5] (maximum at 1): both searches land
    within their tolerance of scipy's bounded Brent minimiser (xatol 1e-8)."""
    f = lambda x: x * math.exp(-x)  # noqa: E731
    ref = minimize_scalar(lambda x: -f(x), bounds=(0.0, 5.0), method="bounded", options={"xatol": 1e-8}).x
    res = maximise(f, 0.0, 5.0, 1e-4, method)
    assert abs(res.x - ref) <= 1e-4
    assert abs(ref - 1.0) < 1e-6


def test_search_inputs_are_checked() -> None:
    with pytest.raises(VisionInputError) as e:
        fibonacci_search(lambda x: x, 1.0, 1.0, 0.1)
    assert e.value.field == "bracket"
    with pytest.raises(VisionInputError) as e:
        golden_section_search(lambda x: x, 0.0, 1.0, -1.0)
    assert e.value.field == "tolerance"
    with pytest.raises(VisionInputError) as e:
        maximise(lambda x: x, 0.0, 1.0, 0.1, "binary")
    assert e.value.field == "search"
    assert np.isfinite(fibonacci_search(lambda x: -x * x, -1.0, 1.0, 5.0).x)  # already within tolerance
