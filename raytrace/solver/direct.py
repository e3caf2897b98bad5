"""Seeds for direct (refraction-only) paths that the straight line does not give.

The straight transmitter->receiver segment's crossings are the direct path's
signature only when refraction does not change which surfaces the path
crosses. Behind strongly refracting interfaces it does: the refracted path
misses an organ the line clips, or crosses one the line misses, and paths
near a critical angle (muscle -> fat 26 deg, muscle -> bone 28 deg,
muscle -> lung 41 deg) leave through a thin sliver of launch directions that
a launch lattice can step over and whose Newton basin is narrower than the
lattice spacing.

:func:`refraction_walk` follows rays refraction-only (Snell with ``Re n``,
smooth normals, a ray stops at total internal reflection or in air, no
splitting) and records, for every leg in a receiver's material, the closest
approach to the receiver and the signature so far. :func:`direct_seeds`
walks the whole Fibonacci launch once (one cast per ray and event) and keeps
per receiver the closest rays with distinct launch directions;
:func:`zoom_seeds` then shrinks a grid of launch directions around each seed
(derivative-free, so it cannot overshoot into total reflection the way a
Newton step does near a critical angle) until the miss is small enough for
:func:`raytrace.solver.refine.refine` to converge. Every path is still made exact by
Newton refinement; these are only seeds. The tracer's forward walk rides on the
shooting's rays (:mod:`raytrace.solver.sbr`); :func:`direct_seeds` itself serves the search from the
receiver's side (:func:`reverse_seeds`).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from raytrace.engine import kernels
from raytrace.engine.records import WalkOutput, WalkRays, WalkTargets, build
from raytrace.engine.scene import TracerScene
from raytrace.solver.budget import Budget
from raytrace.solver.config import TracerConfig
from raytrace.solver.launch import angular_spacing_rad, fibonacci_sphere
from raytrace.solver.media import MediaTable
from raytrace.solver.refine import tangent_basis


@dataclass
class Walk:
    miss_m: np.ndarray  # (P, R) closest approach of a leg in the receiver's material (inf: none)
    events: np.ndarray  # (P, E) every refraction of the walk, -1 padded (E: TracerConfig.walk_max_events)
    nint: np.ndarray  # (P, R) events before that closest leg
    segments: int

    def codes(self, rows: np.ndarray, col: int | np.ndarray) -> np.ndarray:
        """Signatures (-1 padded) of walked rays ``rows`` up to their closest leg to receiver
        column ``col``: the first ``nint[rows, col]`` events. Built only for the rows asked
        for (a (P, R, E) table of every ray would be tens of MB per batch)."""
        rows = np.asarray(rows, np.int64)
        out = np.array(self.events[rows])
        out[np.arange(self.events.shape[1])[None, :] >= self.nint[rows, col][:, None]] = -1
        return out


def refraction_walk(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    dirs: np.ndarray,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    ray_rx: np.ndarray | None = None,
    *,
    exact: bool = True,
    config: TracerConfig | None = None,
) -> Walk:
    """Walk rays refraction-only; closest approach to every receiver (``ray_rx`` None, R
    columns) or to each ray's own receiver ``ray_rx[i]`` (one column). Vectorised per event.
    ``exact=False``: Embree's float32 hit distances and barycentric normals (about 1e-8 m,
    enough for the global seed walk; the zoom uses the float64 re-intersection). Up to
    ``config.walk_max_events`` refractions."""
    max_events = (config or TracerConfig()).walk_max_events
    p = len(dirs)
    own = ray_rx is not None
    cols = 1 if own else len(rx_m)
    media_tables = media.kernel_tables
    rx_cls = media_tables.material_class[np.asarray(rx_medium, np.int64) + 1]
    targets = build(WalkTargets, position_m=np.ascontiguousarray(rx_m, dtype=float),
                    material_class=np.ascontiguousarray(rx_cls),
                    ray_rx=np.ascontiguousarray(ray_rx, np.int64) if own else np.zeros(0, np.int64))
    out = build(WalkOutput, miss=np.full((p, cols), np.inf), nmiss=np.zeros((p, cols), np.int64),
                codes=np.full((p, max_events), -1, np.int64))
    tables = scene.kernel_tables
    # state of the rays still alive only, compacted after every event (row ``r`` is walked ray
    # ``ids[r]``): no gathers and scatters of the whole launch per event
    o = np.broadcast_to(np.asarray(tx_m, float), (p, 3)).copy()
    d = np.array(dirs, float)
    rays = build(WalkRays, ids=np.arange(p), o=o, d=d, med=np.full(p, tx_medium, np.int64), nint=np.zeros(p, np.int64),
                 q=(o - scene.center).astype(np.float32), dq=d.astype(np.float32))
    segments = 0
    # the seed walk casts into the shooting's fast scene (raytrace.engine.scene: seeds only)
    embree = scene.embree if exact else scene.embree_shooting
    for _ in range(max_events + 1):
        if len(rays.ids) == 0:
            break
        hits = embree.intersect(rays.q, rays.dq)
        segments += len(rays.ids)
        rays = kernels.walk_step(rays, hits, targets, out, tables, media_tables, exact, max_events)
    miss, codes, nmiss = out.miss, out.codes, out.nmiss
    return Walk(miss_m=miss, events=codes, nint=nmiss, segments=segments)


@dataclass
class Seeds:
    receiver: np.ndarray  # (S,)
    launch_dir: np.ndarray  # (S, 3)
    miss_m: np.ndarray  # (S,)
    codes: np.ndarray  # (S, E) -1 padded
    nint: np.ndarray  # (S,)
    segments: int


def _charge(budget: Budget | None, n: int) -> None:
    if budget is not None:
        budget.charge(n)


def _closest(miss_m: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` smallest finite values of ``miss_m``, smallest first, ties in index
    order: the first ``k`` of a stable argsort of the finite values, without sorting them all
    (a partition finds the k-th value; only the values up to it are sorted)."""
    ok = np.flatnonzero(np.isfinite(miss_m))
    if len(ok) > k:
        kth = np.partition(miss_m[ok], k - 1)[k - 1]
        ok = ok[miss_m[ok] <= kth]  # every value tied with the k-th too: the stable order decides
    return ok[np.argsort(miss_m[ok], kind="stable")[:k]]


