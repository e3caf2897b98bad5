"""Channel between a transmitter and receivers inside a phantom: exact ray paths.

Pipeline (``docs/tracer.md``). This module is the one place that runs the stages in order and
shares their state (the worker pool, the budget, the seeds between stages); the stages themselves
live in their own modules, so it stays whole (~560 lines).

1. Validate the request (typed errors naming the field).
2. Direct paths: the straight transmitter->receiver segment's crossings
   (a multi-hit walk along it) give the refraction-only signature; it is
   always refined, whatever ``max_interactions`` is. Receivers where it
   fails get refraction-only seeds from the rays themselves, zoomed when
   Newton's basin is narrower than the launch spacing, and finally a search
   from the receiver's side (reciprocity) (:mod:`raytrace.solver.direct`).
3. Shooting and bouncing rays (:mod:`raytrace.solver.sbr`): one Fibonacci launch for
   all receivers, reflected + transmitted splitting up to
   ``max_interactions``, candidates grouped by interaction signature.
4. Refinement (:mod:`raytrace.solver.refine`): Newton on the launch angles until
   each signature's last leg passes through its receiver; the Jacobian gives
   the ray tube. Paths that fail, or whose exact geometry is blocked, are
   dropped; duplicates (same signature, same delay) are merged.
5. Field (:mod:`raytrace.solver.field`): Jones/Fresnel/absorption/spreading per path,
   at the centre frequency and every band frequency (geometry traced once at
   the centre frequency, tissue properties re-evaluated per frequency).

Design choices (where this departs from or sharpens ``docs/tracer.md``):

* Refinement is Newton on the two launch angles with the signature traced
  physically (first hit in the full scene must be the named surface), not a
  Fermat minimisation over interaction points: every vertex then obeys
  Snell / reflection with *smooth* normals on faceted organs (so Fermat holds
  on the smoothed surface), blocking is detected by construction, and the
  Jacobian (ray differentials carried through every event) is the ray tube at
  no extra cost.
* Direct paths whose straight launch would be totally reflected (a capsule
  deep in muscle, a sensor in air) are found by homotopy on the indices
  (``n_i^s``, s: 0 -> 1), starting from the exact straight line at s = 0.
  The direct path is refined whatever ``max_interactions`` is (it may need
  more refractions than that); it is missing when geometric optics has no
  refraction-only path (shadow of a critical angle, e.g. a sensor whose fat
  patch the capsule sees beyond muscle -> fat's 26 deg, or the wedge behind
  a colon's limb), or when its only solutions pass a critical angle within a
  launch sliver narrower than the search resolves at the requested ``rays``
  (more rays find them; they are ~50 dB under the strongest path).
* The walls of one organ share a signature but are distinct paths: the shot
  candidates of a (receiver, signature) are clustered by launch direction and
  every cluster is refined (:func:`_select_seeds`), and converged duplicates
  are merged only when the launch direction agrees too.
* Fresnel coefficients for rays leaving a lossy tissue use the forward
  branch of the complex ``cos_t`` (:func:`raytrace.physics.em.cos_transmitted`).
* Shooting runs in launch batches (bounded memory, no culling of branches).
* Limits of geometric optics: the caustic field is capped (tube floor) and the
  caustic phase shift is not applied; diffraction and surface (lateral)
  waves are absent.

Ray geometry (Snell directions, total internal reflection, delays) uses
``Re n`` of the complex refractive index at the centre frequency; Fresnel
coefficients use the complex indices and the complex ``cos_t``; delays are
``sum L_i Re n_i / c``, absolute. Geometric optics is an approximation where
organs are comparable to the wavelength (docs/science.md).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from raytrace.body.library import get_phantom
from raytrace.body.phantom import Phantom
from raytrace.engine import kernels
from raytrace.engine.scene import TracerScene, scene_for
from raytrace.physics.em import C0
from raytrace.results import (
    ChannelResult,
    Interaction,
    Path,
    ReceiverProfile,
    Segment,
    TraceStats,
)
from raytrace.solver.budget import Budget
from raytrace.solver.config import TracerConfig
from raytrace.solver.direct import Seeds, reverse_seeds, zoom_seeds
from raytrace.solver.field import path_gains
from raytrace.solver.launch import angular_spacing_rad
from raytrace.solver.media import MediaTable
from raytrace.solver.refine import (
    KIND_PASS,
    KIND_REFLECTION,
    Refined,
    Steps,
    encode,
    follow,
    refine,
    refine_by_continuation,
)
from raytrace.solver.sbr import shoot
from raytrace.solver.validity import receiver_flags, smallest_organ
from raytrace.spec import Antenna, ChannelSpec


def trace_channel(spec: ChannelSpec, phantom: Phantom | None = None, *, budget: Budget | None = None,
                  config: TracerConfig | None = None) -> ChannelResult:
    """Trace every path of ``spec`` from its transmitter to each receiver, with complex gains.

    ``phantom`` is the phantom ``spec.phantom`` names (pass it for an uploaded or
    hand-built one); by default the built-in one of that id
    (:func:`raytrace.body.library.get_phantom`).

    ``a`` of each path is normalised so that ``|a|^2`` is the power transfer
    between the antennas (free space line of sight: ``lambda0 / (4 pi d)``;
    see :mod:`raytrace.solver.field` for the derivation). Paths weaker than the
    strongest one of a receiver by more than ``spec.dynamic_range_db`` are
    dropped; rays whose Fresnel/absorption power factor falls below it are pruned.

    ``spec.max_interactions`` bounds the reflections + refractions of the shot
    rays; the direct (refraction-only) path is searched whatever its number of
    refractions. A receiver can get no path at all when geometric optics has
    none (e.g. a sensor in air outside the escape cone of the skin). Every
    :class:`~raytrace.results.Segment` carries its end points. Raises the
    :class:`~raytrace.errors.InputError` subclasses of :meth:`ChannelSpec.resolve`
    and the media table (naming the field), and
    :class:`~raytrace.errors.BudgetExceededError` when ``budget`` runs out.

    ``config`` (:class:`~raytrace.solver.config.TracerConfig`): the search's tuning constants and
    threads; by default ``TracerConfig()`` (as many threads as this process may use).
    """
    started = time.monotonic()
    config = TracerConfig() if config is None else config
    threads = config.threads
    if phantom is None:
        phantom = get_phantom(spec.phantom)
    resolved = spec.resolve(phantom)
    tx, rx = resolved.tx_m, resolved.rx_m
    tx_pol, rx_pol, rx_pattern = resolved.tx_polarization, resolved.rx_polarization, resolved.rx_pattern
    tx_medium, rx_medium = resolved.tx_medium, resolved.rx_medium
    homogeneous = spec.homogeneous
    frequency_hz, max_interactions, rays = spec.frequency_hz, spec.max_interactions, spec.rays
    dynamic_range_db = spec.dynamic_range_db
    receivers = spec.receivers
    band = resolved.band_frequencies_hz
    # one table for all frequencies: the centre (geometry) frequency first, then the band
    media = MediaTable.build(phantom, np.concatenate([[frequency_hz], [] if band is None else band]), homogeneous)

    full_scene = scene_for(phantom)
    # surfaces between identical materials are invisible to propagation: shoot and refine in
    # a scene without them; the final re-trace uses every surface to split the segments
    scene = scene_for(phantom, ~media.face_transparent)
    segments = 0

    # --- one pool of ``threads`` workers for the request. Its queue: first the direct-path search
    # (it needs nothing from the shooting), then the shooting's launch batches (shooting and
    # bouncing rays: every other signature; the refraction-only seed walk rides on its rays),
    # so both cores stay busy until the last batch; then the Newton refinement of the shot
    # seeds in ``threads`` interleaved shares, while this thread finishes the direct paths. All
    # spend most of their time in the GIL-free kernels and Embree (docs/tracer.md,
    # "Performance"); the result is the same as a serial run's
    with ThreadPoolExecutor(max_workers=threads) as pool:
        direct = pool.submit(_direct_paths, scene, media, tx, tx_medium, rx, budget, config)
        cands = shoot(scene, media, tx, tx_medium, rx, rx_medium, int(rays), int(max_interactions),
                      float(dynamic_range_db), budget, walk=True, pool=pool, config=config)
        s_rx, s_codes, s_n, s_dir = _select_seeds(cands, config)
        # Newton is independent per seed: the shot seeds in interleaved shares, one per thread
        shares = [np.arange(k, len(s_rx), threads) for k in range(threads)]
        shot = [pool.submit(refine, scene, media, tx, tx_medium, rx[s_rx[i]], s_dir[i], s_codes[i], s_n[i],
                            budget=budget, config=config) for i in shares]
        # --- direct paths: the straight line's signature, refined (_direct_paths); then, for
        # receivers still without one, refraction-only rays walked from the transmitter (their
        # own signatures), zoomed in when Newton's basin is narrower than the launch spacing
        # (near a critical angle), and last the reverse search
        found, d_codes, d_n, seg = direct.result()
        segments += seg
        groups = [(np.arange(len(rx)), d_codes, d_n, found)]
        missing = np.flatnonzero(~found.converged)
        if len(missing):
            walk = cands.direct_seeds(missing, config)  # the refraction-only walk rode on the shooting's rays
            ref_w = refine(scene, media, tx, tx_medium, rx[walk.receiver], walk.launch_dir, walk.codes, walk.nint,
                           budget=budget, config=config)
            segments += ref_w.segments
            groups.append((walk.receiver, walk.codes, walk.nint, ref_w))
            have = np.unique(walk.receiver[ref_w.converged])
            still = np.isin(walk.receiver, missing[~np.isin(missing, have)])
            if still.any():
                sub = Seeds(walk.receiver[still], walk.launch_dir[still], walk.miss_m[still],
                            walk.codes[still], walk.nint[still], 0)
                zoomed = zoom_seeds(scene, media, tx, tx_medium, rx, rx_medium, sub,
                                    2.0 * angular_spacing_rad(int(rays)), budget, config)
                segments += zoomed.segments
                ref_z = refine(scene, media, tx, tx_medium, rx[zoomed.receiver], zoomed.launch_dir, zoomed.codes,
                               zoomed.nint, budget=budget, config=config)
                segments += ref_z.segments
                groups.append((zoomed.receiver, zoomed.codes, zoomed.nint, ref_z))
                have = np.union1d(have, zoomed.receiver[ref_z.converged])
            # still none: search from the receiver's side (reciprocity), refine the reversed path forward
            rest = missing[~np.isin(missing, have)]
            if len(rest):
                back = reverse_seeds(scene, media, tx, tx_medium, rx, rx_medium, rest, int(rays), budget, config)
                segments += back.segments
                ref_b = refine(scene, media, tx, tx_medium, rx[back.receiver], back.launch_dir, back.codes, back.nint,
                               budget=budget, config=config)
                segments += ref_b.segments
                groups.append((back.receiver, back.codes, back.nint, ref_b))

        # --- the shot seeds' refinement (started above, in parallel): every other signature
        ref_s = _merge_refined(shares, [f.result() for f in shot], len(s_rx))
    segments += cands.segments + ref_s.segments
    groups.append((s_rx, s_codes, s_n, ref_s))
    # --- the echo of a direct path off the receiver's own organ surface (a contact sensor's
    # skin/air total reflection: as strong as the direct path, 2 x the sensor depth longer). The
    # shooting finds it where it finds the direct path; where only the refraction-only search
    # found that (near a critical angle: the groups between the straight line's and the
    # shooting's) it is seeded from the direct path here
    t_rx, t_codes, t_n, t_dir = _surface_echo_seeds(groups[1:-1], rx_medium, int(max_interactions))
    if len(t_rx):
        ref_t = refine(scene, media, tx, tx_medium, rx[t_rx], t_dir, t_codes, t_n, budget=budget, config=config)
        segments += ref_t.segments
        groups.append((t_rx, t_codes, t_n, ref_t))

    width = max(max(g[1].shape[1] for g in groups), 1)
    seed_rx = np.concatenate([g[0] for g in groups])
    seed_codes = np.concatenate([_pad(g[1], width) for g in groups])
    seed_n = np.concatenate([g[2] for g in groups])
    refined = Refined(
        dirs=np.concatenate([g[3].dirs for g in groups]),
        converged=np.concatenate([g[3].converged for g in groups]),
        tube_m2_per_sr=np.concatenate([g[3].tube_m2_per_sr for g in groups]),
        segments=0,
    )
    conv = np.flatnonzero(refined.converged)
    # one row per exact path (_unique_paths) before the re-trace and the fields, which then
    # run once per path rather than once per converged seed (about 2.3 seeds per path)
    conv = conv[_unique_paths(seed_rx[conv], seed_codes[conv], refined.dirs[conv], config)]
    rec = follow(full_scene, media, tx, tx_medium, refined.dirs[conv], seed_codes[conv], seed_n[conv],
                 targets_m=rx[seed_rx[conv]])
    segments += rec.segments
    if budget is not None:
        budget.charge(rec.segments)
    fields = path_gains(
        rec.steps, media, tx, tx_medium, rx[seed_rx[conv]], rx_medium[seed_rx[conv]], refined.dirs[conv],
        refined.tube_m2_per_sr[conv], tx_pol, spec.transmitter.pattern, rx_pol[seed_rx[conv]],
        rx_pattern[seed_rx[conv]], near_field=spec.near_field,
    )
    if budget is not None:
        budget.hold(fields.gains.nbytes)  # every path's gain at every frequency (the band dominates)
    keep = rec.ok & np.isfinite(fields.gains).all(axis=1) & np.isfinite(fields.delay_s)

    # --- assemble profiles: per receiver, its rows above the dynamic-range floor in delay
    # order; then every path's objects in one pass (_make_paths)
    floor = 10.0 ** (-float(dynamic_range_db) / 20.0)
    per_rx = []
    for r in range(len(receivers)):
        rows = np.flatnonzero(keep & (seed_rx[conv] == r))
        if len(rows):
            amp = np.abs(fields.gains[rows, 0])
            rows = rows[amp >= floor * amp.max()]
            rows = rows[np.argsort(fields.delay_s[rows], kind="stable")]
        per_rx.append(rows)
    all_rows = np.concatenate(per_rx) if per_rx else np.zeros(0, np.int64)
    tir = np.array(fields.reflect_tir, bool).reshape(rec.steps.valid.shape)  # (S, P)
    made = _make_paths(phantom, rec.steps, tir, fields, all_rows, tx, rx[seed_rx[conv][all_rows]], int(tx_medium),
                       band is not None)
    strongest_direct = []
    for r in range(len(receivers)):  # the strongest refraction-only path's geometry, for the validity flags
        rows = [j for j in per_rx[r] if not any(rec.steps.valid[s, j] and rec.steps.kind[s, j] == KIND_REFLECTION
                                                for s in range(rec.steps.valid.shape[0]))]
        if not rows:
            strongest_direct.append(None)
            continue
        j = max(rows, key=lambda j: abs(fields.gains[j, 0]))
        straight = not any(rec.steps.valid[s, j] and rec.steps.kind[s, j] != KIND_PASS
                           for s in range(rec.steps.valid.shape[0]))
        strongest_direct.append((straight, float(fields.max_sin_t[j]), float(fields.exit_sin_t[j]),
                                 float(fields.stack_tilt_deg[j])))
    lam_tx = C0 / frequency_hz / float(media.n_real[tx_medium + 1])
    flags = receiver_flags(phantom, rx, rx_medium, np.linalg.norm(rx - tx, axis=1), lam_tx, spec.near_field,
                           strongest_direct)
    profiles = []
    start = 0
    widths: dict[int, float] = {}
    for r, antenna in enumerate(receivers):
        paths = tuple(made[start:start + len(per_rx[r])])
        start += len(per_rx[r])
        organ, size, warning = smallest_organ(phantom, media.n[0], float(frequency_hz), paths, widths)
        profiles.append(
            ReceiverProfile(
                receiver=antenna.name,
                position_m=rx[r].copy(),
                medium=phantom.medium_name(int(rx_medium[r])),
                geometric_distance_m=float(np.linalg.norm(rx[r] - tx)),
                paths=paths,
                smallest_organ=organ,
                smallest_organ_size_wavelengths=size,
                warnings=() if warning is None else (warning,),
                validity=flags[r],
            )
        )
    n_paths = len(made)
    stats = TraceStats(
        rays_launched=int(cands.rays_launched),
        ray_segments_traced=int(segments),
        paths_found=n_paths,
        elapsed_s=time.monotonic() - started,
    )
    return ChannelResult(
        phantom=spec.phantom,
        frequency_hz=float(frequency_hz),
        transmitter_position_m=tx.copy(),
        transmitter_medium=phantom.medium_name(tx_medium),
        profiles=tuple(profiles),
        stats=stats,
        band_frequencies_hz=band,
    )


# ------------------------------------------------------------------ helpers
def _merge_refined(shares: list[np.ndarray], parts: list[Refined], count: int) -> Refined:
    """One :class:`Refined` of ``count`` seeds from the refinements of its ``shares`` (index arrays)."""
    out = Refined(dirs=np.zeros((count, 3)), converged=np.zeros(count, bool), tube_m2_per_sr=np.full(count, np.nan),
                  segments=sum(p.segments for p in parts))
    for rows, part in zip(shares, parts):
        out.dirs[rows] = part.dirs
        out.converged[rows] = part.converged
        out.tube_m2_per_sr[rows] = part.tube_m2_per_sr
    return out


def _surface_echo_seeds(groups, rx_medium, max_interactions):
    """Seeds for the echo of each converged direct (refraction-only) path off the surface of
    the organ its receiver is in: the same signature plus one reflection on that organ's own
    boundary from inside, launched along the direct path (Newton moves it by a fraction of a
    degree). One seed per (receiver, direct signature) within ``max_interactions`` (unlike the
    direct path, its echo obeys the cap); none for receivers in air."""
    rows = []
    for rx_idx, codes, nint, ref in groups:
        real = codes >= 0
        direct = ref.converged & real.any(axis=1) & ~((codes & 1).astype(bool) & real).any(axis=1)
        direct &= (rx_medium[rx_idx] >= 0) & (nint < max_interactions)
        for i in np.flatnonzero(direct):
            rows.append((int(rx_idx[i]), codes[i, : nint[i]], ref.dirs[i]))
    seen, out = set(), []
    for r, code, d in rows:  # a few per receiver: a loop over converged paths, not rays
        key = (r, code.tobytes())
        if key not in seen:
            seen.add(key)
            out.append((r, np.append(code, encode(rx_medium[r], True, 1)), d))
    if not out:
        return np.zeros(0, np.int64), np.zeros((0, 1), np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    width = max(len(c) for _, c, _ in out)
    codes = np.full((len(out), width), -1, np.int64)
    for k, (_, c, _) in enumerate(out):
        codes[k, : len(c)] = c
    return (np.array([r for r, _, _ in out], np.int64), codes, np.array([len(c) for _, c, _ in out], np.int64),
            np.array([d for _, _, d in out]))


def _direct_paths(scene: TracerScene, media: MediaTable, tx: np.ndarray, tx_medium: int, rx: np.ndarray,
                  budget: Budget | None, config: TracerConfig):
    """The direct path of every receiver from its straight line's refraction-only signature,
    refined from the straight launch; where that fails (the straight launch totally
    reflected on the way), by homotopy on the indices (:func:`refine_by_continuation`).
    Returns the refined paths, the signatures, their event counts and the segments cast."""
    d_codes, d_n, segments = _straight_signatures(scene, media, tx, rx)
    direct_dir = (rx - tx) / np.linalg.norm(rx - tx, axis=1, keepdims=True)
    found = refine(scene, media, tx, tx_medium, rx, direct_dir, d_codes, d_n, budget=budget, config=config)
    segments += found.segments
    retry = np.flatnonzero(~found.converged)
    if len(retry):
        again = refine_by_continuation(scene, media, tx, tx_medium, rx[retry], d_codes[retry], d_n[retry],
                                       budget=budget, config=config)
        segments += again.segments
        found.dirs[retry] = again.dirs
        found.converged[retry] = again.converged
        found.tube_m2_per_sr[retry] = again.tube_m2_per_sr
    return found, d_codes, d_n, segments


def _straight_signatures(scene: TracerScene, media: MediaTable, tx: np.ndarray, rx: np.ndarray):
    """Refraction-only signature of each straight transmitter->receiver segment (multi-hit walk)."""
    m = len(rx)
    o = np.broadcast_to(tx, (m, 3)).copy()
    d = (rx - tx) / np.linalg.norm(rx - tx, axis=1, keepdims=True)
    push = np.zeros((m, 3))
    codes: list[np.ndarray] = []
    active = np.ones(m, bool)
    segments = 0
    for _ in range(1024):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        face, t = scene.first_hit(o[idx], d[idx], push[idx])
        segments += len(idx)
        remaining = np.linalg.norm(rx[idx] - o[idx], axis=1)
        cross = (face >= 0) & (t < remaining)
        active[idx[~cross]] = False
        step = np.full(m, -1, np.int64)
        if cross.any():
            j = idx[cross]
            f = face[cross]
            fn = scene.face_normals[f]
            leaving = np.einsum("ij,ij->i", d[j], fn) > 0.0
            o[j] = o[j] + t[cross, None] * d[j]
            push[j] = np.where(leaving, 1.0, -1.0)[:, None] * fn * scene.offset_m
            real = ~media.face_transparent[f]
            step[j[real]] = encode(scene.face_organ[f[real]], leaving[real], 0)
        if (step >= 0).any():
            codes.append(step)
    if not codes:
        return np.zeros((m, 0), np.int64), np.zeros(m, np.int64), segments
    table = np.stack(codes, axis=1)  # (m, steps) with -1 gaps
    # compact each row (drop the -1 gaps, keep order)
    order = np.argsort(table < 0, axis=1, kind="stable")
    table = np.take_along_axis(table, order, axis=1)
    nint = (table >= 0).sum(axis=1)
    return table[:, : max(int(nint.max()), 0)], nint, segments


def _pad(a: np.ndarray, width: int) -> np.ndarray:
    out = np.full((len(a), width), -1, np.int64)
    out[:, : a.shape[1]] = a
    return out


def _select_seeds(c, config: TracerConfig):
    """Seeds to refine: one or more per distinct path of each (receiver, signature) group.

    The faces of one organ share a signature (a box room's six walls, the two specular points
    of a concave organ), so a group holds as many distinct paths as the geometry has. Its
    candidates are clustered by launch direction (:func:`_clusters`: single linkage at
    ``config.cluster_link`` launch spacings): the rays near one exact path are neighbours on the
    launch sphere, distinct paths are apart. Per cluster, candidates in order of closeness,
    each kept only if its launch direction is at least ``config.seed_separation`` spacings from
    the cluster's seeds already kept, up to ``config.seeds_per_cluster`` (retries of one path,
    the closest first: :func:`raytrace.engine.kernels.spread_picks`). The number of clusters is
    not capped; the refinement charges the request's :class:`Budget` instead. Since
    ``cluster_link >= seed_separation``, candidates of two clusters are always farther apart
    than the separation, so each cluster's seeds start with what a greedy pick over the whole
    group would have kept there. Seeds are returned in candidate order."""
    if len(c.receiver) == 0:
        return c.receiver, c.codes, c.nint, c.launch_dir
    spacing = np.sqrt(4.0 * np.pi / max(c.rays_launched, 1))
    group = _row_groups(np.concatenate([c.receiver[:, None], c.codes], axis=1))
    cluster = _clusters(group, c.launch_dir, config.cluster_link * spacing)
    order = np.lexsort((c.closeness, cluster))
    k = cluster[order]
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1], True])
    min_cos = np.cos(config.seed_separation * spacing)
    chosen = np.flatnonzero(kernels.spread_picks(order, starts, np.ascontiguousarray(c.launch_dir, float), min_cos,
                                                 config.seeds_per_cluster))
    # the group's first picks in order of closeness come first (then the rest, each part in
    # candidate order): of several seeds converging to one path the first is kept
    # (_unique_paths), so a path found before clustering keeps its seed, bit for bit
    by_group = chosen[np.lexsort((c.closeness[chosen], group.ravel()[chosen]))]
    g = group.ravel()[by_group]
    first = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    rank = np.arange(len(g)) - np.repeat(first, np.diff(np.r_[first, len(g)]))
    early = np.zeros(len(c.receiver), bool)
    early[by_group[rank < config.seeds_per_cluster]] = True
    chosen = np.concatenate([chosen[early[chosen]], chosen[~early[chosen]]])
    return c.receiver[chosen], c.codes[chosen], c.nint[chosen], c.launch_dir[chosen]


def _row_groups(key: np.ndarray) -> np.ndarray:
    """The label of each row of the int ``key`` matrix among its distinct rows in lexicographic
    order: ``np.unique(key, axis=0, return_inverse=True)[1]``, without sorting rows as records
    (0.95 s for 1.5e5 candidates of the room with a sphere). The rows (values >= -1) are read as
    numbers in a mixed radix (each column's digit ``value + 1`` below its base, so the order is
    the rows' lexicographic order) and one int64 array is sorted; a lexsort of the columns when
    that number would not fit in 63 bits."""
    key = np.asarray(key, np.int64)
    if len(key) == 0:
        return np.zeros(0, np.int64)
    digits = key - key.min(axis=0)
    base = digits.max(axis=0) + 1
    if float(np.prod(base.astype(float))) < 2.0 ** 62:
        weight = np.cumprod(np.r_[base[1:], 1][::-1])[::-1]
        _, group = np.unique(digits @ weight, return_inverse=True)
        return np.ascontiguousarray(group.ravel(), np.int64)
    order = np.lexsort(key.T[::-1])
    ranked = key[order]
    new = np.r_[True, (ranked[1:] != ranked[:-1]).any(axis=1)]
    group = np.empty(len(key), np.int64)
    group[order] = np.cumsum(new) - 1
    return group


def _clusters(group: np.ndarray, dirs: np.ndarray, link_rad: float) -> np.ndarray:
    """Cluster label (0..) of each candidate: the connected components of the graph linking two
    candidates of the same ``group`` whose unit launch directions ``dirs`` are within ``link_rad``
    of each other (chord length). Groups are kept apart by shifting each one's directions by
    ``3 * group`` along x (unit vectors of two groups are then at least 1 apart, far beyond any
    link). Deterministic: labels follow the smallest candidate index. The components come from
    cells of the shifted points (:func:`raytrace.engine.kernels.link_components`), not from the
    list of linked pairs: the 8e5 candidates of 64 receivers around a sphere link in 4.5e6 pairs,
    which a k-d tree's pair query listed in ~1 s."""
    pts = np.asarray(dirs, float).copy()
    pts[:, 0] += 3.0 * group
    cell = float(link_rad) / np.sqrt(3.0) * (1.0 - 1e-9)
    cells = np.floor(pts / cell).astype(np.int64)
    return kernels.link_components(np.ascontiguousarray(pts), np.ascontiguousarray(cells), float(link_rad))


def _unique_paths(rx_idx, codes, dirs, config: TracerConfig):
    """Mask keeping one of several converged seeds with the same receiver, signature and
    launch direction (within ``config.duplicate_angle_rad``): seeds from neighbouring rays
    converge to the same exact path, while symmetric walls of one organ give distinct paths
    (with equal delays) from distinct launches. Rows in order, each against the rows
    already kept in its group (:func:`raytrace.engine.kernels.first_of_duplicates`)."""
    if len(rx_idx) == 0:
        return np.zeros(0, bool)
    group = _row_groups(np.concatenate([rx_idx[:, None], codes], axis=1))
    return kernels.first_of_duplicates(group, np.ascontiguousarray(dirs, float), config.duplicate_angle_rad)


def _make_paths(phantom, records: Steps, tir: np.ndarray, fields, rows: np.ndarray, tx_m: np.ndarray,
                rx_m: np.ndarray, tx_medium: int, band: bool) -> list[Path]:
    """The :class:`Path` of each recorded path ``rows`` (receiver ``rx_m[j]`` for ``rows[j]``),
    from the (S, P) step records and total-reflection flags ``tir``. The geometry is
    gathered for all paths at once (a path's valid steps are a prefix of its column:
    :func:`raytrace.solver.refine.follow` records them in order); the loop only builds the objects."""
    n = len(rows)
    if n == 0:
        return []
    valid = records.valid[:, rows]  # (S, n)
    cnt = valid.sum(axis=0)
    pts = np.zeros((n, valid.shape[0] + 2, 3))  # transmitter, events, receiver (then unused zeros)
    pts[:, 0] = tx_m
    pts[:, 1:-1] = np.where(valid[:, :, None], records.point[:, rows], 0.0).transpose(1, 0, 2)
    pts[np.arange(n), cnt + 1] = rx_m
    names = [phantom.medium_name(m) for m in range(-1, len(phantom.organs))]  # medium m at m + 1
    # flat lists, path after path: its cnt valid steps (a prefix of its row), then its cnt + 1 segments
    has_step = valid.T  # (n, S)
    kind, m_from, m_to, total = (a[:, rows].T[has_step] for a in (records.kind, records.med_from, records.med_to, tir))
    ends = np.arange(valid.shape[0] + 1) <= cnt[:, None]
    lengths = np.linalg.norm(np.diff(pts, axis=1), axis=2)[ends].tolist()
    first = np.concatenate([[0], np.cumsum(cnt)])  # path j's first step; its first segment: + j
    # per step: what it is called (None: a pass, no interaction) and the media names either side;
    # per segment: its medium (each step's from-medium, then the medium after the last step)
    label = np.where(kind == KIND_PASS, 0, np.where(kind == KIND_REFLECTION, np.where(total, 2, 1), 3))
    labels = [None, "reflection", "total_internal_reflection", "refraction"]
    step_kind = [labels[k] for k in label.tolist()]
    after = np.where(kind == KIND_REFLECTION, m_from, m_to)
    last = np.full(n, tx_medium, np.int64)
    last[cnt > 0] = after[first[1:][cnt > 0] - 1]
    seg_medium = np.empty(len(kind) + n, np.int64)  # path j's segments start at first[j] + j
    seg_first = first[:-1] + np.arange(n)
    is_last = np.zeros(len(seg_medium), bool)
    is_last[seg_first + cnt] = True
    seg_medium[is_last] = last
    seg_medium[~is_last] = m_from
    seg_names = [names[m + 1] for m in seg_medium.tolist()]
    from_names = [names[m + 1] for m in m_from.tolist()]
    to_names = [names[m + 1] for m in m_to.tolist()]
    views = list(pts.reshape(-1, 3))  # one view per point, shared by the objects that end there
    width = pts.shape[1]
    first, cnt = first.tolist(), cnt.tolist()
    delay_s, length_m = fields.delay_s[rows].tolist(), fields.length_m[rows].tolist()
    group_delay_s = fields.group_delay_s[rows].tolist()
    gain = fields.gains[rows, 0].tolist()
    out = []
    for j in range(n):
        steps, e = cnt[j], first[j]
        base = j * width
        points = views[base:base + steps + 2]
        interactions = tuple(Interaction(step_kind[e + k], points[k + 1], from_names[e + k], to_names[e + k])
                             for k in range(steps) if step_kind[e + k] is not None)
        g = e + j  # this path's first segment
        segments = tuple(Segment(seg_names[g + i], lengths[g + i], points[i], points[i + 1]) for i in range(steps + 1))
        out.append(Path(delay_s=delay_s[j], group_delay_s=group_delay_s[j], gain=gain[j], length_m=length_m[j],
                        interactions=interactions, segments=segments,
                        band_gains=fields.gains[rows[j], 1:].copy() if band else None))
    return out


def warm_up() -> float:
    """Compile the tracer's numba kernels (:mod:`raytrace.engine.kernels`), or load them from numba's
    on-disk cache, before the first request needs them: one small trace of the half-space
    scenario runs every kernel with the argument types of a real trace (~17 s to compile
    after an install, ~0.2 s from the cache). Returns the seconds it took."""
    from raytrace.body.library import half_space

    t0 = time.perf_counter()
    phantom = half_space()
    spec = ChannelSpec(Antenna(site="tx"), (Antenna(site="rx_oblique"),), phantom=phantom.name, rays=2000,
                       max_interactions=2)
    trace_channel(spec, phantom)
    return time.perf_counter() - t0
