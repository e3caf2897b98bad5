"""Choosing N sensors among the candidates (docs/design.md, "The search").

Minimises the key of :class:`design.criterion.Problem` (uncovered positions, then the mean or
90th-percentile bound) over the sets of N candidates that obey the constraints:

* ``allowed``: candidates outside every keep-out region and, with belts, on one of them;
* belts' quotas: at most ``quota[b]`` sensors on belt b (``belt_of[c]`` its belt, -1: none);
* ``min_spacing_m``: no two chosen sensors closer than this.

Algorithm (deterministic for a given ``seed``):

1. **Exact** when the allowed candidates give at most ``exact_limit`` sets of N: every set is
   enumerated (feasible ones scored), the best kept (the first in enumeration order on ties).
2. Otherwise **greedy with swaps**: greedy forward selection (each step adds the feasible candidate
   whose addition gives the lowest key, the smallest index on ties; every candidate is scored at
   once, the information updated by Sherman-Morrison), then best-improvement 1-swaps (replace one
   chosen sensor by one feasible candidate) until no swap lowers the key or ``max_passes`` passes;
   then ``restarts`` more local searches from random feasible sets (seeded), the best of all kept.

Greedy with swaps is a local search: it finds a set no single swap improves, not necessarily the
global optimum; ``tests/design/test_optimize.py`` compares it with exhaustive enumeration written in
the test on small random cases.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from design.criterion import Problem

#: Relative improvement below which a swap does not count (round-off).
_RELATIVE_TOL = 1e-12


@dataclass(frozen=True)
class Constraints:
    allowed: np.ndarray  # (C,) bool
    positions_m: np.ndarray  # (C, 3), for the spacing
    min_spacing_m: float = 0.0
    belt_of: np.ndarray | None = None  # (C,) int, -1 for none
    quota: tuple[int, ...] | None = None  # per belt; None: no quotas


@dataclass
class SearchResult:
    subset: list[int]
    key: tuple[int, float]
    method: str  # "exact" or "greedy+swaps"
    evaluations: int = 0
    swaps: int = 0
    starts: int = 0
    history: list = field(default_factory=list)


def _better(a: tuple[int, float], b: tuple[int, float]) -> bool:
    """Whether key ``a`` is lower than ``b`` (lexicographic, the bound by more than round-off)."""
    if a[0] != b[0]:
        return a[0] < b[0]
    return a[1] < b[1] * (1.0 - _RELATIVE_TOL)


def _feasible(cons: Constraints, base: list[int]) -> np.ndarray:
    """Mask of the candidates that may join ``base``."""
    ok = cons.allowed.copy()
    ok[np.asarray(base, np.int64)] = False
    if base and cons.min_spacing_m > 0:
        d = np.linalg.norm(cons.positions_m[:, None, :] - cons.positions_m[None, base, :], axis=2)
        ok &= d.min(axis=1) >= cons.min_spacing_m
    if cons.quota is not None:
        used = np.bincount(cons.belt_of[base], minlength=len(cons.quota)) if base else np.zeros(len(cons.quota), int)
        full = np.flatnonzero(used >= np.asarray(cons.quota))
        ok &= ~np.isin(cons.belt_of, full)
    return ok


def _set_feasible(cons: Constraints, subset) -> bool:
    subset = list(subset)
    if not cons.allowed[subset].all():
        return False
    if cons.min_spacing_m > 0 and len(subset) > 1:
        p = cons.positions_m[subset]
        d = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(subset)) * 1e9
        if d.min() < cons.min_spacing_m:
            return False
    if cons.quota is not None:
        used = np.bincount(cons.belt_of[subset], minlength=len(cons.quota))
        if np.any(used > np.asarray(cons.quota)):
            return False
    return True


def _pick(u: np.ndarray, v: np.ndarray, idx: np.ndarray) -> int:
    """Position in ``idx`` of the lowest (u, v), the smallest candidate index on ties."""
    order = np.lexsort((idx, v, u))
    return int(order[0])


def greedy(problem: Problem, cons: Constraints, n: int, start: list[int] | None = None) -> list[int] | None:
    """Forward selection up to ``n`` sensors from ``start`` (None when the constraints stop it)."""
    chosen = list(start or [])
    while len(chosen) < n:
        ok = np.flatnonzero(_feasible(cons, chosen))
        if len(ok) == 0:
            return None
        u, v = problem.scores(chosen, ok)
        chosen.append(int(ok[_pick(u, v, ok)]))
    return chosen


def local_search(problem: Problem, cons: Constraints, subset: list[int], max_passes: int,
                 check: Callable[[], None] | None = None) -> tuple[list[int], tuple[int, float], int, int]:
    """Best-improvement 1-swaps from ``subset`` (module docstring): (set, key, evaluations, swaps)."""
    current = list(subset)
    key = problem.key(current)
    evaluations, swaps = 1, 0
    for _ in range(max_passes):
        if check is not None:
            check()
        best = None
        for k in range(len(current)):
            base = current[:k] + current[k + 1:]
            ok = _feasible(cons, base)
            ok[current[k]] = False
            idx = np.flatnonzero(ok)
            if len(idx) == 0:
                continue
            u, v = problem.scores(base, idx)
            evaluations += len(idx)
            j = _pick(u, v, idx)
            cand = (int(u[j]), float(v[j]))
            if _better(cand, key) and (best is None or _better(cand, best[0])):
                best = (cand, k, int(idx[j]))
        if best is None:
            break
        key, k, c = best
        current[k] = c
        swaps += 1
    return current, problem.key(current), evaluations, swaps


def _random_start(problem: Problem, cons: Constraints, n: int, rng: np.random.Generator) -> list[int] | None:
    order = rng.permutation(np.flatnonzero(cons.allowed))
    chosen: list[int] = []
    for c in order:
        if len(chosen) == n:
            break
        if _feasible(cons, chosen)[c]:
            chosen.append(int(c))
    return chosen if len(chosen) == n else None


def exact(problem: Problem, cons: Constraints, n: int, check: Callable[[], None] | None = None) -> SearchResult:
    """Every feasible set of ``n`` allowed candidates scored; the best (first on ties)."""
    allowed = np.flatnonzero(cons.allowed)
    best, best_key, count = None, None, 0
    batch: list[tuple[int, ...]] = []

    def flush():
        nonlocal best, best_key, count
        if not batch:
            return
        if check is not None:
            check()
        for s in batch:
            key = problem.key(list(s))
            count += 1
            if best_key is None or _better(key, best_key):
                best, best_key = list(s), key
        batch.clear()

    for combo in combinations(allowed.tolist(), n):
        if _set_feasible(cons, combo):
            batch.append(combo)
            if len(batch) >= 256:
                flush()
    flush()
    if best is None:
        return SearchResult([], (problem.positions, math.inf), "exact", count)
    return SearchResult(best, best_key, "exact", count, starts=1)


def search(problem: Problem, cons: Constraints, n: int, *, restarts: int = 4, seed: int = 0,
           exact_limit: int = 20_000, max_passes: int = 50,
           check: Callable[[], None] | None = None) -> SearchResult:
    """The best set of ``n`` candidates found (module docstring); an empty ``subset`` when no
    feasible set exists."""
    allowed = int(cons.allowed.sum())
    if math.comb(allowed, n) <= exact_limit:
        return exact(problem, cons, n, check)
    result = SearchResult([], (problem.positions, math.inf), "greedy+swaps")
    starts = []
    first = greedy(problem, cons, n)
    if first is not None:
        starts.append(first)
    rng = np.random.default_rng(seed)
    for _ in range(restarts):
        s = _random_start(problem, cons, n, rng)
        if s is not None:
            starts.append(s)
    for s in starts:
        subset, key, evals, swaps = local_search(problem, cons, s, max_passes, check)
        result.evaluations += evals
        result.swaps += swaps
        result.starts += 1
        result.history.append({"start": s, "subset": subset, "uncovered": key[0], "value": key[1]})
        if not result.subset or _better(key, result.key):
            result.subset, result.key = subset, key
    return result