def direct_seeds(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    rays: int,
    receivers: np.ndarray,
    budget: Budget | None = None,
    config: TracerConfig | None = None,
) -> Seeds:
    """Per receiver in ``receivers``, the ``config.seeds_per_receiver`` launch directions (of a
    ``rays``-direction Fibonacci launch) whose refraction-only rays pass closest to it, walked
    in batches of ``config.walk_batch`` on ``config.threads`` threads.
    (:func:`raytrace.solver.sbr.shoot` does the same walk on the shooting's own rays.)"""
    config = config or TracerConfig()
    batch, threads = config.walk_batch, config.threads
    receivers = np.asarray(receivers, np.int64)
    launch = fibonacci_sphere(rays)
    segments = 0
    pools: list[list] = [[] for _ in receivers]

    def walk(first: int) -> Walk:
        w = refraction_walk(scene, media, tx_m, tx_medium, launch[first:first + batch], rx_m[receivers],
                            rx_medium[receivers], exact=False, config=config)
        _charge(budget, w.segments)
        return w

    firsts = list(range(0, rays, batch))
    # the walk's kernels and Embree run without the GIL: batches in threads, in waves (so only a
    # wave's walks are held at once), merged in batch order
    with ThreadPoolExecutor(max_workers=min(threads, len(firsts))) as workers:
        for wave in range(0, len(firsts), threads):
            part = firsts[wave:wave + threads]
            for first, w in zip(part, workers.map(walk, part)):
                segments += w.segments
                offers = closest_launches(w.miss_m, w.nint, w.codes, launch[first:first + batch],
                                          config.seeds_per_receiver)
                for pool, offer in zip(pools, offers):
                    pool.extend(offer)
    return pick_seeds(pools, receivers, rays, segments, config)


