"""How the tracer searches: one frozen :class:`TracerConfig` of its tuning constants.

These settings trade time and memory against the completeness of the path search; none is a
physical constant (those live in :mod:`raytrace.physics`) and the defaults are the values the
golden channels and the oracles of docs/tracer.md were recorded with. Pass one to
:func:`raytrace.trace_channel` (``config=``); the service builds one from its settings
(``CAPSULE_RT_TRACER_*``). A config is small, frozen and pickles (a sweep ships it to its
workers with the specs).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field, fields


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one, else every
    CPU): the default thread count."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):  # macOS and Windows have no sched_getaffinity
        return max(os.cpu_count() or 1, 1)


#: Smallest allowed value of the int settings that may be below 1.
_LEAST_INT = {"zoom_grid": 2, "zoom_levels": 0, "line_search_growth": 0}
#: Float settings that may be 0 (no curvature widening).
_MAY_BE_ZERO = {"curvature_margin"}


@functools.cache
def _kinds() -> tuple[tuple[str, bool], ...]:
    """Each field of :class:`TracerConfig` and whether it is an int (else a float)."""
    return tuple((f.name, f.type == "int") for f in fields(TracerConfig))


@dataclass(frozen=True)
class TracerConfig:
    """The tracer's tuning constants (module doc). Raises ValueError naming the field when a
    value is out of its range."""

    #: Worker threads of one trace: the direct-path search and the shooting's launch batches,
    #: then the Newton refinement of the shot seeds, and the global refraction-only walk's
    #: batches (Embree and the kernels run without the GIL). Default: the CPUs this process may
    #: use. Peak memory grows with it (each launch batch in flight holds its bounce tree).
    threads: int = field(default_factory=available_cpus)

    # --- shooting and bouncing (raytrace.solver.sbr)
    #: Launch directions traced together (their whole bounce tree at once). Batches are handed to
    #: the threads as they free up, so small ones balance the cores and keep each generation's
    #: arrays in cache: on the default torso (1e5 rays, 2 threads) the shooting took 0.225-0.239 s
    #: wall (0.44-0.47 CPU-s) with 12 500, 0.253-0.263 s (0.48-0.50) with 50 000, and 0.237-0.251 s
    #: with 6 250 (more per-generation overhead); the paths are the same.
    launch_batch: int = 12_500
    #: Safety cap on the live rays of one launch batch (highest priority kept; the walk's rays, at
    #: most one per launch, always: so it must stay above launch_batch).
    max_live_rays: int = 2_000_000
    #: Rays per Embree batch inside one bounce (bounds the temporaries' memory).
    chunk_rays: int = 1 << 18
    #: Reception radius in units of the local ray-tube half-width.
    reception_factor: float = 1.0
    #: Safety factor on the curvature widening of the tubes (raytrace.solver.sbr). Measured on the
    #: default torso (3 capsules x 12 sensors, 1e5 rays; reference: the union of 1e6-ray traces):
    #: paths within 20 dB of a receiver's strongest that were missed, of 267: 84 without the term,
    #: 42 with margin 1, 25 with margin 2; receivers missing their strongest path: 6, 1, 0 of 36.
    #: Request time grows with the candidates (about +50 % at margin 2).
    curvature_margin: float = 2.0

    # --- seeds of the shooting (raytrace.solver.tracer)
    #: The candidates of one (receiver, signature) group are clustered by launch direction: two
    #: candidates closer than this many launch spacings are one cluster (single linkage), and
    #: each cluster is one distinct path to refine (docs/tracer.md, "Seeds"). The faces of one
    #: organ share a signature (a box room's six walls, a concave organ's two specular points), so
    #: a group may hold any number of distinct paths; candidates of one path lie within about one
    #: spacing of each other. It must be at least seed_separation (then the clusters' seeds are
    #: a superset of a per-group greedy pick).
    cluster_link: float = 3.0
    #: Candidate seeds refined per cluster, at most (the closest first, seed_separation apart):
    #: retries for one distinct path whose closest candidate's Newton fails, not a cap on paths.
    #: The number of clusters is not capped: the refinement charges the request's work Budget.
    seeds_per_cluster: int = 6
    #: Seeds of one cluster must be this many launch spacings apart. With the curvature-widened
    #: reception tubes a cluster holds many neighbouring candidates that converge to one path: 6
    #: seeds 3 spacings apart found the same strong paths as 16 seeds 1 spacing apart on the
    #: default torso (within 20 dB of the strongest, 24 of 267 missed against 1e6 rays by both) in
    #: about 25 % less time; 4 seeds lost one of two symmetric walls' paths (tests).
    seed_separation: float = 3.0
    #: Two converged seeds with the same receiver and signature whose launch directions are closer
    #: than this are one path [rad] (a path is its signature's trace from its launch).
    duplicate_angle_rad: float = 1e-6

    # --- direct (refraction-only) paths (raytrace.solver.direct)
    #: Refraction events a refraction-only walk follows at most.
    walk_max_events: int = 24
    #: Seeds kept per receiver (closest approaches, launch directions two spacings apart).
    seeds_per_receiver: int = 12
    #: Rays walked together by the stand-alone walk.
    walk_batch: int = 50_000
    #: Zoom grid: zoom_grid x zoom_grid launch directions per seed and level.
    zoom_grid: int = 11
    #: Zoom levels (the grid half-width halves per level).
    zoom_levels: int = 24
    #: The zoom stops once the miss is below this [m] (Newton then takes over).
    zoom_miss_m: float = 1e-7
    #: A zoomed seed whose miss is not below zoom_stall_factor times its miss zoom_stall_window
    #: levels earlier (less than 1 % progress over 6 levels) stops zooming: it sits in a geometric-
    #: optics shadow. Measured on the torso's tract (35 positions x 12 sensors, 2e4 rays, and the six
    #: capsule sites at 1e5): 21 seeds reached the miss, none ever improved less than 19 % over 4
    #: levels; the 651 that did not stall at level 12 (median) of 24 under this rule.
    zoom_stall_window: int = 6
    zoom_stall_factor: float = 0.99
    #: Stages of the homotopy on the refractive indices (n_i^s, s from 0 to 1) for direct paths
    #: whose straight launch is totally reflected.
    continuation_stages: int = 8

    # --- Newton refinement (raytrace.solver.refine)
    #: Newton stops when the last leg misses the receiver by less than this [m].
    miss_tolerance_m: float = 1e-9
    #: Largest Newton step on the launch angles [rad].
    max_step_rad: float = 0.25
    #: Newton iterations per seed, at most.
    max_iterations: int = 40
    #: A seed whose miss is not below stall_factor times its miss stall_window iterations earlier
    #: (less than 0.3 % progress per iteration) is given up. Newton in its basin shrinks the miss
    #: quadratically; flat seeds otherwise keep iterating up to max_iterations. Slow but steady
    #: seeds do converge late (one at iteration 35 after 24 iterations of ~1 % progress), so the
    #: rule only drops flat ones. Measured on the default torso, 6 capsules x (the 12 sensor sites
    #: + the 12 uniform-belt positions of tests/raytrace/test_tracer_torso.py), 2200 paths: none lost;
    #: window 10 with factor 0.9 lost one (-37.5 dB under its receiver's strongest), window 6 / 0.9
    #: two, a cap of 12 iterations eleven (one 0.7 dB under the strongest).
    stall_window: int = 10
    stall_factor: float = 0.97
    #: Step fractions of the backtracking line search: 1, 1/2, ... 1/2^(halvings - 1), tried in
    #: this order per seed, stopping at the first that reduces the miss (batches of fractions
    #: traced together cast 0.62e6 segments on 2225 torso seeds where this casts 0.2e6, same result).
    line_search_halvings: int = 10
    #: A seed's line search starts this many halvings above its last accepted fraction (a step may
    #: double per iteration), not at the full step: a seed pushed against the edge of its
    #: signature's launch region accepts ever smaller fractions (1, 1/2, 1/8, 1/32, ... then none),
    #: and retrying the large ones first cost 4 of every 5 Newton rays on the default torso, almost
    #: all on seeds that fail. Seeds in their basin accept the full step and are unaffected.
    line_search_growth: int = 1
    #: Seeds per call of the Newton kernel: the work budget is charged between calls.
    newton_chunk: int = 128

    def __post_init__(self) -> None:
        for name, is_int in _kinds():
            value = getattr(self, name)
            if is_int:
                least = _LEAST_INT.get(name, 1)
                if isinstance(value, bool) or not isinstance(value, int) or value < least:
                    raise ValueError(f"TracerConfig.{name}: expected an int >= {least}, got {value!r}")
            elif (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
                  or value < 0 or (value == 0 and name not in _MAY_BE_ZERO)):
                bound = ">= 0" if name in _MAY_BE_ZERO else "> 0"
                raise ValueError(f"TracerConfig.{name}: expected a finite number {bound}, got {value!r}")
        if self.max_live_rays <= self.launch_batch:
            raise ValueError(f"TracerConfig.max_live_rays: must exceed launch_batch ({self.launch_batch}): the walk "
                             f"keeps one ray per launch, got {self.max_live_rays}")
        if self.cluster_link < self.seed_separation:
            raise ValueError(f"TracerConfig.cluster_link: must be at least seed_separation ({self.seed_separation}), "
                             f"got {self.cluster_link}")
        if self.stall_factor > 1.0:
            raise ValueError(f"TracerConfig.stall_factor: must be at most 1, got {self.stall_factor}")
        if self.zoom_stall_factor > 1.0:
            raise ValueError(f"TracerConfig.zoom_stall_factor: must be at most 1, got {self.zoom_stall_factor}")
