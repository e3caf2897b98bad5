"""Exact paths from interaction signatures: physical re-tracing and Newton refinement.

A *signature* is the ordered list of events of a path, each encoded as one
integer ``code = (organ * 2 + leaving) * 2 + reflect``: which organ's
surface, from which side (``leaving = 1``: from inside the organ to its
parent), and whether the wave is reflected (1) or refracted (0). Surfaces
between identical materials (homogeneous override) are transparent and are
not events.

:func:`follow` shoots rays from the transmitter along given launch
directions and makes them obey a signature *physically*: at each hit (first
hit in the scene of every non-transparent surface, so nothing can be
skipped) the surface must be the one
the signature names, and the new direction follows the law of reflection or
Snell's law (real parts of the indices, smooth normals). :func:`refine` then
drives the launch direction by Newton's method (Jacobian on two tangent
angles from ray differentials carried through every event, Igehy 1999) until
the last leg passes through the receiver; the stationary optical path (Fermat)
is automatically satisfied since every vertex obeys Snell / reflection. The
same Jacobian is the ray tube:
``|det J|`` is the tube cross-section at the receiver per unit launch solid
angle [m^2/sr], i.e. the geometric spreading (1 m^2/sr at 1 m in a homogeneous
medium, d^2 at distance d). Both run in compiled kernels (:mod:`raytrace.engine.kernels`),
one ray or seed at a time to its end; Newton's iterations run in the kernel too
(:func:`raytrace.engine.kernels.newton`), so Python only splits the seeds into chunks.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from raytrace.engine import kernels
from raytrace.engine.kernels import KIND_PASS, KIND_REFLECTION, KIND_REFRACTION  # noqa: F401 (re-exported)
from raytrace.engine.records import (
    Differentials,
    LineSearch,
    NewtonSeeds,
    NewtonSettings,
    StepRecords,
    TraceState,
    build,
    step_records,
)
from raytrace.engine.scene import TracerScene
from raytrace.solver.budget import Budget
from raytrace.solver.config import TracerConfig
from raytrace.solver.media import MediaTable


@functools.lru_cache(maxsize=16)
def _newton_settings(config: TracerConfig) -> NewtonSettings:
    """Newton's settings from ``config``; the line search's step fractions 1, 1/2, 1/4, ..."""
    return build(NewtonSettings, fractions=0.5 ** np.arange(config.line_search_halvings),
                 max_iterations=config.max_iterations, tolerance_m=config.miss_tolerance_m,
                 max_step_rad=config.max_step_rad, stall_window=config.stall_window,
                 stall_factor=config.stall_factor, growth=config.line_search_growth)


def encode(organ: np.ndarray, leaving: np.ndarray, reflect: np.ndarray) -> np.ndarray:
    return (np.asarray(organ, np.int64) * 2 + np.asarray(leaving, np.int64)) * 2 + np.asarray(reflect, np.int64)


#: Per-step records of a :func:`follow` in record mode, arrays over steps and paths (S, P, ...):
#: ``valid[s]`` is step s of every path (:class:`raytrace.engine.records.StepRecords`).
Steps = StepRecords


@dataclass
class FollowResult:
    ok: np.ndarray  # (P,) the signature was obeyed (and, in record mode, the last leg is clear)
    last_point: np.ndarray  # (P, 3) last event point (or the transmitter)
    last_dir: np.ndarray  # (P, 3) direction of the last leg
    last_med: np.ndarray  # (P,)
    segments: int  # ray casts done
    steps: Steps | None = None
    d_point: np.ndarray | None = None  # (P, 2, 3) derivatives of last_point by the two launch angles
    d_dir: np.ndarray | None = None  # (P, 2, 3) derivatives of last_dir by the two launch angles
    won: np.ndarray | None = None  # (P,) line search: index of the accepted fraction, -1 for none
    launch_dir: np.ndarray | None = None  # (P, 3) line search: the accepted (else last) trial launch


def follow(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    dirs: np.ndarray,
    codes: np.ndarray,
    nint: np.ndarray,
    *,
    targets_m: np.ndarray | None = None,
    tangents: tuple[np.ndarray, np.ndarray] | None = None,
    line_search: tuple | None = None,
) -> FollowResult:
    """Trace each ray through its signature (vectorised over rays).

    Without ``targets_m`` the trace stops after the last event (for Newton).
    With ``targets_m`` (record mode) it continues along the straight line to
    each target, through transparent surfaces, and fails (``ok = False``) if
    a real surface blocks the last leg; every step is recorded.
    ``tangents`` (two (P, 3) unit vectors normal to each launch direction, without
    ``targets_m``): also the derivatives of the last point and direction with respect to
    tilting the launch along them (ray differentials, :func:`raytrace.engine.kernels.follow`).
    ``line_search = (fractions, step, rx_m, old_miss_m, first)``: ``dirs`` are Newton's base
    directions, and each ray tries the steps ``fractions[first:] * step`` in turn until one
    brings its last leg closer to its receiver than ``old_miss_m`` (differentials included;
    see the kernel's line-search mode). These two modes run the per-ray steps of
    :func:`refine`'s kernel (:func:`raytrace.engine.kernels.newton`) on their own, so that each can be
    checked against closed forms (tests/raytrace/test_kernels.py).
    """
    p = len(dirs)
    record = targets_m is not None
    nint = np.ascontiguousarray(nint, dtype=np.int64)
    max_steps = _max_steps(media, nint)

    def state() -> TraceState:
        return build(TraceState, o=np.broadcast_to(np.asarray(tx_m, float), (p, 3)).copy(),
                     d=np.array(dirs, dtype=float), med=np.full(p, tx_medium, dtype=np.int64), push=np.zeros((p, 3)),
                     k=np.zeros(p, dtype=np.int64), nint=nint, ok=np.ones(p, dtype=bool),
                     done=np.zeros(p, dtype=bool) if record else (nint == 0),
                     codes=np.ascontiguousarray(codes, dtype=np.int64),
                     targets=np.ascontiguousarray(targets_m, dtype=float) if record else np.zeros((0, 3)),
                     record=record)

    tables, media_tables = scene.kernel_tables, media.kernel_tables
    out = _NO_STEPS
    counted = 0
    if record:
        # a counting pass first, so the step records are allocated for the steps taken (about a
        # dozen), not for the cap (~70: 160 MB at 20k paths)
        counted, used = kernels.follow(tables, media_tables, state(), out, max_steps, _NO_DIFFERENTIALS,
                                       _NO_LINE_SEARCH)
        out = step_records(used, p)
    run = state()
    differentials = _NO_DIFFERENTIALS
    if tangents is not None and not record:
        differentials = build(Differentials, launch=np.ascontiguousarray(np.stack(tangents, axis=1), dtype=float),
                              point=np.zeros((p, 2, 3)), direction=np.zeros((p, 2, 3)))
    search = _NO_LINE_SEARCH
    if line_search is not None and not record:
        fractions, step, rx_m, old_miss, first = line_search
        search = build(LineSearch, fractions=np.ascontiguousarray(fractions, dtype=float), base_dir=run.d.copy(),
                       step=np.ascontiguousarray(step, dtype=float), rx=np.ascontiguousarray(rx_m, dtype=float),
                       old_miss=np.ascontiguousarray(old_miss, dtype=float), won=np.array(first, dtype=np.int64),
                       trial_dir=np.zeros((p, 3)), dims={"P": p})
        differentials = build(Differentials, launch=np.zeros((p, 2, 3)), point=np.zeros((p, 2, 3)),
                              direction=np.zeros((p, 2, 3)))
    with_differentials = len(differentials.point) > 0
    segments, used = kernels.follow(tables, media_tables, run, out, max_steps, differentials, search)
    segments += counted
    steps = None
    if record:
        steps = Steps(*(rows[:used] for rows in out))
    ok = run.ok & run.done
    d_last = np.where(ok[:, None], run.d, np.nan) if record else run.d
    searched = len(search.fractions) > 0
    return FollowResult(ok=ok, last_point=run.o, last_dir=d_last, last_med=run.med, segments=segments, steps=steps,
                        d_point=differentials.point if with_differentials else None,
                        d_dir=differentials.direction if with_differentials else None,
                        won=search.won if searched else None, launch_dir=search.trial_dir if searched else None)


def _max_steps(media: MediaTable, nint: np.ndarray) -> int:
    """The step cap per ray of :func:`raytrace.engine.kernels.follow` and
    :func:`raytrace.engine.kernels.newton`: the events, the passes through transparent surfaces,
    and a margin."""
    return 4 * (int(nint.max(initial=0)) + 2) + 2 * len(media.materials) + 8


_NO_STEPS = step_records(0, 0)
_NO_DIFFERENTIALS = build(Differentials, launch=np.zeros((0, 2, 3)), point=np.zeros((0, 2, 3)),
                          direction=np.zeros((0, 2, 3)))
_NO_LINE_SEARCH = build(LineSearch, fractions=np.zeros(0), base_dir=np.zeros((0, 3)), step=np.zeros((0, 2)),
                        rx=np.zeros((0, 3)), old_miss=np.zeros(0), won=np.zeros(0, np.int64),
                        trial_dir=np.zeros((0, 3)))


def tangent_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to each unit direction and to each other (right-handed)."""
    ref = np.where(np.abs(d[:, 0:1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    u = np.cross(d, ref)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    return u, v


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass
class Refined:
    dirs: np.ndarray  # (P, 3) launch directions
    converged: np.ndarray  # (P,) bool
    tube_m2_per_sr: np.ndarray  # (P,) |det J|: ray-tube cross-section at the receiver per launch solid angle
    segments: int


def refine_by_continuation(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    codes: np.ndarray,
    nint: np.ndarray,
    *,
    budget: Budget | None = None,
    config: TracerConfig | None = None,
) -> Refined:
    """Refraction-only paths by homotopy on the refractive indices.

    With every index set to 1 the straight transmitter->receiver line is the
    exact path; the indices are raised as ``n_i^s`` for s from 0 to 1 in
    ``config.continuation_stages`` steps, each stage's Newton starting from the previous stage's
    solution. This finds direct paths whose straight launch direction would
    be totally reflected (a capsule deep in muscle, a sensor in air).
    """
    import dataclasses

    config = config or TracerConfig()
    stages = config.continuation_stages
    dirs = (rx_m - tx_m) / np.linalg.norm(rx_m - tx_m, axis=1, keepdims=True)
    alive = np.ones(len(dirs), bool)
    segments = 0
    out = None
    log_n = np.log(media.n_real)
    for s in np.linspace(0.0, 1.0, stages + 1)[1:]:
        idx = np.flatnonzero(alive)
        if len(idx) == 0:
            break
        staged = dataclasses.replace(media, n=np.exp(s * log_n)[None, :] + 0j)
        res = refine(scene, staged, tx_m, tx_medium, rx_m[idx], dirs[idx], codes[idx], nint[idx], budget=budget,
                     config=config)
        segments += res.segments
        dirs[idx[res.converged]] = res.dirs[res.converged]
        alive[idx[~res.converged]] = False
        out = res
    tube = np.full(len(dirs), np.nan)
    if out is not None:
        tube[np.flatnonzero(alive)] = out.tube_m2_per_sr[out.converged]
    return Refined(dirs=dirs, converged=alive, tube_m2_per_sr=tube, segments=segments)


def refine(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    dirs0: np.ndarray,
    codes: np.ndarray,
    nint: np.ndarray,
    *,
    budget: Budget | None = None,
    config: TracerConfig | None = None,
) -> Refined:
    """Newton on the two launch angles until each path's last leg hits its receiver.

    Residual: the offset, in the plane through the receiver normal to the
    last leg, of where the last leg crosses that plane. Jacobian: the same
    offset's derivatives with respect to tilting the launch along two
    orthonormal tangents, from the ray differentials the trace carries
    (as :func:`follow` with ``tangents``), so the Jacobian determinant is the
    ray-tube area per steradian. Steps are limited to ``config.max_step_rad`` and
    backtracked (halved, ``line_search_growth``) until the miss decreases; seeds that
    stall (``stall_window``, ``stall_factor``) are given up
    (:class:`~raytrace.solver.config.TracerConfig`). Each seed is iterated to its end in
    :func:`raytrace.engine.kernels.newton`, ``newton_chunk`` seeds per call (the budget is
    charged between calls).
    """
    config = config or TracerConfig()
    p = len(dirs0)
    dirs = _normalize(np.asarray(dirs0, float).copy())
    converged = np.zeros(p, bool)
    tube = np.full(p, np.nan)
    segments = 0
    if p == 0:
        return Refined(dirs=dirs, converged=converged, tube_m2_per_sr=tube, segments=0)
    codes = np.ascontiguousarray(codes, dtype=np.int64)
    nint = np.ascontiguousarray(nint, dtype=np.int64)
    rx_m = np.ascontiguousarray(rx_m, dtype=float)
    max_steps = _max_steps(media, nint)
    settings = _newton_settings(config)
    tables, media_tables = scene.kernel_tables, media.kernel_tables
    tx = np.ascontiguousarray(tx_m, dtype=float)
    for a in range(0, p, config.newton_chunk):  # the budget is charged (and checked) between chunks
        part = slice(a, a + config.newton_chunk)
        seeds = build(NewtonSeeds, tx=tx, tx_medium=int(tx_medium), dirs=dirs[part], codes=codes[part],
                      nint=nint[part], rx=rx_m[part], converged=converged[part], tube=tube[part])
        cast = kernels.newton(tables, media_tables, seeds, _NO_STEPS, max_steps, settings)
        segments += cast
        if budget is not None:
            budget.charge(cast)
    return Refined(dirs=dirs, converged=converged, tube_m2_per_sr=tube, segments=segments)