def closest_launches(miss_m: np.ndarray, nint: np.ndarray, codes_of, dirs: np.ndarray,
                     seeds_per_receiver: int) -> list[list[tuple]]:
    """Per receiver column of one batch of walked launches (``miss_m``, ``nint``: (B, R)),
    the ``8 * seeds_per_receiver`` closest as ``(miss, launch direction, signature, events)``,
    closest first; ``codes_of(rows, columns)`` gives the signatures (one call for all columns)."""
    tops = [_closest(miss_m[:, c], 8 * seeds_per_receiver) for c in range(miss_m.shape[1])]
    rows = np.concatenate(tops) if tops else np.zeros(0, np.int64)
    cols = np.repeat(np.arange(len(tops)), [len(t) for t in tops])
    codes, launch = codes_of(rows, cols), dirs[rows]
    miss, events = miss_m[rows, cols].tolist(), nint[rows, cols].tolist()
    ends = np.cumsum([len(t) for t in tops]).tolist()
    return [list(zip(miss[a:b], launch[a:b], codes[a:b], events[a:b])) for a, b in zip([0] + ends, ends)]


def pick_seeds(pools: list[list[tuple]], receivers: np.ndarray, rays: int, segments: int,
               config: TracerConfig) -> Seeds:
    """From each receiver's pool of closest launches (``receivers[j]``'s is ``pools[j]``, in
    launch-batch order), the ``config.seeds_per_receiver`` closest whose launch directions are
    two launch spacings apart."""
    min_cos = np.cos(2.0 * angular_spacing_rad(rays))
    out = []
    for r, pool in zip(np.asarray(receivers, np.int64), pools):  # a few dozen candidates per receiver
        kept: list[tuple] = []
        for cand in sorted(pool, key=lambda x: x[0]):
            if all(float(cand[1] @ k[1]) < min_cos for k in kept):
                kept.append(cand)
                if len(kept) == config.seeds_per_receiver:
                    break
        out.extend((int(r),) + k for k in kept)
    if not out:
        return _no_seeds(config, segments)
    return Seeds(
        receiver=np.array([x[0] for x in out], np.int64),
        launch_dir=np.array([x[2] for x in out]),
        miss_m=np.array([x[1] for x in out]),
        codes=np.array([x[3] for x in out], np.int64),
        nint=np.array([x[4] for x in out], np.int64),
        segments=segments,
    )


def _no_seeds(config: TracerConfig, segments: int) -> Seeds:
    return Seeds(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0),
                 np.zeros((0, config.walk_max_events), np.int64), np.zeros(0, np.int64), segments)


def zoom_seeds(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    seeds: Seeds,
    half_width_rad: float,
    budget: Budget | None = None,
    config: TracerConfig | None = None,
) -> Seeds:
    """Derivative-free zoom: a ``zoom_grid`` x ``zoom_grid`` patch of launch directions around
    each seed, the best (smallest refraction-only miss) becomes the centre, the half-width
    halves; until the miss is below ``zoom_miss_m``, or ``zoom_levels`` levels, or the seed
    stalls: its miss less than ``1 - zoom_stall_factor`` smaller than ``zoom_stall_window``
    levels earlier (all seeds at once; :class:`~raytrace.solver.config.TracerConfig`). A seed
    with a refraction-only path nearby closes in on it level after level (its miss shrinks
    with the patch), one in a geometric-optics shadow settles on the shadow's edge, mm away,
    and used to zoom all its levels there."""
    config = config or TracerConfig()
    s = len(seeds.receiver)
    if s == 0:
        return seeds
    d0 = np.array(seeds.launch_dir, float)
    best = np.array(seeds.miss_m, float)
    codes = np.array(seeds.codes)
    nint = np.array(seeds.nint)
    scale = np.full(s, float(half_width_rad))
    a = np.linspace(-1.0, 1.0, config.zoom_grid)
    ga, gb = (x.ravel() for x in np.meshgrid(a, a))
    segments = 0
    stalled = np.zeros(s, bool)
    history = [best.copy()]
    for _ in range(config.zoom_levels):
        act = np.flatnonzero((best >= config.zoom_miss_m) & ~stalled)
        if len(act) == 0:
            break
        u, v = tangent_basis(d0[act])
        k = len(ga)
        dirs = (d0[act, None, :] + (scale[act, None] * ga)[:, :, None] * u[:, None, :]
                + (scale[act, None] * gb)[:, :, None] * v[:, None, :]).reshape(-1, 3)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        ray_rx = np.repeat(seeds.receiver[act], k)
        w = refraction_walk(scene, media, tx_m, tx_medium, dirs, rx_m, rx_medium, ray_rx, config=config)
        segments += w.segments
        _charge(budget, w.segments)
        m = w.miss_m[:, 0].reshape(len(act), k)
        pick = np.argmin(m, axis=1)
        row = np.arange(len(act)) * k + pick
        better = m[np.arange(len(act)), pick] < best[act]
        sel = act[better]
        d0[sel] = dirs[row[better]]
        best[sel] = m[np.arange(len(act)), pick][better]
        codes[sel] = w.codes(row[better], 0)
        nint[sel] = w.nint[row[better], 0]
        scale[act] *= 0.5
        history.append(best.copy())
        if len(history) > config.zoom_stall_window:
            stalled |= best > config.zoom_stall_factor * history[-1 - config.zoom_stall_window]
    return Seeds(receiver=seeds.receiver, launch_dir=d0, miss_m=best, codes=codes, nint=nint,
                 segments=seeds.segments + segments)


def reverse_signature(codes: np.ndarray, nint: np.ndarray) -> np.ndarray:
    """The signature of the same path travelled backwards: events in reverse order, each
    surface crossed from the other side (``leaving`` flipped, the reflect bit kept)."""
    codes = np.asarray(codes, np.int64)
    out = np.full_like(codes, -1)
    for row in range(len(codes)):  # a handful of seeds
        k = int(nint[row])
        ev = codes[row, :k][::-1]
        out[row, :k] = ev ^ 2  # code = (organ * 2 + leaving) * 2 + reflect: bit 1 is `leaving`
    return out


def reverse_seeds(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    receivers: np.ndarray,
    rays: int,
    budget: Budget | None = None,
    config: TracerConfig | None = None,
) -> Seeds:
    """Forward seeds for ``receivers`` found from the receiver's side (reciprocity).

    Near a critical angle the launch-to-landing map from the high-index side is badly
    conditioned (a launch sliver fans out over centimetres of skin), while from the other
    end the same path can be a broad, well-conditioned bundle. For each receiver the walk
    and Newton refinement (no zoom: this is the well-conditioned side) run with the roles swapped
    (source at the receiver, target the transmitter); each converged reverse path gives the
    forward launch direction (towards its last vertex) and the reversed signature, which the
    caller refines forward so the field is computed along the forward path as usual. A loop over receivers (at most a
    dozen), vectorised inside."""
    from raytrace.solver.refine import follow, refine

    config = config or TracerConfig()
    out_rx, out_dir, out_codes, out_n = [], [], [], []
    segments = 0
    target = np.asarray(tx_m, float)[None, :]
    target_medium = np.array([tx_medium])
    for r in np.asarray(receivers, np.int64):
        src, src_med = rx_m[r], int(rx_medium[r])
        seeds = direct_seeds(scene, media, src, src_med, target, target_medium, rays, np.array([0]), budget, config)
        segments += seeds.segments
        if len(seeds.receiver) == 0:
            continue
        tgt = np.repeat(target, len(seeds.receiver), axis=0)
        ref = refine(scene, media, src, src_med, tgt, seeds.launch_dir, seeds.codes, seeds.nint, budget=budget,
                     config=config)
        segments += ref.segments
        dirs, codes, nint, ok = ref.dirs, seeds.codes, seeds.nint, ref.converged
        if not ok.any():
            continue
        dirs, codes, nint = dirs[ok], codes[ok], nint[ok]
        back = follow(scene, media, src, src_med, dirs, codes, nint)
        segments += back.segments
        last = np.where((nint > 0)[:, None], back.last_point, src)  # the forward path's first vertex
        fwd = last - np.asarray(tx_m, float)
        fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
        out_rx.append(np.full(len(dirs), r))
        out_dir.append(fwd)
        out_codes.append(reverse_signature(codes, nint))
        out_n.append(nint)
    if not out_rx:
        return _no_seeds(config, segments)
    return Seeds(
        receiver=np.concatenate(out_rx),
        launch_dir=np.concatenate(out_dir),
        miss_m=np.zeros(sum(len(x) for x in out_rx)),
        codes=np.concatenate(out_codes),
        nint=np.concatenate(out_n),
        segments=segments,
    )
